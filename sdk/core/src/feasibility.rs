//! The trajectory feasibility score (TFS): the fraction of waypoints that satisfy every hard
//! limit of the robot.
//!
//! # Plan TFS
//!
//! For a plan of `T` poses at step `dt` (pose 0 is the robot's pose at the planning instant),
//! waypoint `k = 1 … T−1` is **feasible** iff segment `k − 1` (from pose `k−1` to pose `k`, with
//! the finite differences of [`crate::trajectory`]) satisfies
//!
//! * `v ≤ v_max` (forward) and `−v ≤ v_reverse_max` (reverse),
//! * `|ω| ≤ ω_max`,
//! * `|vy| ≤ lateral_speed_max`,
//! * `|κ| ≤ κ_max` when the robot has a curvature limit,
//! * `a·|v| + b·|vy| + c·|ω| ≤ max` when the embodiment declares a coupled limit
//!   ([`crate::limits::CoupledLimit`], e.g. a tracked base's track speed),
//!
//! and the acceleration ending at segment `k − 1` satisfies `|a| ≤ a_max`: for `k = 1` that is
//! the initial acceleration `(v_0 − v_init)/dt` from the current speed, for `k ≥ 2`
//! `(v_{k−1} − v_{k−2})/dt`. Every comparison has the relative tolerance [`TFS_TOLERANCE`]
//! (`q ≤ (1 + 0.02)·limit`), which absorbs finite-difference and resampling noise without
//! accepting a real violation. `TFS = feasible / (T − 1)`.
//!
//! # Executed TFS
//!
//! For the commands the planner's tracking controller asked for (before saturation), command
//! `j` is feasible iff `v_x ≤ v_max`, `−v_x ≤ v_reverse_max`, `|ω| ≤ ω_max`,
//! `|v_y| ≤ lateral_speed_max`, `|κ| = |ω|/sqrt(v_x² + ε_κ²) ≤ κ_max` (when limited), the
//! coupled limit (when declared) and, for
//! `j ≥ 1`, `|v_x,j − v_x,j−1|/dt ≤ a_max`, with the same tolerance. The paper reports
//! `min(plan TFS, executed TFS)` ([`tfs_min`]).
//!
//! Non-finite values are never feasible.

use crate::limits::Limits;
use crate::se2::{Pose2, Twist2};
use crate::trajectory::{curvature, segment_values};

/// Relative tolerance of every TFS comparison: a quantity is within its limit when
/// `|q| ≤ (1 + TFS_TOLERANCE)·limit` (2 %).
pub const TFS_TOLERANCE: f64 = 0.02;

/// How many limits TFS checks ([`Violations::NAMES`]).
pub const LIMIT_COUNT: usize = 7;

/// Which limits one waypoint (or command) violates.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Violations {
    /// The forward speed `v` exceeds `v_max` (beyond the check's tolerance, as every flag).
    pub speed: bool,
    /// The reverse speed `−v` exceeds `v_reverse_max`.
    pub reverse: bool,
    /// `|a|`, the longitudinal acceleration, exceeds `a_max` (false where none is checked).
    pub acceleration: bool,
    /// `|ω|` exceeds `omega_max`.
    pub yaw_rate: bool,
    /// `|κ|` exceeds `kappa_max` (never set for a robot without a curvature limit).
    pub curvature: bool,
    /// The body-frame lateral speed `|v_y|` exceeds `lateral_speed_max`.
    pub lateral: bool,
    /// The coupled limit `a·|v| + b·|vy| + c·|ω| ≤ max` is exceeded (never set without one).
    pub coupled: bool,
}

impl Violations {
    /// The limits' names, in the order of [`Self::flags`] and [`Self::count`].
    pub const NAMES: [&'static str; LIMIT_COUNT] = [
        "speed",
        "reverse",
        "acceleration",
        "yaw_rate",
        "curvature",
        "lateral",
        "coupled",
    ];

    /// Which limits are violated, in the order of [`Self::NAMES`].
    pub fn flags(&self) -> [bool; LIMIT_COUNT] {
        [
            self.speed,
            self.reverse,
            self.acceleration,
            self.yaw_rate,
            self.curvature,
            self.lateral,
            self.coupled,
        ]
    }

    /// How many of `violations` break each limit, in the order of [`Self::NAMES`].
    pub fn count(violations: &[Violations]) -> [usize; LIMIT_COUNT] {
        let mut out = [0; LIMIT_COUNT];
        for v in violations {
            for (n, f) in out.iter_mut().zip(v.flags()) {
                *n += usize::from(f);
            }
        }
        out
    }

    /// True when no limit is violated.
    pub fn feasible(&self) -> bool {
        !self.flags().contains(&true)
    }
}

/// `q ≤ (1 + tol)·limit`, false for NaN.
#[inline]
fn within(q: f64, limit: f64, tol: f64) -> bool {
    q <= limit * (1.0 + tol)
}

/// Checks one motion sample `(v, vy, ω, a)` against the limits with relative tolerance `tol`
/// (`a = None`: no acceleration to check).
pub fn check(v: f64, vy: f64, omega: f64, a: Option<f64>, limits: &Limits, tol: f64) -> Violations {
    Violations {
        speed: !within(v, limits.v_max, tol),
        reverse: !within(-v, limits.v_reverse_max, tol),
        acceleration: a.is_some_and(|a| !within(a.abs(), limits.a_max, tol)),
        yaw_rate: !within(omega.abs(), limits.omega_max, tol),
        curvature: limits
            .kappa_max
            .is_some_and(|k| !within(curvature(v, omega).abs(), k, tol)),
        lateral: !within(vy.abs(), limits.lateral_speed_max, tol),
        coupled: limits
            .coupled
            .is_some_and(|c| !within(c.value(v, vy, omega), c.max, tol)),
    }
}

/// Per-waypoint violations of a plan on flat `[T, 3]` poses, written into `out` (cleared
/// first; `T − 1` entries, `out[k − 1]` for waypoint `k`). Allocation-free once `out` has the
/// capacity.
pub fn plan_violations_into(
    poses: &[f64],
    dt: f64,
    limits: &Limits,
    initial_velocity: Twist2,
    tol: f64,
    out: &mut Vec<Violations>,
) {
    out.clear();
    let t = poses.len() / 3;
    let mut prev_v = initial_velocity.vx;
    for i in 0..t.saturating_sub(1) {
        let (v, vy, w) = segment_values(&poses[3 * i..3 * i + 3], &poses[3 * i + 3..3 * i + 6], dt);
        out.push(check(v, vy, w, Some((v - prev_v) / dt), limits, tol));
        prev_v = v;
    }
}

/// Per-waypoint violations of a plan (`T − 1` entries, entry `k − 1` for waypoint `k`).
pub fn plan_violations(
    poses: &[Pose2],
    dt: f64,
    limits: &Limits,
    initial_velocity: Twist2,
) -> Vec<Violations> {
    let flat: Vec<f64> = poses.iter().flat_map(|p| p.to_array()).collect();
    let mut out = Vec::with_capacity(poses.len());
    plan_violations_into(&flat, dt, limits, initial_velocity, TFS_TOLERANCE, &mut out);
    out
}

/// Per-pose feasibility for figures (feasible green, infeasible red): `T` entries, entry 0 (the
/// current pose, not a decision) always true, entry `k ≥ 1` the feasibility of waypoint `k`.
pub fn feasibility_mask(
    poses: &[Pose2],
    dt: f64,
    limits: &Limits,
    initial_velocity: Twist2,
) -> Vec<bool> {
    let mut mask = Vec::with_capacity(poses.len());
    if !poses.is_empty() {
        mask.push(true);
    }
    mask.extend(
        plan_violations(poses, dt, limits, initial_velocity)
            .iter()
            .map(Violations::feasible),
    );
    mask
}

/// TFS of a plan whose pose 0 is the robot's pose at the planning instant, moving at
/// `initial_velocity`. A plan with fewer than two poses has no waypoint and scores 1.
pub fn tfs_plan(poses: &[Pose2], dt: f64, limits: &Limits, initial_velocity: Twist2) -> f64 {
    let v = plan_violations(poses, dt, limits, initial_velocity);
    fraction(v.iter().filter(|x| x.feasible()).count(), v.len())
}

/// TFS of a plan on flat `[T, 3]` poses (see [`tfs_plan`]), reusing `scratch`.
pub fn tfs_plan_flat(
    poses: &[f64],
    dt: f64,
    limits: &Limits,
    initial_velocity: Twist2,
    scratch: &mut Vec<Violations>,
) -> f64 {
    plan_violations_into(poses, dt, limits, initial_velocity, TFS_TOLERANCE, scratch);
    fraction(
        scratch.iter().filter(|x| x.feasible()).count(),
        scratch.len(),
    )
}

/// Per-command violations of a sequence of commanded body twists at step `dt`.
pub fn command_violations(commands: &[Twist2], dt: f64, limits: &Limits) -> Vec<Violations> {
    commands
        .iter()
        .enumerate()
        .map(|(j, c)| {
            let a = (j > 0).then(|| (c.vx - commands[j - 1].vx) / dt);
            check(c.vx, c.vy, c.omega, a, limits, TFS_TOLERANCE)
        })
        .collect()
}

/// Executed TFS: the fraction of commanded twists (before saturation) within every limit.
/// An empty command list scores 1.
pub fn tfs_executed(commands: &[Twist2], dt: f64, limits: &Limits) -> f64 {
    let v = command_violations(commands, dt, limits);
    fraction(v.iter().filter(|x| x.feasible()).count(), v.len())
}

/// The score the paper reports: the minimum of the plan and the executed TFS.
pub fn tfs_min(plan: f64, executed: f64) -> f64 {
    plan.min(executed)
}

fn fraction(feasible: usize, total: usize) -> f64 {
    if total == 0 {
        1.0
    } else {
        feasible as f64 / total as f64
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;

    fn limits(kappa: Option<f64>) -> Limits {
        Limits {
            v_max: 1.0,
            v_reverse_max: 0.3,
            a_max: 1.0,
            omega_max: 1.0,
            kappa_max: kappa,
            lateral_speed_max: 0.05,
            coupled: None,
        }
    }

    /// Integrates the body twists `w[k]` (one per segment) from the identity.
    fn integrate(w: &[Twist2], dt: f64) -> Vec<Pose2> {
        let mut poses = vec![Pose2::IDENTITY];
        for tw in w {
            let last = poses[poses.len() - 1];
            poses.push(last.euler_step(*tw, dt));
        }
        poses
    }

    #[test]
    fn constant_feasible_motion_scores_one() {
        let poses = integrate(&[Twist2::new(0.8, 0.0, 0.3); 31], 0.1);
        assert_relative_eq!(
            tfs_plan(&poses, 0.1, &limits(Some(1.0)), Twist2::new(0.8, 0.0, 0.3)),
            1.0
        );
        assert!(
            feasibility_mask(&poses, 0.1, &limits(None), Twist2::new(0.8, 0.0, 0.0))
                .iter()
                .all(|&m| m)
        );
    }

    #[test]
    fn speed_violation_closed_form() {
        // 10 segments at 0.9 m/s, then 10 at 1.5 m/s (v_max = 1): the speed jump at waypoint 11
        // is a 6 m/s² acceleration, so waypoints 11 … 20 fail: TFS = 10/20.
        let mut w = vec![Twist2::new(0.9, 0.0, 0.0); 10];
        w.extend(vec![Twist2::new(1.5, 0.0, 0.0); 10]);
        let poses = integrate(&w, 0.1);
        let v0 = Twist2::new(0.9, 0.0, 0.0);
        assert_relative_eq!(tfs_plan(&poses, 0.1, &limits(None), v0), 0.5);
        let viol = plan_violations(&poses, 0.1, &limits(None), v0);
        assert!(viol[10].speed && viol[10].acceleration);
        assert!(viol[11].speed && !viol[11].acceleration);
        let mask = feasibility_mask(&poses, 0.1, &limits(None), v0);
        assert_eq!(mask.len(), 21);
        assert!(mask[..11].iter().all(|&m| m) && mask[11..].iter().all(|&m| !m));
    }

    #[test]
    fn tolerance_is_two_percent() {
        let v0 = Twist2::new(1.0, 0.0, 0.0);
        let just_in = integrate(&[Twist2::new(1.019, 0.0, 0.0); 5], 0.1);
        let just_out = integrate(&[Twist2::new(1.021, 0.0, 0.0); 5], 0.1);
        // The 0.19 m/s² initial acceleration is well within a_max.
        assert_relative_eq!(tfs_plan(&just_in, 0.1, &limits(None), v0), 1.0);
        assert_relative_eq!(tfs_plan(&just_out, 0.1, &limits(None), v0), 0.0);
    }

    #[test]
    fn each_limit_type_is_detected() {
        let dt = 0.1;
        let l = limits(Some(0.5));
        type Which = fn(&Violations) -> bool;
        let cases: [(Twist2, Which); 5] = [
            (Twist2::new(-0.5, 0.0, 0.0), |v| v.reverse),
            (Twist2::new(0.5, 0.0, 1.5), |v| v.yaw_rate),
            (Twist2::new(0.5, 0.0, 0.5), |v| v.curvature),
            (Twist2::new(0.5, 0.2, 0.0), |v| v.lateral),
            (Twist2::new(1.2, 0.0, 0.0), |v| v.speed),
        ];
        for (tw, which) in cases {
            let poses = integrate(&[tw; 4], dt);
            let viol = plan_violations(&poses, dt, &l, tw);
            assert!(viol.iter().all(which), "{tw:?}: {viol:?}");
            assert_relative_eq!(tfs_plan(&poses, dt, &l, tw), 0.0);
        }
        // A coupled limit |v| + 0.5·|ω| ≤ 1: each of v = 0.8 and ω = 0.8 is within its own
        // limit, together they are not; v = 0.5 with ω = 0.8 is fine.
        let mut coupled = limits(None);
        coupled.coupled = Some(crate::limits::CoupledLimit {
            v: 1.0,
            lateral: 0.0,
            omega: 0.5,
            max: 1.0,
        });
        for (tw, over) in [
            (Twist2::new(0.8, 0.0, 0.8), true),
            (Twist2::new(0.5, 0.0, 0.8), false),
        ] {
            let poses = integrate(&[tw; 4], dt);
            let viol = plan_violations(&poses, dt, &coupled, tw);
            assert!(viol.iter().all(|v| v.coupled == over), "{tw:?}: {viol:?}");
            assert!(
                viol.iter().all(|v| !(v.speed || v.yaw_rate)),
                "{tw:?}: {viol:?}"
            );
            assert!(
                plan_violations(&poses, dt, &limits(None), tw)
                    .iter()
                    .all(|v| !v.coupled)
            );
        }
        // Without a curvature limit the same gentle arc is fine.
        let arc = integrate(&[Twist2::new(0.5, 0.0, 0.5); 4], dt);
        assert_relative_eq!(
            tfs_plan(&arc, dt, &limits(None), Twist2::new(0.5, 0.0, 0.5)),
            1.0
        );
        // Starting from rest at 1 m/s needs 10 m/s²: only the first waypoint fails.
        let go = integrate(&[Twist2::new(1.0, 0.0, 0.0); 4], dt);
        assert_relative_eq!(tfs_plan(&go, dt, &l, Twist2::ZERO), 0.75);
    }

    #[test]
    fn executed_tfs_and_min() {
        let l = limits(Some(2.0));
        let cmds = [
            Twist2::new(0.5, 0.0, 0.0),
            Twist2::new(0.55, 0.0, 0.1),
            Twist2::new(0.9, 0.0, 0.1), // a = 3.5 m/s²
            Twist2::new(0.9, 0.0, 0.05),
            Twist2::new(0.0, 0.0, 0.5),  // a = 9 m/s² and κ = 10 1/m
            Twist2::new(0.0, 0.0, 0.05), // κ = 1 1/m: fine
        ];
        assert_relative_eq!(tfs_executed(&cmds, 0.1, &l), 4.0 / 6.0);
        assert_relative_eq!(tfs_executed(&[], 0.1, &l), 1.0);
        assert_relative_eq!(tfs_min(0.9, 4.0 / 6.0), 4.0 / 6.0);
        assert_relative_eq!(tfs_min(0.5, 1.0), 0.5);
    }

    #[test]
    fn degenerate_inputs() {
        assert_relative_eq!(
            tfs_plan(&[Pose2::IDENTITY], 0.1, &limits(None), Twist2::ZERO),
            1.0
        );
        let nan = [Pose2::IDENTITY, Pose2::new(f64::NAN, 0.0, 0.0)];
        assert_relative_eq!(tfs_plan(&nan, 0.1, &limits(None), Twist2::ZERO), 0.0);
        let stop = [Pose2::IDENTITY; 8];
        assert_relative_eq!(tfs_plan(&stop, 0.1, &limits(Some(1.0)), Twist2::ZERO), 1.0);
        let mut scratch = Vec::new();
        let flat: Vec<f64> = stop.iter().flat_map(|p| p.to_array()).collect();
        assert_relative_eq!(
            tfs_plan_flat(&flat, 0.1, &limits(None), Twist2::ZERO, &mut scratch),
            1.0
        );
    }
}
