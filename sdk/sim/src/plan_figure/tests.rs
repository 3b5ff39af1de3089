//! Tests of the planning-step figure: the observation, the episode files, the figure's numbers
//! and PNG, and the BEV's velocity colours.

use super::bev_raster::velocity_colour;
use super::*;
use crate::episode::{AgentTrack, Episode, EpisodeSuite, ScenarioClass};
use crate::runner::StartHeading;
use approx::assert_relative_eq;
use human2nav_core::PlanInfo;

fn episode() -> Episode {
    Episode {
        id: "test/0".into(),
        scene: "test".into(),
        source: "synthetic".into(),
        scenario: ScenarioClass::CrossFlow,
        dt: 0.1,
        start: Pose2::new(1.0, 1.0, 2.0),
        goal: [4.0, 5.0],
        time_budget: 12.5,
        agents: vec![
            AgentTrack {
                id: 1,
                start_step: 0,
                positions: (0..40).map(|k| [2.0 + 0.1 * k as f64, 2.0]).collect(),
                radius: 0.3,
            },
            AgentTrack {
                id: 2,
                start_step: 0,
                positions: vec![[40.0, 40.0]; 5],
                radius: 0.3,
            },
        ],
        density: 1,
        obstacles: Vec::new(),
        human_path: Vec::new(),
    }
}

#[test]
fn observation_faces_the_goal_and_sees_the_crowd_in_range() {
    let ep = episode();
    let opts = StepOptions {
        time: 1.0,
        ego_speed: 0.5,
        ..StepOptions::default()
    };
    let obs = observation_at(&ep, &opts).unwrap();
    assert_relative_eq!(obs.ego.theta, (4.0f64).atan2(3.0), epsilon = 1e-12);
    assert_relative_eq!(obs.ego_velocity.vx, 0.5);
    assert_eq!(obs.agents.len(), 1, "the far pedestrian is out of range");
    let a = &obs.agents[0];
    assert_relative_eq!(a.position[0], 3.0, epsilon = 1e-9);
    assert_relative_eq!(a.velocity[0], 1.0, epsilon = 1e-9);
    assert_eq!(a.history.len(), 8);
    let recorded = StepOptions {
        start_heading: StartHeading::Episode,
        ..StepOptions::default()
    };
    assert_relative_eq!(observation_at(&ep, &recorded).unwrap().ego.theta, 2.0);
    let bad = StepOptions {
        time: f64::NAN,
        ..StepOptions::default()
    };
    assert!(observation_at(&ep, &bad).is_err());
    // The last instant of the episode is fine; past it is an error naming its length.
    let at = |time| StepOptions {
        time,
        ..StepOptions::default()
    };
    assert!(observation_at(&ep, &at(12.5)).is_ok());
    let late = observation_at(&ep, &at(99.0)).unwrap_err().to_string();
    assert!(
        late.contains("step.time") && late.contains("`test/0`, which lasts 12.5 s"),
        "{late}"
    );
}

#[test]
fn episode_files_hold_a_suite_or_one_episode() {
    let dir = std::env::temp_dir().join(format!("h2n-planfig-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let one = dir.join("one.json");
    std::fs::write(&one, serde_json::to_string(&episode()).unwrap()).unwrap();
    assert_eq!(load_episodes(&one).unwrap().len(), 1);
    let suite = dir.join("suite.json");
    let mut second = episode();
    second.id = "test/1".into();
    EpisodeSuite::new("synthetic", vec![episode(), second])
        .save(&suite)
        .unwrap();
    let eps = load_episodes(&suite).unwrap();
    assert_eq!(eps.len(), 2);
    assert_eq!(select_episode(&eps, 1, None).unwrap().id, "test/1");
    assert_eq!(
        select_episode(&eps, 0, Some("test/1")).unwrap().id,
        "test/1"
    );
    assert!(select_episode(&eps, 5, None).is_err());
    assert!(select_episode(&eps, 0, Some("nope")).is_err());
    let bad = dir.join("bad.json");
    std::fs::write(&bad, "{").unwrap();
    assert!(matches!(load_episodes(&bad), Err(SimError::Parse { .. })));
    let _ = std::fs::remove_dir_all(&dir);
}

fn limits() -> Limits {
    Limits {
        v_max: 1.0,
        v_reverse_max: 0.3,
        a_max: 1.0,
        omega_max: 1.0,
        kappa_max: None,
        lateral_speed_max: 0.05,
        coupled: None,
    }
}

/// A plan at 0.05 m then 0.2 m per step (0.5 then 2 m/s): the first waypoints are feasible,
/// the fast ones not; the figure's numbers say so and the PNG is written.
#[test]
fn figure_numbers_and_png() {
    let ep = episode();
    let obs = observation_at(&ep, &StepOptions::default()).unwrap();
    let ego = obs.ego;
    let mut poses = vec![ego];
    let mut x = 0.0;
    for k in 1..=10 {
        x += if k <= 4 { 0.05 } else { 0.2 };
        poses.push(ego.compose(Pose2::new(x, 0.0, 0.0)));
    }
    let slow: Vec<Pose2> = (0..=10)
        .map(|k| ego.compose(Pose2::new(0.05 * k as f64, 0.0, 0.0)))
        .collect();
    let plan = Plan {
        t0: 0.0,
        dt: 0.1,
        poses,
        info: PlanInfo {
            candidates: vec![slow.clone(), slow],
            guided: Vec::new(),
            selected: Some(0),
            phi_before: Some(0.5),
            phi_after: Some(0.1),
            ..PlanInfo::default()
        },
    };
    let lim = limits();
    // The pedestrians' predicted paths are drawn too (a forecast of one scene here).
    let forecast = Forecast::constant_velocity(&obs.agents, 10, 0.1);
    let fig = PlanFigure {
        robot: "test",
        label: &ep.id,
        guidance: true,
        observation: &obs,
        start: Some(ep.start),
        plan: &plan,
        limits: &lim,
        footprint_radius: 0.3,
        bev: BevSpec::default(),
        forecast: Some(&forecast),
    };
    let n = plan_numbers(&fig);
    assert_eq!(n.waypoints, 10);
    // Waypoint 1 accelerates from rest to 0.5 m/s in 0.1 s (5 m/s² > a_max), 2-4 are
    // fine, 5 jumps to 2 m/s, 6-10 are too fast.
    assert_eq!(n.feasible, 3);
    assert_relative_eq!(n.tfs, 0.3, epsilon = 1e-12);
    // The kept sample before guidance: 0.5 m/s from rest, only the first step too brisk.
    assert_relative_eq!(n.tfs_before.unwrap(), 0.9, epsilon = 1e-12);
    let png = std::env::temp_dir().join(format!("h2n-planfig-{}.png", std::process::id()));
    let drawn = draw_plan_figure(&png, &fig).unwrap();
    assert_eq!(drawn, n);
    assert!(std::fs::metadata(&png).unwrap().len() > 10_000);
    let _ = std::fs::remove_file(&png);
}

#[test]
fn velocity_colours_follow_direction() {
    assert_eq!(velocity_colour(0.0, 0.0), RGBColor(70, 70, 70));
    // Forward (hue 0) is red-dominant, sideways differs.
    let f = velocity_colour(1.5, 0.0);
    assert!(f.0 > f.1 && f.0 > f.2, "{f:?}");
    assert_ne!(velocity_colour(0.0, 1.5), f);
}
