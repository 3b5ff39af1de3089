//! Embodiments: how a robot moves. A kinematic model step, command saturation to the robot's
//! limits, and a PD tracking controller that turns a planned trajectory into commands.
//!
//! Commands are body-frame twists `(v_x, v_y, ω)` for every embodiment; a differential-drive or
//! Ackermann robot simply cannot realise `v_y ≠ 0`, and an Ackermann robot's steering angle is
//! implied by the curvature `ω / v_x`.

use crate::planner::Plan;
use crate::se2::{Pose2, Twist2};

/// The robot's state as the simulator and controllers see it.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct RobotState {
    /// Pose of the base-link origin in the world frame.
    pub pose: Pose2,
    /// Body-frame velocity actually executed during the last step.
    pub velocity: Twist2,
}

/// A way of moving.
pub trait Embodiment: Send + Sync {
    /// A short, stable name (`differential_drive`, `ackermann`, `omnidirectional`, ...).
    fn name(&self) -> &str;

    /// Whether the robot can move sideways (`v_y ≠ 0`).
    fn holonomic(&self) -> bool;

    /// Clips a commanded twist to what the robot can do from `state` within `dt`
    /// (speed, reverse speed, yaw rate, curvature, lateral speed and acceleration limits).
    fn saturate(&self, state: &RobotState, cmd: Twist2, dt: f64) -> Twist2;

    /// Advances the kinematic model by `dt` under an already saturated command.
    fn step(&self, state: &RobotState, cmd: Twist2, dt: f64) -> RobotState;

    /// The tracking controller: the (unsaturated) command that follows `plan` at time `t`.
    fn track(&self, state: &RobotState, plan: &Plan, t: f64) -> Twist2;

    /// A limit coupling the twist's components that `saturate` applies and the box limits of
    /// the profile cannot express (a tracked base's track speed, see
    /// [`CoupledLimit`](crate::limits::CoupledLimit)). Loading the robot copies it into the
    /// profile's limits, so that TFS, Φ and the last-step correction see it. Default: none.
    fn coupled_limit(&self) -> Option<crate::limits::CoupledLimit> {
        None
    }
}

// ---------------------------------------------------------------------------------------------
// Built-in embodiments
// ---------------------------------------------------------------------------------------------

use crate::limits::{ControllerGains, Limits};
use crate::se2::wrap_angle;
use crate::trajectory::{KAPPA_EPS, curvature};
use serde::{Deserialize, Serialize};

/// Below this remaining time (s) the reference twist of a plan is taken as zero.
const MIN_DIFFERENCE_WINDOW: f64 = 1e-9;

/// The closed set of built-in kinematic models.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum EmbodimentKind {
    /// Two driven wheels on one axle: the unicycle `(v_x, 0, ω)`; can turn in place.
    DifferentialDrive,
    /// Car-like steering: the kinematic bicycle about the rear axle, `ω = v·tan(δ)/L`,
    /// `|κ| = |ω / v| ≤ κ_max`, no turning in place, `v_y = 0`.
    Ackermann,
    /// Independent `(v_x, v_y, ω)` (legged robots, mecanum or swerve bases).
    Omnidirectional,
}

impl EmbodimentKind {
    /// Every built-in kind, in the order they are documented.
    pub const ALL: [EmbodimentKind; 3] = [
        EmbodimentKind::DifferentialDrive,
        EmbodimentKind::Ackermann,
        EmbodimentKind::Omnidirectional,
    ];

    /// The name used in `robot.toml` (`differential_drive`, `ackermann`, `omnidirectional`).
    pub fn as_str(self) -> &'static str {
        match self {
            EmbodimentKind::DifferentialDrive => "differential_drive",
            EmbodimentKind::Ackermann => "ackermann",
            EmbodimentKind::Omnidirectional => "omnidirectional",
        }
    }

    /// Parses the `robot.toml` name; `None` for anything else.
    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|k| k.as_str() == name)
    }

    /// Whether the model can realise `v_y ≠ 0`.
    pub fn holonomic(self) -> bool {
        matches!(self, EmbodimentKind::Omnidirectional)
    }
}

impl std::fmt::Display for EmbodimentKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

/// The reference a tracking controller follows at time `t`: the plan's pose at `t` (geodesic
/// interpolation between waypoints, clamped to the plan's ends) and the feed-forward body twist
/// `log(P(t)⁻¹·P(t + h)) / h` over the look-ahead window `h` (shortened at the end of the plan;
/// zero once the plan is over or when every remaining pose is equal).
///
/// `None` when the plan has no pose or a non-finite `t0`/`dt`.
pub fn plan_reference(plan: &Plan, t: f64, lookahead: f64) -> Option<(Pose2, Twist2)> {
    let first = *plan.poses.first()?;
    if !(plan.t0.is_finite() && plan.dt.is_finite() && t.is_finite()) {
        return None;
    }
    if plan.poses.len() == 1 || plan.dt <= 0.0 {
        return Some((first, Twist2::ZERO));
    }
    let end = plan.t0 + plan.duration();
    let t = t.clamp(plan.t0, end);
    let pose = plan_pose_at(plan, t)?;
    let t_ahead = (t + lookahead.max(0.0)).min(end);
    let h = t_ahead - t;
    if h < MIN_DIFFERENCE_WINDOW {
        return Some((pose, Twist2::ZERO));
    }
    let ahead = plan_pose_at(plan, t_ahead)?;
    Some((pose, pose.between(ahead).log().scale(1.0 / h)))
}

/// The feed-forward body twist of the built-in tracking controller for the control period
/// `[t, t + h]`: the plan's segment twists `ξ_k = log(P_k⁻¹·P_{k+1})/dt`, placed at the segment
/// midpoints `t0 + (k + ½)·dt`, and the robot's `current` twist, placed at `t0 − h/2` (the
/// middle of the control period that produced it), interpolated linearly in time and read at
/// the middle of the coming period, `t + h/2`. Held at the last segment to the end of the
/// plan; zero after it, and for a plan with fewer than two poses or non-finite times.
///
/// A plan whose segment speeds change by at most `a_max·dt` (and whose first segment's mean is
/// within `a_max·dt/2` of the current speed) thus gives a feed-forward that changes by less
/// than `a_max·h` per control period, also across replanning, where the raw segment twists
/// (what [`plan_reference`] differences) jump at every waypoint.
pub fn plan_feedforward(plan: &Plan, t: f64, current: Twist2, h: f64) -> Twist2 {
    let n = plan.poses.len();
    let h = if h.is_finite() { h.max(0.0) } else { 0.0 };
    if n < 2 || !(plan.t0.is_finite() && plan.dt.is_finite() && plan.dt > 0.0 && t.is_finite()) {
        return Twist2::ZERO;
    }
    let segments = n - 1;
    if t >= plan.t0 + segments as f64 * plan.dt {
        return Twist2::ZERO;
    }
    let twist = |k: usize| {
        plan.poses[k]
            .between(plan.poses[k + 1])
            .log()
            .scale(1.0 / plan.dt)
    };
    let lerp = |a: Twist2, b: Twist2, f: f64| {
        let f = f.clamp(0.0, 1.0);
        Twist2::new(
            a.vx + (b.vx - a.vx) * f,
            a.vy + (b.vy - a.vy) * f,
            a.omega + (b.omega - a.omega) * f,
        )
    };
    // Reading time in units of dt from t0; knot k at k + ½, the current twist at −h/(2·dt).
    let tau = (t + 0.5 * h - plan.t0) / plan.dt;
    let out = if tau < 0.5 {
        let start = -0.5 * h / plan.dt;
        lerp(current, twist(0), (tau - start) / (0.5 - start))
    } else {
        let k = (tau - 0.5).floor() as usize;
        if k + 1 >= segments {
            twist(segments - 1)
        } else {
            lerp(twist(k), twist(k + 1), tau - 0.5 - k as f64)
        }
    };
    if out.is_finite() { out } else { Twist2::ZERO }
}

/// Keeps a tracking controller's feedback from taking a command past a limit that the plan's
/// own feed-forward twist respects: the command `cmd` (feed-forward plus feedback) is clipped to
///
/// * `v_x ∈ [min(ff_x, −v_reverse_max), max(ff_x, v_max)]`, `|v_y| ≤ max(|ff_y|, lateral)`,
///   `|ω| ≤ max(|ff_ω|, ω_max)`;
/// * `|v_x − current_x| ≤ max(a_max·h, |ff_x − current_x|)` over the control period `h`, and
///   `|v_y − current_y| ≤ sqrt((a_max·h)² − (v_x − current_x)²)` (the robot limits the change
///   of `(v_x, v_y)` in norm; the executed TFS checks `v_x`'s);
/// * with a curvature limit, `|ω| ≤ max(κ_max, |κ_ff|)·sqrt(v_x² + ε_κ²)` (the curvature as
///   [`crate::feasibility`] measures it, for the clipped `v_x`);
/// * with a coupled limit `a·|v_x| + b·|v_y| + c·|ω| ≤ max`, the command's value at most
///   `max(max, value of ff)` as far as `ω` and then `v_y` can give way; `v_x` is left as the
///   bounds above made it (its changes are what the acceleration check sees).
///
/// Each interval contains the feed-forward, so a plan that asks for more than a limit still
/// gets it, and is still counted against it by the executed TFS; a feasible plan is followed
/// with commands inside every limit, its feedback saturated the way the robot would saturate
/// it anyway. `current` is the velocity executed last step; non-finite inputs leave `cmd` as is.
pub fn bound_feedback(cmd: Twist2, ff: Twist2, current: Twist2, limits: &Limits, h: f64) -> Twist2 {
    if !(cmd.is_finite() && ff.is_finite() && current.is_finite() && h.is_finite()) {
        return cmd;
    }
    let l = limits;
    let step = l.a_max * h.max(0.0);
    let dv = step.max((ff.vx - current.vx).abs());
    let vx = cmd
        .vx
        .clamp(ff.vx.min(-l.v_reverse_max), ff.vx.max(l.v_max))
        .clamp(current.vx - dv, current.vx + dv);
    // The robot limits the change of (v_x, v_y) in norm (`saturate`): v_y may change by what
    // v_x leaves, so that the robot does not shorten v_x's step (v_x's changes are what the
    // executed TFS checks).
    let lateral = ff.vy.abs().max(l.lateral_speed_max);
    let room = (step * step - (vx - current.vx).powi(2)).max(0.0).sqrt();
    let vy = cmd
        .vy
        .clamp(-lateral, lateral)
        .clamp(current.vy - room, current.vy + room);
    let mut yaw = ff.omega.abs().max(l.omega_max);
    if let Some(kappa_max) = l.kappa_max {
        let kappa_ff = curvature(ff.vx, ff.omega).abs();
        yaw = yaw.min(kappa_max.max(kappa_ff) * vx.hypot(KAPPA_EPS));
    }
    let omega = cmd.omega.clamp(-yaw, yaw);
    match &l.coupled {
        Some(c) => {
            let cap = c.max.max(c.value(ff.vx, ff.vy, ff.omega));
            let omega = give_way(omega, c.omega, cap - c.value(vx, vy, 0.0));
            let vy = give_way(vy, c.lateral, cap - c.value(vx, 0.0, omega));
            Twist2::new(vx, vy, omega)
        }
        None => Twist2::new(vx, vy, omega),
    }
}

/// `x` clipped so that `coef·|x| ≤ room` (left as is when `coef` is 0; 0 when `room < 0`).
fn give_way(x: f64, coef: f64, room: f64) -> f64 {
    if coef > 0.0 {
        let r = room.max(0.0) / coef;
        x.clamp(-r, r)
    } else {
        x
    }
}

/// The plan's pose at time `t` (clamped to the plan), by geodesic interpolation (Eq. 4).
pub fn plan_pose_at(plan: &Plan, t: f64) -> Option<Pose2> {
    let last = plan.poses.len().checked_sub(1)?;
    if last == 0 || !plan.dt.is_finite() || plan.dt <= 0.0 {
        return plan.poses.first().copied();
    }
    let s = ((t - plan.t0) / plan.dt).clamp(0.0, last as f64);
    if !s.is_finite() {
        return plan.poses.first().copied();
    }
    let k = (s.floor() as usize).min(last - 1);
    let frac = s - k as f64;
    Some(plan.poses[k].interpolate(plan.poses[k + 1], frac))
}

/// A built-in embodiment: one of the three [`EmbodimentKind`]s with its limits and gains.
///
/// * [`saturate`](Embodiment::saturate) projects the command onto the model (`v_y = 0` unless
///   omnidirectional), clips `v_x` to `[−v_reverse_max, v_max]` and `|v_y|` to
///   `lateral_speed_max`, limits the change of the linear velocity `(v_x, v_y)` from the current
///   one to `a_max·dt` (Euclidean norm), clips `|ω|` to `ω_max` and finally, when `κ_max` is set,
///   `|ω| ≤ κ_max·‖(v_x, v_y)‖` (so an Ackermann robot cannot turn in place). There is no
///   yaw-acceleration limit (the profiles carry none). Non-finite commands become zero.
/// * [`step`](Embodiment::step) integrates exactly on SE(2): `pose·exp(dt·cmd)` (Eq. 5), after
///   projecting the command onto the model.
/// * [`track`](Embodiment::track) is a PD controller on the pose error `e = pose⁻¹·ref` in the
///   robot frame, with the reference pose from [`plan_pose_at`] and the feed-forward twist from
///   [`plan_feedforward`] with `h = gains.lookahead`, the control period (segment twists
///   interpolated between segment midpoints from the current velocity, so that a plan within
///   `a_max` asks for no step larger than `a_max·h`, also across replanning). With the
///   feed-forward twist rotated into the robot frame,
///   `v_ff = R(e_θ)·(v_x,ref, v_y,ref)`:
///   - differential drive and Ackermann (Kanayama-style):
///     `v = v_ff,x + k_x·e_x`, `ω = ω_ref + k_y·v_x,ref·e_y + k_θ·sin e_θ`
///     (`k_y` in 1/m², `k_θ` in 1/s, so the heading is corrected even when `v_ref = 0`);
///   - omnidirectional: `(v_x, v_y) = v_ff + k_x·(e_x, e_y)`, `ω = ω_ref + k_θ·sin e_θ`;
///   - all: plus the derivative term `k_d·(ξ_ff − ξ)`, the error between the feed-forward twist
///     and the velocity executed last step (the time derivative of the pose error);
///   - then [`bound_feedback`] with the plan's feed-forward twist (unrotated) and the control
///     period `lookahead`: the feedback never takes the command past a limit the plan respects.
///
///   Measured in `sdk/core/tests/embodiment_tracking.rs` (control period 0.05 s, empty world,
///   the three shipped robot profiles, 24 s S-curves from rest at 70 % of v_max and a_max with
///   60 % of the yaw-rate, curvature and lateral limits): starting on the plan the position error
///   stays below 1 cm and the heading error below 0.01 rad; starting 0.32 m and 0.2 rad off, both
///   are below 2 cm and 0.02 rad after a 5 s transient. A plan whose poses are all equal (the
///   planner's stop-in-place fallback) brings the robot to rest at that pose.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BuiltinEmbodiment {
    kind: EmbodimentKind,
    limits: Limits,
    gains: ControllerGains,
}

impl BuiltinEmbodiment {
    /// A built-in embodiment of `kind`. The limits are used as given (a validated
    /// [`crate::robot::RobotProfile`] guarantees they are finite and positive); an Ackermann
    /// embodiment without `κ_max` cannot enforce "no turning in place".
    pub fn new(kind: EmbodimentKind, limits: Limits, gains: ControllerGains) -> Self {
        Self {
            kind,
            limits,
            gains,
        }
    }

    /// The kinematic model.
    pub fn kind(&self) -> EmbodimentKind {
        self.kind
    }

    /// The limits commands are saturated to.
    pub fn limits(&self) -> &Limits {
        &self.limits
    }

    /// The gains of the tracking controller.
    pub fn gains(&self) -> &ControllerGains {
        &self.gains
    }

    /// The command restricted to what the kinematic model can express (`v_y = 0` unless
    /// omnidirectional; non-finite components become zero).
    fn project(&self, cmd: Twist2) -> Twist2 {
        let finite = |x: f64| if x.is_finite() { x } else { 0.0 };
        let vy = if self.kind.holonomic() {
            finite(cmd.vy)
        } else {
            0.0
        };
        Twist2::new(finite(cmd.vx), vy, finite(cmd.omega))
    }
}

impl Embodiment for BuiltinEmbodiment {
    fn name(&self) -> &str {
        self.kind.as_str()
    }

    fn holonomic(&self) -> bool {
        self.kind.holonomic()
    }

    fn saturate(&self, state: &RobotState, cmd: Twist2, dt: f64) -> Twist2 {
        let l = &self.limits;
        let cmd = self.project(cmd);
        let current = self.project(state.velocity);
        // Speed box.
        let mut vx = cmd.vx.clamp(-l.v_reverse_max, l.v_max);
        let mut vy = cmd.vy.clamp(-l.lateral_speed_max, l.lateral_speed_max);
        // Acceleration: the linear velocity may change by at most a_max·dt.
        let max_dv = l.a_max * if dt.is_finite() { dt.max(0.0) } else { 0.0 };
        let (dvx, dvy) = (vx - current.vx, vy - current.vy);
        let dv = dvx.hypot(dvy);
        if dv > max_dv {
            let s = if dv > 0.0 { max_dv / dv } else { 0.0 };
            vx = current.vx + dvx * s;
            vy = current.vy + dvy * s;
        }
        // Yaw rate, then curvature.
        let mut omega = cmd.omega.clamp(-l.omega_max, l.omega_max);
        if let Some(kappa_max) = l.kappa_max {
            let bound = kappa_max * vx.hypot(vy);
            omega = omega.clamp(-bound, bound);
        }
        Twist2::new(vx, vy, omega)
    }

    fn step(&self, state: &RobotState, cmd: Twist2, dt: f64) -> RobotState {
        let cmd = self.project(cmd);
        RobotState {
            pose: state.pose.euler_step(cmd, dt).normalized(),
            velocity: cmd,
        }
    }

    fn track(&self, state: &RobotState, plan: &Plan, t: f64) -> Twist2 {
        let g = &self.gains;
        let Some(reference) = plan_pose_at(plan, t) else {
            return Twist2::ZERO;
        };
        if !state.pose.is_finite() || !reference.is_finite() {
            return Twist2::ZERO;
        }
        let xi = plan_feedforward(plan, t, self.project(state.velocity), g.lookahead);
        let e = state.pose.between(reference);
        let e_theta = wrap_angle(e.theta);
        let (s, c) = e_theta.sin_cos();
        // The reference velocity expressed in the robot frame.
        let ff = Twist2::new(c * xi.vx - s * xi.vy, s * xi.vx + c * xi.vy, xi.omega);
        let (ff, mut cmd) = if self.kind.holonomic() {
            let cmd = Twist2::new(
                ff.vx + g.k_x * e.x,
                ff.vy + g.k_x * e.y,
                xi.omega + g.k_theta * e_theta.sin(),
            );
            (ff, cmd)
        } else {
            let ff = Twist2::new(ff.vx, 0.0, ff.omega);
            let cmd = Twist2::new(
                ff.vx + g.k_x * e.x,
                0.0,
                xi.omega + g.k_y * xi.vx * e.y + g.k_theta * e_theta.sin(),
            );
            (ff, cmd)
        };
        let v = self.project(state.velocity);
        cmd.vx += g.k_d * (ff.vx - v.vx);
        cmd.vy += g.k_d * (ff.vy - v.vy);
        cmd.omega += g.k_d * (ff.omega - v.omega);
        bound_feedback(
            self.project(cmd),
            self.project(xi),
            v,
            &self.limits,
            g.lookahead,
        )
    }
}
