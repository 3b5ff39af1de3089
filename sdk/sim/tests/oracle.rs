//! The clairvoyant yardstick: feasible plans, avoidance of what the recording holds, the note
//! when nothing avoids it, and settings errors that name the field.

mod common;

use common::{episode, robot, robots, walking};
use human2nav_core::robot::footprint::clearance_at;
use human2nav_core::tfs::tfs_plan;
use human2nav_core::{Observation, Planner, Pose2, Twist2};
use human2nav_sim::episode::ScenarioClass;
use human2nav_sim::episode::{AgentTrack, Episode};
use human2nav_sim::oracle::{OracleConfig, OraclePlanner, Prediction};
use human2nav_sim::replay::CrowdReplay;
use human2nav_sim::straight::{StraightConfig, StraightPlanner};
use human2nav_sim::{EpisodeMetrics, MethodSpec, Outcome, SimConfig, run_episode};
use std::f64::consts::PI;

fn oracle_for(
    r: &human2nav_sim::RobotSetup,
    ep: &human2nav_sim::episode::Episode,
) -> OraclePlanner {
    OraclePlanner::new(
        OracleConfig::default(),
        r.limits,
        r.footprint.clone(),
        ep.clone(),
    )
    .expect("valid oracle")
}

#[test]
fn the_oracle_reaches_empty_world_goals_with_feasible_plans() {
    let cfg = SimConfig::default();
    for r in robots() {
        for k in 0..4 {
            let a = 2.0 * PI * k as f64 / 4.0 + 0.3;
            let mut ep = episode("empty", ScenarioClass::CoFlow, 0.0, vec![]);
            ep.goal = [5.0 * a.cos(), 5.0 * a.sin()];
            let mut oracle = oracle_for(&r, &ep);
            // Its first plan is within the robot's limits from rest.
            let obs = Observation {
                ego: ep.start,
                goal: ep.goal,
                ..Default::default()
            };
            let plan = oracle.plan(&obs).unwrap();
            let local: Vec<Pose2> = plan.poses.iter().map(|p| ep.start.between(*p)).collect();
            assert_eq!(
                tfs_plan(&local, plan.dt, &r.limits, Twist2::ZERO),
                1.0,
                "{}",
                r.name
            );
            let run = run_episode(&ep, &r, &mut oracle, &cfg);
            assert_eq!(
                run.outcome,
                Outcome::Success,
                "{} toward {a:.2} rad",
                r.name
            );
            assert!(run.planner_errors.is_empty());
            // Across replanning too: the commands the tracking controller sent are within the
            // limits (segment means that ramp from the current speed).
            let m = EpisodeMetrics::compute(&run, &r.limits);
            assert!(
                m.tfs_executed >= 0.99,
                "{}: executed TFS {}",
                r.name,
                m.tfs_executed
            );
        }
    }
}

#[test]
fn the_oracle_avoids_a_walker_that_straight_runs_into() {
    let cfg = SimConfig::default();
    for r in robots() {
        // Head-on along the robot's line, from beyond the goal at 1.2 m/s.
        let ep = episode(
            "head-on",
            ScenarioClass::CounterFlow,
            0.0,
            vec![walking(7, [7.0, 0.0], [-1.2, 0.0], 200)],
        );
        let straight = StraightPlanner::new(StraightConfig {
            speed: r.limits.v_max,
            accel: r.limits.a_max,
            ..StraightConfig::default()
        })
        .unwrap();
        let run = run_episode(&ep, &r, &mut { straight }, &cfg);
        assert_eq!(run.outcome, Outcome::Collision, "{}: straight", r.name);
        let run = run_episode(&ep, &r, &mut oracle_for(&r, &ep), &cfg);
        assert_eq!(run.outcome, Outcome::Success, "{}: oracle", r.name);
        assert!(run.clearance.iter().all(|&c| c > 0.0));
    }
}

#[test]
fn a_closing_ring_leaves_no_motion_and_the_plan_says_so() {
    let r = robot("diablo");
    // Twelve people converge on the robot from 2 m at 1.5 m/s: everyone meets within 1.3 s.
    let ring = (0..12)
        .map(|i| {
            let a = 2.0 * PI * i as f64 / 12.0;
            walking(
                i,
                [2.0 * a.cos(), 2.0 * a.sin()],
                [-1.5 * a.cos(), -1.5 * a.sin()],
                40,
            )
        })
        .collect();
    let ep = episode("ring", ScenarioClass::MultidirectionFlow, 0.0, ring);
    let obs = Observation {
        ego: ep.start,
        goal: ep.goal,
        ..Default::default()
    };
    let plan = oracle_for(&r, &ep).plan(&obs).unwrap();
    assert!(plan.is_finite());
    assert!(
        plan.info
            .notes
            .iter()
            .any(|n| n.starts_with("every motion touches someone")),
        "{:?}",
        plan.info.notes
    );
}

#[test]
fn bad_oracle_settings_name_the_field() {
    for (table, field) in [
        ("horizon = 0.0", "horizon"),
        ("turn_levels = 4", "turn_levels"),
        ("speed_levels = 1", "speed_levels"),
        ("margin = -1.0", "margin"),
        ("max_candidates = 0", "max_candidates"),
        ("horizon = 1000.0", "horizon"),
    ] {
        let t: toml::Table = toml::from_str(table).unwrap();
        let err = MethodSpec::oracle("oracle", &t).unwrap_err().to_string();
        assert!(err.contains(field), "{table}: {err}");
    }
    let t: toml::Table = toml::from_str("horizons = 3.0").unwrap();
    let err = MethodSpec::oracle("oracle", &t).unwrap_err().to_string();
    assert!(err.contains("horizons"), "{err}");
}

#[test]
fn the_constant_velocity_search_knows_only_the_observation() {
    let r = robot("diablo");
    // Somebody steps onto the line at (2.5, 0) 1.5 s in and stays: not yet in the observation.
    let late = AgentTrack {
        id: 9,
        start_step: 15,
        positions: vec![[2.5, 0.0]; 100],
        radius: 0.3,
    };
    let ep = episode("late", ScenarioClass::CrossFlow, 0.0, vec![late]);
    let obs = Observation {
        ego: ep.start,
        goal: ep.goal,
        ..Default::default()
    };
    let closest = |prediction: Prediction| {
        let cfg = OracleConfig {
            prediction,
            ..OracleConfig::default()
        };
        let mut p = OraclePlanner::new(cfg, r.limits, r.footprint.clone(), ep.clone()).unwrap();
        let plan = p.plan(&obs).unwrap();
        // Closest approach to the late pedestrian once it is there.
        plan.poses[15..]
            .iter()
            .map(|q| clearance_at(&r.footprint, *q, [2.5, 0.0], 0.3))
            .fold(f64::INFINITY, f64::min)
    };
    assert!(closest(Prediction::Recorded) >= 0.05);
    for prediction in [Prediction::ConstantVelocity, Prediction::Seen] {
        assert!(closest(prediction) < 0.0, "{prediction:?} cannot know");
    }
    let cfg = OracleConfig {
        prediction: Prediction::ConstantVelocity,
        ..OracleConfig::default()
    };
    let p = OraclePlanner::new(cfg, r.limits, r.footprint.clone(), ep).unwrap();
    assert_eq!(p.name(), "search-cv");
}

#[test]
fn the_seen_oracle_knows_the_future_of_whom_the_robot_observes() {
    let r = robot("diablo");
    // A walker 4 m ahead comes toward the robot, steps onto its line after 1 s and stays there.
    let mut positions: Vec<[f64; 2]> = (0..=10).map(|k| [4.0 - 0.1 * k as f64, 0.6]).collect();
    positions.extend((1..=5).map(|k| [3.0, 0.6 - 0.12 * k as f64]));
    positions.extend(std::iter::repeat_n([3.0, 0.0], 100));
    let walker = AgentTrack {
        id: 4,
        start_step: 0,
        positions,
        radius: 0.3,
    };
    let ep = episode("steps in", ScenarioClass::CounterFlow, 0.0, vec![walker]);
    let seen = Observation {
        ego: ep.start,
        goal: ep.goal,
        agents: CrowdReplay::new(&ep).observe(0.0, [ep.start.x, ep.start.y], 10.0, 8),
        ..Default::default()
    };
    assert_eq!(seen.agents.len(), 1);
    let unseen = Observation {
        agents: vec![],
        ..seen.clone()
    };
    let plan = |prediction: Prediction, ep: &Episode, obs: &Observation| {
        let cfg = OracleConfig {
            prediction,
            ..OracleConfig::default()
        };
        let mut p = OraclePlanner::new(cfg, r.limits, r.footprint.clone(), ep.clone()).unwrap();
        p.plan(obs).unwrap().poses
    };
    let empty = episode("empty", ScenarioClass::CounterFlow, 0.0, vec![]);
    let blind = plan(Prediction::Recorded, &empty, &unseen);
    // Observed, the walker's recorded future is known: the plan is the oracle's, and the walker
    // changes it.
    let known = plan(Prediction::Seen, &ep, &seen);
    assert_eq!(known, plan(Prediction::Recorded, &ep, &seen));
    assert_ne!(known, blind);
    // Out of sight, it is not: the plan is the one of an empty world.
    assert_eq!(plan(Prediction::Seen, &ep, &unseen), blind);
    let cfg = OracleConfig {
        prediction: Prediction::Seen,
        ..OracleConfig::default()
    };
    let p = OraclePlanner::new(cfg, r.limits, r.footprint.clone(), ep).unwrap();
    assert_eq!(p.name(), "oracle-seen");
}
