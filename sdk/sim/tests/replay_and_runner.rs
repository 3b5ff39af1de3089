//! Pedestrian replay, the closed loop and the budget rule.

mod common;

use approx::assert_relative_eq;
use common::{episode, robot, robots, standing, walking};
use human2nav_core::{Limits, Observation, Plan, PlanError, Planner, Pose2};
use human2nav_sim::episode::{AgentTrack, ScenarioClass};
use human2nav_sim::replay::CrowdReplay;
use human2nav_sim::runner::{StartHeading, nearest_clearance};
use human2nav_sim::straight::{StraightConfig, StraightPlanner};
use human2nav_sim::{Outcome, SimConfig, run_episode};
use std::f64::consts::PI;

fn straight_for(r: &human2nav_sim::RobotSetup) -> StraightPlanner {
    StraightPlanner::new(StraightConfig {
        speed: r.limits.v_max,
        accel: r.limits.a_max,
        ..StraightConfig::default()
    })
    .expect("valid straight config")
}

#[test]
fn replay_interpolates_linearly_and_respects_presence() {
    let track = AgentTrack {
        id: 3,
        start_step: 2,
        positions: vec![[0.0, 0.0], [1.0, 0.0], [3.0, 1.0]],
        radius: 0.25,
    };
    let ep = episode("replay", ScenarioClass::CoFlow, 0.0, vec![track.clone()]);
    let replay = CrowdReplay::new(&ep);
    // Present on [0.2, 0.4] s only.
    assert!(replay.sample(&track, 0.1).is_none());
    assert!(replay.sample(&track, 0.41).is_none());
    let a = replay.sample(&track, 0.25).unwrap();
    assert_relative_eq!(a.position[0], 0.5, epsilon = 1e-12);
    assert_relative_eq!(a.velocity[0], 10.0, epsilon = 1e-9);
    let b = replay.sample(&track, 0.35).unwrap();
    assert_relative_eq!(b.position[0], 2.0, epsilon = 1e-12);
    assert_relative_eq!(b.position[1], 0.5, epsilon = 1e-12);
    assert_relative_eq!(b.velocity[0], 20.0, epsilon = 1e-9);
    assert_relative_eq!(b.velocity[1], 10.0, epsilon = 1e-9);
    // The final sample keeps the last segment's velocity.
    let c = replay.sample(&track, 0.4).unwrap();
    assert_relative_eq!(c.position[0], 3.0, epsilon = 1e-12);
    assert_relative_eq!(c.velocity[0], 20.0, epsilon = 1e-9);
    assert_relative_eq!(c.radius, 0.25);
    // Observation: history at the episode's step, oldest first, up to the current sample.
    let seen = replay.observe(0.35, [0.0, 0.0], 10.0, 2);
    assert_eq!(seen.len(), 1);
    assert_eq!(seen[0].history, vec![[0.0, 0.0], [1.0, 0.0]]);
    let seen = replay.observe(0.4, [0.0, 0.0], 10.0, 8);
    assert_eq!(seen[0].history.len(), 3);
    // Out of sensor range.
    assert!(replay.observe(0.4, [100.0, 0.0], 10.0, 2).is_empty());
    // The observed velocity is the last step's displacement, not the segment ahead: zero at the
    // first sample, (1, 0) m over 0.1 s at the second, half a step into the last segment the
    // move from 0.25 s to 0.35 s, at the final sample the last segment.
    let v = |t: f64| replay.observe(t, [0.0, 0.0], 10.0, 2)[0].velocity;
    assert_eq!(v(0.2), [0.0, 0.0]);
    assert_relative_eq!(v(0.3)[0], 10.0, epsilon = 1e-9);
    assert_relative_eq!(v(0.3)[1], 0.0, epsilon = 1e-9);
    assert_relative_eq!(v(0.25)[0], 10.0, epsilon = 1e-9);
    assert_relative_eq!(v(0.35)[0], 15.0, epsilon = 1e-9);
    assert_relative_eq!(v(0.35)[1], 5.0, epsilon = 1e-9);
    assert_relative_eq!(v(0.4)[0], 20.0, epsilon = 1e-9);
    assert_relative_eq!(v(0.4)[1], 10.0, epsilon = 1e-9);
    assert_relative_eq!(replay.end_time(), 0.4, epsilon = 1e-12);
}

#[test]
fn observation_reads_nothing_after_its_time() {
    // Two recordings equal up to 0.5 s and apart after it: whatever the planners see at or
    // before 0.5 s must be the same.
    let past: Vec<[f64; 2]> = (0..6).map(|k| [0.1 * k as f64, 0.05 * k as f64]).collect();
    let mut a = past.clone();
    a.extend([[0.6, 0.3], [0.7, 0.35]]);
    let mut b = past;
    b.extend([[0.4, 0.9], [-1.0, 2.0]]);
    let track = |positions| AgentTrack {
        id: 7,
        start_step: 0,
        positions,
        radius: 0.3,
    };
    let ep_a = episode("a", ScenarioClass::CoFlow, 0.0, vec![track(a)]);
    let ep_b = episode("b", ScenarioClass::CoFlow, 0.0, vec![track(b)]);
    let (ra, rb) = (CrowdReplay::new(&ep_a), CrowdReplay::new(&ep_b));
    for k in 0..=10 {
        let t = 0.05 * k as f64;
        assert_eq!(
            ra.observe(t, [0.0, 0.0], 10.0, 8),
            rb.observe(t, [0.0, 0.0], 10.0, 8),
            "t = {t}"
        );
    }
    assert_ne!(
        ra.observe(0.55, [0.0, 0.0], 10.0, 8),
        rb.observe(0.55, [0.0, 0.0], 10.0, 8)
    );
}

#[test]
fn single_sample_track_is_a_standing_pedestrian_for_one_instant() {
    let track = AgentTrack {
        id: 1,
        start_step: 5,
        positions: vec![[2.0, 1.0]],
        radius: 0.3,
    };
    let ep = episode("single", ScenarioClass::CoFlow, 0.0, vec![track.clone()]);
    let replay = CrowdReplay::new(&ep);
    let s = replay.sample(&track, 0.5).unwrap();
    assert_eq!(s.velocity, [0.0, 0.0]);
    assert!(replay.sample(&track, 0.6).is_none());
}

#[test]
fn sim_config_validation_names_the_field() {
    let ok = SimConfig::default();
    assert!(ok.validate().is_ok());
    assert_eq!(ok.replan_every(), 2);
    let bad = SimConfig {
        replan_hz: 7.0,
        ..SimConfig::default()
    };
    let err = bad.validate().unwrap_err().to_string();
    assert!(err.contains("replan_hz"), "{err}");
    let bad = SimConfig {
        goal_tolerance: 0.0,
        ..SimConfig::default()
    };
    assert!(
        bad.validate()
            .unwrap_err()
            .to_string()
            .contains("goal_tolerance")
    );
}

#[test]
fn empty_world_time_matches_closed_form() {
    let cfg = SimConfig::default();
    let limits = Limits {
        v_max: 1.5,
        v_reverse_max: 0.5,
        a_max: 1.0,
        omega_max: 2.0,
        kappa_max: None,
        lateral_speed_max: 0.05,
        coupled: None,
    };
    // 5 m, tolerance 0.3: 4.7 m, ramp v²/2a = 1.125 m < 4.7 → 4.7/1.5 + 1.5/2.
    let ep = episode("t", ScenarioClass::CoFlow, 1.0, vec![]);
    assert_relative_eq!(
        cfg.empty_world_time(&ep, &limits),
        4.7 / 1.5 + 0.75,
        epsilon = 1e-12
    );
    // Facing away with the episode's heading: + π / ω_max to turn in place.
    let cfg_ep = SimConfig {
        start_heading: StartHeading::Episode,
        ..SimConfig::default()
    };
    let away = episode("t", ScenarioClass::CoFlow, PI, vec![]);
    assert_relative_eq!(
        cfg_ep.empty_world_time(&away, &limits),
        4.7 / 1.5 + 0.75 + PI / 2.0,
        epsilon = 1e-12
    );
    // Short distance: never reaches v_max, t = sqrt(2d/a).
    let mut near = episode("t", ScenarioClass::CoFlow, 0.0, vec![]);
    near.goal = [1.0, 0.0];
    assert_relative_eq!(
        cfg.empty_world_time(&near, &limits),
        (2.0f64 * 0.7).sqrt(),
        epsilon = 1e-12
    );
    // The budget is the episode's when that is larger, else the rule.
    assert_relative_eq!(cfg.budget_for(&ep, &limits), 12.5);
    let mut tight = ep.clone();
    tight.time_budget = 1.0;
    assert_relative_eq!(
        cfg.budget_for(&tight, &limits),
        1.5 * (4.7 / 1.5 + 0.75) + 3.0,
        epsilon = 1e-12
    );
}

#[test]
fn start_faces_the_goal_by_default() {
    let mut ep = episode("h", ScenarioClass::CoFlow, 2.0, vec![]);
    ep.goal = [0.0, 5.0];
    assert_relative_eq!(
        SimConfig::default().start_pose(&ep).theta,
        PI / 2.0,
        epsilon = 1e-12
    );
    let cfg = SimConfig {
        start_heading: StartHeading::Episode,
        ..SimConfig::default()
    };
    assert_relative_eq!(cfg.start_pose(&ep).theta, 2.0);
}

/// Every robot reaches the goal of an empty world with the straight planner, no faster than the
/// physical lower bound and within the budget, from any goal direction.
#[test]
fn straight_planner_reaches_empty_world_goals_on_every_robot() {
    let cfg = SimConfig::default();
    for r in robots() {
        for k in 0..8 {
            let a = 2.0 * PI * k as f64 / 8.0;
            let mut ep = episode("empty", ScenarioClass::CoFlow, 0.0, vec![]);
            ep.goal = [5.0 * a.cos(), 5.0 * a.sin()];
            let mut planner = straight_for(&r);
            let run = run_episode(&ep, &r, &mut planner, &cfg);
            assert_eq!(
                run.outcome,
                Outcome::Success,
                "{} toward {a:.2} rad: {:?}",
                r.name,
                run.outcome
            );
            let lower = cfg.empty_world_time(&ep, &r.limits);
            assert!(
                run.end_time >= lower - cfg.dt,
                "{}: {} s beats the bound {lower} s",
                r.name,
                run.end_time
            );
            assert!(run.end_time <= run.budget);
            assert!(run.planner_errors.is_empty());
            assert_eq!(run.states.len(), run.commands.len() + 1);
            assert_eq!(run.clearance.len(), run.states.len());
        }
    }
}

#[test]
fn standing_pedestrian_on_the_line_is_a_collision() {
    let cfg = SimConfig::default();
    let r = robot("diablo");
    let ep = episode(
        "block",
        ScenarioClass::CounterFlow,
        0.0,
        vec![standing(42, [2.5, 0.0], 200)],
    );
    let run = run_episode(&ep, &r, &mut straight_for(&r), &cfg);
    assert_eq!(run.outcome, Outcome::Collision);
    let hit = run.contact.unwrap();
    assert_eq!(hit.pedestrian, 42);
    // The robot drives along +x into a pedestrian standing there since the start.
    assert!(hit.robot_closing > 0.0 && hit.robot_closing <= r.limits.v_max + 1e-9);
    assert_eq!(hit.pedestrian_closing, 0.0);
    assert_eq!(hit.pedestrian_speed, 0.0);
    assert!((hit.pedestrian_age - run.end_time).abs() < 1e-9);
    // The robot stops at the first step whose footprint overlaps: its centre within one step of
    // travel past the contact point 2.5 − 0.3 − r_footprint.
    let contact = 2.5 - 0.3 - r.footprint_radius;
    let x = run.states.last().unwrap().pose.x;
    assert!(
        x > contact && x <= contact + r.limits.v_max * cfg.dt + 1e-9,
        "x = {x}, contact at {contact}"
    );
    assert!(*run.clearance.last().unwrap() < 0.0);
}

#[test]
fn clearance_to_a_pedestrian_beside_the_path() {
    let cfg = SimConfig::default();
    let r = robot("diablo");
    let ep = episode(
        "beside",
        ScenarioClass::CrossFlow,
        0.0,
        vec![standing(1, [2.5, 3.0], 200)],
    );
    let run = run_episode(&ep, &r, &mut straight_for(&r), &cfg);
    assert_eq!(run.outcome, Outcome::Success);
    // The robot drives along y = 0: the closest approach is 3 − 0.3 − r, up to the sampling
    // (≤ 7.5 cm of travel per step changes the distance by < 1 mm at 3 m).
    let min = run.clearance.iter().copied().fold(f64::INFINITY, f64::min);
    assert_relative_eq!(min, 3.0 - 0.3 - r.footprint_radius, epsilon = 1e-3);
}

#[test]
fn collisions_use_the_urdf_footprint_not_the_planners_disc() {
    // A pedestrian standing still at (x, y) in the robot's frame (robot at the origin facing +x).
    let clearance = |name: &str, p: [f64; 2], theta: f64| {
        let r = robot(name);
        let ep = episode(
            "at",
            ScenarioClass::CrossFlow,
            0.0,
            vec![standing(1, p, 10)],
        );
        let present = CrowdReplay::new(&ep).at(0.0);
        nearest_clearance(&present, Pose2::new(0.0, 0.0, theta), &r.footprint).0
    };
    // go2: a 0.70 × 0.31 m box about the base link (planners' disc r = 0.383 m). 0.5 m to the
    // side is clear of the box (0.5 − 0.155 − 0.3) though inside the disc; 0.5 m ahead is not.
    assert_relative_eq!(clearance("go2", [0.0, 0.5], 0.0), 0.045, epsilon = 1e-9);
    assert_relative_eq!(clearance("go2", [0.5, 0.0], 0.0), -0.15, epsilon = 1e-9);
    // Turned by 90°, the same pedestrian ahead is beside the body.
    assert_relative_eq!(
        clearance("go2", [0.5, 0.0], std::f64::consts::FRAC_PI_2),
        0.045,
        epsilon = 1e-9
    );
    // ackermann: the 0.98 × 0.745 m body box lies 0.325 m ahead of the rear axle (disc r =
    // 0.896 m about the axle). 0.7 m behind the axle is 0.535 m behind the bumper.
    assert_relative_eq!(
        clearance("ackermann", [-0.7, 0.0], 0.0),
        0.235,
        epsilon = 1e-9
    );
    assert!(0.7 - 0.3 - robot("ackermann").footprint_radius < 0.0);
    // diablo: an upright cylinder about the base link, the same as its disc.
    let d = robot("diablo");
    assert_relative_eq!(
        clearance("diablo", [0.0, 1.0], 0.0),
        1.0 - 0.3 - d.footprint_radius,
        epsilon = 1e-9
    );
}

#[test]
fn pedestrian_leaving_early_is_no_longer_an_obstacle() {
    // The pedestrian stands on the line for 0.5 s only (6 samples): the robot passes later.
    let cfg = SimConfig::default();
    let r = robot("go2");
    let ep = episode(
        "gone",
        ScenarioClass::CounterFlow,
        0.0,
        vec![standing(1, [3.0, 0.0], 6)],
    );
    let run = run_episode(&ep, &r, &mut straight_for(&r), &cfg);
    assert_eq!(run.outcome, Outcome::Success);
    let walker = walking(2, [5.0, 0.0], [-1.0, 0.0], 150);
    let ep = episode("walker", ScenarioClass::CounterFlow, 0.0, vec![walker]);
    let run = run_episode(&ep, &r, &mut straight_for(&r), &cfg);
    assert_eq!(run.outcome, Outcome::Collision);
}

struct Failing {
    calls: usize,
    panic: bool,
}

impl Planner for Failing {
    fn name(&self) -> &str {
        "failing"
    }
    fn plan(&mut self, obs: &Observation) -> Result<Plan, PlanError> {
        self.calls += 1;
        if self.panic {
            panic!("boom at {}", obs.time);
        }
        Err(PlanError::Failed {
            planner: "failing".into(),
            message: "no".into(),
        })
    }
}

#[test]
fn planner_errors_and_panics_become_stop_in_place() {
    let cfg = SimConfig::default();
    let r = robot("diablo");
    let ep = episode("fail", ScenarioClass::CoFlow, 0.0, vec![]);
    for panic in [false, true] {
        let mut p = Failing { calls: 0, panic };
        let run = run_episode(&ep, &r, &mut p, &cfg);
        assert_eq!(run.outcome, Outcome::Timeout);
        assert_eq!(run.planner_errors.len(), p.calls);
        assert!(run.plans.iter().all(|p| p.fallback));
        // Replanned at 10 Hz over the whole budget.
        assert_eq!(p.calls, (run.budget / 0.1).round() as usize);
        let last = run.states.last().unwrap().pose;
        assert_relative_eq!(last.x, 0.0, epsilon = 1e-12);
        if panic {
            assert!(
                run.planner_errors[0].contains("boom"),
                "{}",
                run.planner_errors[0]
            );
        }
    }
}
