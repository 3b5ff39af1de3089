//! Built-in embodiments: saturation, exact SE(2) stepping, and closed-loop tracking of feasible
//! trajectories in an empty world for the three shipped robots.

#![allow(clippy::unwrap_used)] // test helpers; a failed fixture should panic

use approx::assert_relative_eq;
use human2nav_core::embodiment::{
    BuiltinEmbodiment, Embodiment, EmbodimentKind, RobotState, plan_pose_at, plan_reference,
};
use human2nav_core::limits::{ControllerGains, Limits};
use human2nav_core::planner::{Plan, PlanInfo};
use human2nav_core::robot::RobotProfile;
use human2nav_core::se2::{Pose2, Twist2, wrap_angle};
use proptest::prelude::*;
use std::f64::consts::PI;
use std::path::Path;

/// Control period of every closed-loop test (s).
const DT: f64 = 0.05;
/// Waypoint spacing of the plans (s), the planner's.
const PLAN_DT: f64 = 0.1;

fn profile(name: &str) -> RobotProfile {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../robots")
        .join(name)
        .join("robot.toml");
    RobotProfile::load(&path).unwrap()
}

fn limits(kappa_max: Option<f64>) -> Limits {
    Limits {
        v_max: 1.5,
        v_reverse_max: 0.5,
        a_max: 1.0,
        omega_max: 2.0,
        kappa_max,
        lateral_speed_max: 0.4,
        coupled: None,
    }
}

fn embodiment(kind: EmbodimentKind, kappa_max: Option<f64>) -> BuiltinEmbodiment {
    BuiltinEmbodiment::new(kind, limits(kappa_max), ControllerGains::default())
}

fn at_rest() -> RobotState {
    RobotState::default()
}

fn moving(v: Twist2) -> RobotState {
    RobotState {
        pose: Pose2::IDENTITY,
        velocity: v,
    }
}

// ---------------------------------------------------------------------------------------------
// Saturation and stepping, closed forms
// ---------------------------------------------------------------------------------------------

#[test]
fn differential_drive_saturation() {
    let e = embodiment(EmbodimentKind::DifferentialDrive, None);
    // A long dt leaves the acceleration limit slack: speed box, no lateral, ω_max.
    let c = e.saturate(&at_rest(), Twist2::new(3.0, 0.5, 5.0), 10.0);
    assert_eq!(c, Twist2::new(1.5, 0.0, 2.0));
    let c = e.saturate(&at_rest(), Twist2::new(-3.0, 0.0, -5.0), 10.0);
    assert_eq!(c, Twist2::new(-0.5, 0.0, -2.0));
    // From rest within 0.1 s at a_max = 1: 0.1 m/s.
    let c = e.saturate(&at_rest(), Twist2::new(1.5, 0.0, 0.0), 0.1);
    assert_relative_eq!(c.vx, 0.1, epsilon = 1e-12);
    // Braking is limited too.
    let c = e.saturate(&moving(Twist2::new(1.0, 0.0, 0.0)), Twist2::ZERO, 0.2);
    assert_relative_eq!(c.vx, 0.8, epsilon = 1e-12);
    // Turning in place is allowed.
    let c = e.saturate(&at_rest(), Twist2::new(0.0, 0.0, 1.0), 0.1);
    assert_eq!(c, Twist2::new(0.0, 0.0, 1.0));
    // Non-finite commands become zero.
    let c = e.saturate(&at_rest(), Twist2::new(f64::NAN, 0.0, f64::INFINITY), 0.1);
    assert_eq!(c, Twist2::ZERO);
    assert!(!e.holonomic());
    assert_eq!(e.name(), "differential_drive");
}

#[test]
fn ackermann_saturation_respects_curvature() {
    let kappa = 0.625;
    let e = embodiment(EmbodimentKind::Ackermann, Some(kappa));
    // No turning in place.
    let c = e.saturate(&at_rest(), Twist2::new(0.0, 0.0, 1.0), 0.1);
    assert_eq!(c, Twist2::ZERO);
    // At 1 m/s the yaw rate is capped at κ_max·v.
    let c = e.saturate(
        &moving(Twist2::new(1.0, 0.0, 0.0)),
        Twist2::new(1.0, 0.0, 1.5),
        0.1,
    );
    assert_relative_eq!(c.omega, kappa * 1.0, epsilon = 1e-12);
    // Curvature applies to the velocity after the acceleration limit: 0 → 0.1 m/s.
    let c = e.saturate(&at_rest(), Twist2::new(1.0, 0.0, -1.0), 0.1);
    assert_relative_eq!(c.vx, 0.1, epsilon = 1e-12);
    assert_relative_eq!(c.omega, -kappa * 0.1, epsilon = 1e-12);
    // In reverse too.
    let c = e.saturate(
        &moving(Twist2::new(-0.4, 0.0, 0.0)),
        Twist2::new(-0.4, 0.0, 2.0),
        0.1,
    );
    assert_relative_eq!(c.omega, kappa * 0.4, epsilon = 1e-12);
}

#[test]
fn omnidirectional_saturation() {
    let e = embodiment(EmbodimentKind::Omnidirectional, None);
    assert!(e.holonomic());
    let c = e.saturate(&at_rest(), Twist2::new(0.0, 2.0, 0.0), 10.0);
    assert_eq!(c, Twist2::new(0.0, 0.4, 0.0));
    // The acceleration limit is on the norm of (Δv_x, Δv_y) and keeps the direction.
    let c = e.saturate(&at_rest(), Twist2::new(0.3, 0.4, 0.0), 0.1);
    assert_relative_eq!(c.vx, 0.06, epsilon = 1e-12);
    assert_relative_eq!(c.vy, 0.08, epsilon = 1e-12);
}

#[test]
fn step_integrates_exactly_on_se2() {
    let e = embodiment(EmbodimentKind::DifferentialDrive, None);
    // Quarter circle of radius 2/π... v = 1, ω = π/2 for 1 s ends at (2/π, 2/π, π/2).
    let cmd = Twist2::new(1.0, 0.0, PI / 2.0);
    let one = e.step(&at_rest(), cmd, 1.0);
    let mut many = at_rest();
    for _ in 0..20 {
        many = e.step(&many, cmd, 0.05);
    }
    for s in [one, many] {
        assert_relative_eq!(s.pose.x, 2.0 / PI, epsilon = 1e-12);
        assert_relative_eq!(s.pose.y, 2.0 / PI, epsilon = 1e-12);
        assert_relative_eq!(s.pose.theta, PI / 2.0, epsilon = 1e-12);
        assert_eq!(s.velocity, cmd);
    }
    // A differential drive cannot move sideways even when told to.
    let s = e.step(&at_rest(), Twist2::new(0.0, 1.0, 0.0), 1.0);
    assert_eq!(s.pose, Pose2::IDENTITY);
    // An omnidirectional robot can.
    let o = embodiment(EmbodimentKind::Omnidirectional, None);
    let s = o.step(&at_rest(), Twist2::new(0.0, 0.3, 0.0), 2.0);
    assert_relative_eq!(s.pose.y, 0.6, epsilon = 1e-12);
}

fn arb_kind() -> impl Strategy<Value = EmbodimentKind> {
    prop_oneof![
        Just(EmbodimentKind::DifferentialDrive),
        Just(EmbodimentKind::Ackermann),
        Just(EmbodimentKind::Omnidirectional)
    ]
}

proptest! {
    /// From any state within the limits, a saturated command is within every limit and within
    /// a_max·dt of the current velocity.
    #[test]
    fn saturated_commands_respect_every_limit(
        kind in arb_kind(),
        v0 in (-0.5f64..1.5, -0.4f64..0.4, -2.0f64..2.0),
        cmd in (-10.0f64..10.0, -10.0f64..10.0, -10.0f64..10.0),
        dt in 0.001f64..1.0,
    ) {
        let kappa = (kind == EmbodimentKind::Ackermann).then_some(0.625);
        let e = embodiment(kind, kappa);
        let l = limits(kappa);
        let vy0 = if kind.holonomic() { v0.1 } else { 0.0 };
        let state = moving(Twist2::new(v0.0, vy0, v0.2));
        let c = e.saturate(&state, Twist2::new(cmd.0, cmd.1, cmd.2), dt);
        let tol = 1e-12;
        prop_assert!(c.vx <= l.v_max + tol && c.vx >= -l.v_reverse_max - tol);
        prop_assert!(c.vy.abs() <= l.lateral_speed_max + tol);
        prop_assert!(c.omega.abs() <= l.omega_max + tol);
        prop_assert!((c.vx - state.velocity.vx).hypot(c.vy - state.velocity.vy) <= l.a_max * dt + 1e-9);
        if !kind.holonomic() {
            prop_assert_eq!(c.vy, 0.0);
        }
        if let Some(k) = l.kappa_max {
            prop_assert!(c.omega.abs() <= k * c.vx.hypot(c.vy) + tol);
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Plan references
// ---------------------------------------------------------------------------------------------

fn plan_of(poses: Vec<Pose2>, dt: f64) -> Plan {
    Plan {
        t0: 0.0,
        dt,
        poses,
        info: PlanInfo::default(),
    }
}

#[test]
fn reference_of_a_constant_twist_plan_is_that_twist() {
    let xi = Twist2::new(0.8, 0.1, 0.4);
    let poses = (0..30)
        .map(|k| Pose2::exp(xi.scale(k as f64 * PLAN_DT)))
        .collect();
    let plan = plan_of(poses, PLAN_DT);
    for &t in &[0.0, 0.37, 1.0, 2.5] {
        let (pose, twist) = plan_reference(&plan, t, 0.1).unwrap();
        let exact = Pose2::exp(xi.scale(t));
        assert_relative_eq!(pose.x, exact.x, epsilon = 1e-12);
        assert_relative_eq!(pose.y, exact.y, epsilon = 1e-12);
        assert_relative_eq!(pose.theta, exact.theta, epsilon = 1e-12);
        assert_relative_eq!(twist.vx, xi.vx, epsilon = 1e-9);
        assert_relative_eq!(twist.vy, xi.vy, epsilon = 1e-9);
        assert_relative_eq!(twist.omega, xi.omega, epsilon = 1e-9);
    }
    // After the end: the last pose, at rest.
    let (pose, twist) = plan_reference(&plan, 100.0, 0.1).unwrap();
    assert_eq!(pose, plan_pose_at(&plan, plan.duration()).unwrap());
    assert_eq!(twist, Twist2::ZERO);
    assert!(plan_reference(&plan_of(vec![], PLAN_DT), 0.0, 0.1).is_none());
}

// ---------------------------------------------------------------------------------------------
// Closed-loop tracking
// ---------------------------------------------------------------------------------------------

/// A feasible S-curve for `kind` under `l`: a smooth start from rest (peak acceleration 70 % of
/// a_max), cruise at 70 % of v_max, yaw rate (or curvature, for Ackermann) weaving with 60 % of
/// its limit, plus a lateral weave at 60 % of the lateral limit for omnidirectional robots.
/// Integrated exactly at 1 ms and sampled every `PLAN_DT`.
fn s_curve(kind: EmbodimentKind, l: &Limits, duration: f64) -> Plan {
    let v_c = 0.7 * l.v_max;
    let t_ramp = v_c * PI / (2.0 * 0.7 * l.a_max);
    let period = 8.0;
    let twist = |t: f64| {
        let s = if t < t_ramp {
            0.5 * (1.0 - (PI * t / t_ramp).cos())
        } else {
            1.0
        };
        let v = v_c * s;
        let wave = (2.0 * PI * t / period).sin();
        let omega = match (kind, l.kappa_max) {
            (EmbodimentKind::Ackermann, Some(k)) => v * 0.6 * k * wave,
            _ => 0.6 * l.omega_max * s * wave,
        };
        let vy = if kind.holonomic() {
            0.6 * l.lateral_speed_max * s * (2.0 * PI * t / 5.0).sin()
        } else {
            0.0
        };
        Twist2::new(v, vy, omega.clamp(-0.9 * l.omega_max, 0.9 * l.omega_max))
    };
    let fine = 0.001;
    let per_sample = (PLAN_DT / fine).round() as usize;
    let samples = (duration / PLAN_DT).round() as usize + 1;
    let mut poses = Vec::with_capacity(samples);
    let mut pose = Pose2::IDENTITY;
    let mut t = 0.0;
    for _ in 0..samples {
        poses.push(pose);
        for _ in 0..per_sample {
            pose = pose.euler_step(twist(t + 0.5 * fine), fine);
            t += fine;
        }
    }
    plan_of(poses, PLAN_DT)
}

/// Errors of one closed-loop run.
#[derive(Debug)]
struct Tracking {
    /// Largest position error after the transient (m).
    max_position_error: f64,
    /// Largest heading error after the transient (rad).
    max_heading_error: f64,
    /// Position error at the end of the transient (m).
    initial_position_error: f64,
    /// Executed TFS of the controller's commands before saturation, over the whole run.
    executed_tfs: f64,
}

fn run(
    e: &dyn Embodiment,
    limits: &Limits,
    plan: &Plan,
    start: RobotState,
    transient: f64,
) -> Tracking {
    let steps = (plan.duration() / DT).round() as usize;
    let mut state = start;
    let mut out = Tracking {
        max_position_error: 0.0,
        max_heading_error: 0.0,
        initial_position_error: 0.0,
        executed_tfs: 0.0,
    };
    let mut raw = Vec::with_capacity(steps);
    for k in 0..steps {
        let t = k as f64 * DT;
        let cmd = e.track(&state, plan, t);
        assert!(cmd.is_finite());
        raw.push(cmd);
        let cmd = e.saturate(&state, cmd, DT);
        state = e.step(&state, cmd, DT);
        let target = plan_pose_at(plan, t + DT).unwrap();
        let pos = (state.pose.x - target.x).hypot(state.pose.y - target.y);
        let head = wrap_angle(state.pose.theta - target.theta).abs();
        if t + DT >= transient {
            if out.max_position_error == 0.0 {
                out.initial_position_error = pos;
            }
            out.max_position_error = out.max_position_error.max(pos);
            out.max_heading_error = out.max_heading_error.max(head);
        }
    }
    out.executed_tfs = human2nav_core::tfs::tfs_executed(&raw, DT, limits);
    out
}

/// Starting on the plan, the position error stays below 1 cm and the heading error below
/// 0.01 rad throughout. Starting 0.3 m to the side, 0.1 m behind and 0.2 rad off, both are below
/// 2 cm and 0.02 rad once a 5 s transient is over (a non-holonomic robot can only correct a
/// lateral offset by turning while moving, and the plan starts from rest). In both runs every
/// command the controller asks for is within the robot's limits (executed TFS 1): the plan is,
/// and the feedback is bounded by what the plan leaves (`bound_feedback`).
fn check_tracking(robot: &str) {
    let transient = 5.0;
    let p = profile(robot);
    let e = p.builtin_embodiment().unwrap();
    let kind = match p.embodiment {
        human2nav_core::robot::EmbodimentSpec::Builtin(k) => k,
        human2nav_core::robot::EmbodimentSpec::Plugin(_) => unreachable!(),
    };
    let plan = s_curve(kind, &p.limits, 24.0);

    let on = run(e.as_ref(), &p.limits, &plan, RobotState::default(), 0.0);
    eprintln!("{robot}: from the plan's start: {on:?}");
    assert!(on.max_position_error < 0.01, "{robot}: {on:?}");
    assert!(on.max_heading_error < 0.01, "{robot}: {on:?}");
    assert_eq!(on.executed_tfs, 1.0, "{robot}: {on:?}");

    let start = RobotState {
        pose: Pose2::new(-0.1, 0.3, 0.2),
        velocity: Twist2::ZERO,
    };
    let off = run(e.as_ref(), &p.limits, &plan, start, transient);
    eprintln!("{robot}: from 0.32 m / 0.2 rad off, after {transient} s: {off:?}");
    assert!(off.max_position_error < 0.02, "{robot}: {off:?}");
    assert!(off.max_heading_error < 0.02, "{robot}: {off:?}");
    assert_eq!(off.executed_tfs, 1.0, "{robot}: {off:?}");
}

#[test]
fn differential_drive_tracks_an_s_curve() {
    check_tracking("diablo");
}

#[test]
fn quadruped_tracks_an_s_curve() {
    check_tracking("go2");
}

#[test]
fn ackermann_tracks_an_s_curve() {
    check_tracking("ackermann");
}

/// The planner's stop-in-place fallback (every pose equal to the current one) brings a moving
/// robot to rest near the pose where the plan was made.
#[test]
fn stop_in_place_plan_brings_every_robot_to_rest() {
    for robot in ["diablo", "go2", "ackermann"] {
        let p = profile(robot);
        let e = p.builtin_embodiment().unwrap();
        let v0 = 0.8 * p.limits.v_max;
        let start = RobotState {
            pose: Pose2::new(1.0, 2.0, 0.5),
            velocity: Twist2::new(v0, 0.0, 0.0),
        };
        let plan = Plan {
            t0: 0.0,
            dt: PLAN_DT,
            poses: vec![start.pose; 32],
            info: PlanInfo::default(),
        };
        let mut state = start;
        let mut farthest: f64 = 0.0;
        for k in 0..200 {
            let t = k as f64 * DT;
            let cmd = e.saturate(&state, e.track(&state, &plan, t), DT);
            state = e.step(&state, cmd, DT);
            farthest = farthest.max((state.pose.x - 1.0).hypot(state.pose.y - 2.0));
        }
        let speed = state.velocity.vx.hypot(state.velocity.vy);
        let dist = (state.pose.x - 1.0).hypot(state.pose.y - 2.0);
        eprintln!(
            "{robot}: after 10 s speed {speed:.2e} m/s, ω {:.2e} rad/s, {dist:.3} m from the stop pose (farthest {farthest:.3} m)",
            state.velocity.omega
        );
        assert!(speed < 1e-3, "{robot}: still moving at {speed} m/s");
        assert!(state.velocity.omega.abs() < 1e-3, "{robot}: still turning");
        // Braking from v0 at a_max takes v0²/(2·a_max); the controller may not go much beyond.
        let braking = v0 * v0 / (2.0 * p.limits.a_max);
        assert!(
            farthest < braking + 0.1,
            "{robot}: went {farthest} m, braking distance {braking} m"
        );
        assert!(
            dist < 0.05,
            "{robot}: came to rest {dist} m from the stop pose"
        );
    }
}

/// Receding-horizon use as in the simulator: every 0.1 s a new plan starts at the robot's pose
/// and accelerates from its current speed at 90 % of `a_max` (the first segment half a step of
/// ramp, as the planner's last-step correction plans it). The controller's commands before
/// saturation, at the 20 Hz control rate, must then change no faster than `a_max` (executed
/// TFS 1): the feed-forward interpolates between segment midpoints from the current velocity.
#[test]
fn replanned_accelerating_plans_give_commands_within_a_max() {
    use human2nav_core::tfs::tfs_executed;
    for kind in [
        EmbodimentKind::DifferentialDrive,
        EmbodimentKind::Omnidirectional,
        EmbodimentKind::Ackermann,
    ] {
        let l = limits(Some(0.5));
        let e = BuiltinEmbodiment::new(kind, l, ControllerGains::default());
        let mut state = at_rest();
        let mut raw = Vec::new();
        let mut plan = plan_of(vec![Pose2::IDENTITY], PLAN_DT);
        for k in 0..60 {
            let t = k as f64 * DT;
            if k % 2 == 0 {
                // Mean segment speeds of a ramp at 0.9·a_max from the current speed, capped.
                let a = 0.9 * l.a_max;
                let mut pose = state.pose;
                let mut poses = vec![pose];
                for j in 0..32 {
                    let v = (state.velocity.vx + a * (j as f64 + 0.5) * PLAN_DT).min(0.9 * l.v_max);
                    pose = pose.euler_step(Twist2::new(v, 0.0, 0.0), PLAN_DT);
                    poses.push(pose);
                }
                plan = Plan {
                    t0: t,
                    ..plan_of(poses, PLAN_DT)
                };
            }
            let cmd = e.track(&state, &plan, t);
            raw.push(cmd);
            state = e.step(&state, e.saturate(&state, cmd, DT), DT);
        }
        assert!(
            state.velocity.vx > 1.2,
            "{kind:?}: reached {:?}",
            state.velocity
        );
        let tfs = tfs_executed(&raw, DT, &l);
        assert_eq!(tfs, 1.0, "{kind:?}: executed TFS {tfs}");
    }
}

/// `bound_feedback` clips the feedback at every limit the feed-forward respects, and lets a
/// feed-forward that exceeds a limit through (so the executed TFS still counts it).
#[test]
fn feedback_is_bounded_by_the_limits_the_plan_respects() {
    use human2nav_core::embodiment::bound_feedback;
    use human2nav_core::tfs::{TFS_TOLERANCE, check};
    let h = DT;
    let current = Twist2::new(1.0, 0.1, 0.3);
    // A feasible feed-forward and a large feedback in every direction, with and without a
    // coupled limit (1.02 + 0.5·0.1 + 0.345·0.3 = 1.17 ≤ 1.25: the feed-forward respects it).
    let ff = Twist2::new(1.02, 0.1, 0.3);
    let tracks = human2nav_core::CoupledLimit {
        v: 1.0,
        lateral: 0.5,
        omega: 0.345,
        max: 1.25,
    };
    let coupled = Limits {
        coupled: Some(tracks),
        ..limits(Some(0.5))
    };
    for (l, fb) in [limits(Some(0.5)), coupled].into_iter().flat_map(|l| {
        [
            Twist2::new(2.0, 1.0, 3.0),
            Twist2::new(-2.0, -1.0, -3.0),
            Twist2::new(0.3, -0.6, 0.9),
            Twist2::new(0.0, 0.0, 2.0),
        ]
        .map(|fb| (l, fb))
    }) {
        let cmd = Twist2::new(ff.vx + fb.vx, ff.vy + fb.vy, ff.omega + fb.omega);
        let out = bound_feedback(cmd, ff, current, &l, h);
        let a = (out.vx - current.vx) / h;
        let v = check(out.vx, out.vy, out.omega, Some(a), &l, TFS_TOLERANCE);
        assert!(v.feasible(), "{fb:?} -> {out:?}: {v:?}");
        // ... and the robot would not have to shorten it (it limits the change in norm).
        let step = (out.vx - current.vx).hypot(out.vy - current.vy);
        assert!(
            step <= l.a_max * h + 1e-12,
            "{fb:?} -> {out:?}: step {step}"
        );
    }
    let l = coupled;
    // A command inside every bound is left alone.
    let inside = Twist2::new(1.01, 0.07, 0.2);
    assert_eq!(bound_feedback(inside, ff, current, &l, h), inside);
    // A feed-forward above v_max, a step faster than a_max and a turn sharper than κ_max
    // passes through unchanged.
    let over = Twist2::new(1.8, 0.1, 1.7);
    assert_eq!(bound_feedback(over, over, current, &l, h), over);
    assert!(!check(over.vx, over.vy, over.omega, None, &l, TFS_TOLERANCE).feasible());
    // Non-finite input is not the bound's business.
    let nan = Twist2::new(f64::NAN, 0.0, 0.0);
    assert!(!bound_feedback(nan, ff, current, &l, h).is_finite());
}
