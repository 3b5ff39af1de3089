//! The reactive crowd: recorded paths with a social-force response to the robot.

mod common;

use approx::assert_relative_eq;
use common::{episode, robot, standing, walking};
use human2nav_core::{Observation, Plan, PlanError, Planner, Pose2};
use human2nav_sim::crowd::{Crowd, CrowdModel, SocialForce};
use human2nav_sim::episode::ScenarioClass;
use human2nav_sim::replay::CrowdReplay;
use human2nav_sim::straight::{StraightConfig, StraightPlanner};
use human2nav_sim::{Outcome, SimConfig, run_episode, run_episode_with};

/// A planner that keeps the robot where it is.
struct Standing;

impl Planner for Standing {
    fn name(&self) -> &str {
        "standing"
    }
    fn plan(&mut self, obs: &Observation) -> Result<Plan, PlanError> {
        Ok(Plan::stop_in_place(obs, 0.1, 32, "stand"))
    }
}

fn reactive() -> CrowdModel {
    CrowdModel::Reactive(SocialForce::default())
}

#[test]
fn a_replayed_crowd_is_the_recording() {
    let ep = episode(
        "r",
        ScenarioClass::CounterFlow,
        0.0,
        vec![
            walking(1, [6.0, 0.1], [-1.0, 0.0], 120),
            standing(2, [2.0, 2.0], 50),
        ],
    );
    let r = robot("diablo");
    let replay = CrowdReplay::new(&ep);
    let mut crowd = Crowd::new(&ep, &CrowdModel::Replay);
    for n in 1..200 {
        let t = n as f64 * 0.05;
        crowd.advance(t, &r.footprint, Pose2::new(4.0, 0.0, 0.0));
        assert_eq!(crowd.present(), replay.at(t).as_slice(), "t = {t}");
    }
    // run_episode is the replay.
    let cfg = SimConfig::default();
    let mut p = StraightPlanner::new(StraightConfig::default()).unwrap();
    let a = run_episode(&ep, &r, &mut p, &cfg);
    let mut p = StraightPlanner::new(StraightConfig::default()).unwrap();
    let b = run_episode_with(&ep, &r, &mut p, &cfg, &CrowdModel::Replay);
    assert_eq!(a.states, b.states);
    assert_eq!(a.outcome, b.outcome);
    assert!(a.crowd.is_none());
}

#[test]
fn a_pedestrian_walking_at_a_standing_robot_goes_around_it_and_back_to_its_path() {
    // Walks −x at 1.2 m/s along y = 0.15, straight through the robot standing at the origin.
    let ep = episode(
        "w",
        ScenarioClass::CounterFlow,
        0.0,
        vec![walking(1, [5.0, 0.15], [-1.2, 0.0], 125)],
    );
    let cfg = SimConfig::default();
    for name in ["diablo", "go2", "ackermann"] {
        let r = robot(name);
        let replayed = run_episode(&ep, &r, &mut Standing, &cfg);
        assert_eq!(replayed.outcome, Outcome::Collision, "{name}");
        let run = run_episode_with(&ep, &r, &mut Standing, &cfg, &reactive());
        assert_eq!(run.outcome, Outcome::Timeout, "{name}: {:?}", run.contact);
        let min = run.clearance.iter().copied().fold(f64::INFINITY, f64::min);
        assert!(min > 0.0 && min < 0.5, "{name}: closest {min}");
        // Every recorded state is within the speed cap (1.3 × 1.2 m/s).
        let states = run.crowd.as_ref().unwrap();
        assert_eq!(states.len(), run.clearance.len());
        for s in states.iter().flatten() {
            assert!(s.velocity[0].hypot(s.velocity[1]) <= 1.3 * 1.2 + 1e-9);
        }
        // Held up for about 2 s in front of the robot (the social force slows a head-on walker
        // more than it steers it), it walks back onto its path and catches up with its
        // recording at up to 1.3 times its speed.
        let lag = |n: usize| {
            let rec = CrowdReplay::new(&ep).at(n as f64 * cfg.dt)[0].position;
            let sim = states[n][0].position;
            (sim[0] - rec[0]).hypot(sim[1] - rec[1])
        };
        let last = (12.3 / cfg.dt).round() as usize;
        let worst = (0..=last).map(lag).fold(0.0, f64::max);
        let end = states[last][0].position;
        assert!((end[1] - 0.15).abs() < 0.02, "{name}: ends at {end:?}");
        assert!(
            lag(last) < 0.5 && lag(last) < 0.5 * worst,
            "{name}: lag {} at the end, {worst} at most",
            lag(last)
        );
    }
}

#[test]
fn pedestrians_far_from_the_robot_are_replayed_exactly() {
    let ep = episode(
        "far",
        ScenarioClass::CrossFlow,
        0.0,
        vec![walking(1, [0.0, 6.0], [1.0, 0.0], 100)],
    );
    let r = robot("go2");
    let replay = CrowdReplay::new(&ep);
    let mut crowd = Crowd::new(&ep, &reactive());
    for n in 1..150 {
        let t = n as f64 * 0.05;
        crowd.advance(t, &r.footprint, Pose2::new(0.0, 0.0, 0.0));
        assert_eq!(crowd.present(), replay.at(t).as_slice(), "t = {t}");
        let seen = crowd.observe([0.0, 0.0], 10.0, 8);
        assert_eq!(seen, replay.observe(t, [0.0, 0.0], 10.0, 8), "t = {t}");
    }
}

#[test]
fn a_displaced_pedestrian_is_observed_where_it_is() {
    // Standing 0.8 m in front of the robot, which stands still: pushed away from it.
    let ep = episode(
        "push",
        ScenarioClass::CounterFlow,
        0.0,
        vec![standing(1, [0.8, 0.0], 40)],
    );
    let r = robot("diablo");
    let mut crowd = Crowd::new(&ep, &reactive());
    for n in 1..=20 {
        crowd.advance(n as f64 * 0.05, &r.footprint, Pose2::new(0.0, 0.0, 0.0));
    }
    let p = crowd.present()[0];
    assert!(p.position[0] > 0.8 + 0.05, "{:?}", p.position);
    assert_relative_eq!(p.position[1], 0.0, epsilon = 1e-9);
    let seen = crowd.observe([0.0, 0.0], 10.0, 8);
    assert_eq!(seen.len(), 1);
    assert_eq!(seen[0].position, p.position);
    assert_eq!(seen[0].history.last(), Some(&p.position));
    assert_eq!(seen[0].history.len(), 8);
    // The first history entry is the recording (t = 0.3 s, before it had moved much).
    assert!(seen[0].history.windows(2).all(|w| w[1][0] >= w[0][0]));
}

#[test]
fn social_force_validation_names_the_field() {
    assert!(SocialForce::default().validate().is_ok());
    let bad = [
        (
            SocialForce {
                relaxation_time: 0.0,
                ..SocialForce::default()
            },
            "relaxation_time",
        ),
        (
            SocialForce {
                range: f64::NAN,
                ..SocialForce::default()
            },
            "range",
        ),
        (
            SocialForce {
                rear_weight: 1.5,
                ..SocialForce::default()
            },
            "rear_weight",
        ),
        (
            SocialForce {
                field_of_view_deg: 400.0,
                ..SocialForce::default()
            },
            "field_of_view_deg",
        ),
        (
            SocialForce {
                max_speed_factor: 0.5,
                ..SocialForce::default()
            },
            "max_speed_factor",
        ),
        (
            SocialForce {
                strength: 1e300,
                ..SocialForce::default()
            },
            "strength",
        ),
    ];
    for (f, field) in bad {
        assert_eq!(f.validate().unwrap_err().0, field);
    }
}
