//! The exact last-step correction: the feasible plan closest to a guided sample.
//!
//! Algorithm 1 steers every integration step of the flow with a gradient step per iteration;
//! on the trained model, whose samples jitter by a few centimetres between 0.1 s waypoints, `M`
//! such steps leave lateral-slip and acceleration violations behind (see `sdk/configs/
//! planner.toml` for the measured numbers). Since the last control `u_{N−1}` reaches the final
//! poses directly (`x_N = x_{N−1}·exp(Δt·(f + u_{N−1}))`), any final plan is reachable through
//! it, and the smallest such intervention that makes the plan feasible is the plan itself moved
//! to the closest feasible one. This module solves that last step exactly instead of by
//! gradient steps, for the robot's hard limits (the ones TFS measures); plugin constraint
//! terms act through Algorithm 1 only.
//!
//! # The problem
//!
//! A plan is parameterised by its segment twists `ξ_k = (v_k, vy_k, ω_k)`, `k = 1 … T`, with
//! exact reconstruction `p_k = p_{k−1}·exp(dt·ξ_k)` from the current pose `p_0 = I` (ego frame).
//! Along such an arc the finite differences of [`crate::trajectory`] are exactly
//! `(c_k·v_k, c_k·vy_k, ω_k)` with the chord factor `c_k = sin(ω_k·dt/2)/(ω_k·dt/2)`, which lies
//! in `[c_min, 1]`, `c_min = c(ω_max)`, once the yaw rate is limited. The limits are imposed
//! as linear constraints on `ξ` that hold for every `c_k` in that range (`s = 1 − margin`):
//!
//! * `0 ≤ σ·v_k ≤ s·v_lim` with `σ = +1` (forward, `v_lim = v_max`) unless the target
//!   plan's mean speed is negative (`σ = −1`, `v_lim = v_reverse_max`): one gear per plan, so
//!   noise around zero speed cannot make the plan stop and reverse. A robot moving against
//!   that gear brakes first: the segments before the first one that can reach zero speed under
//!   the acceleration limit keep the robot's own direction (`σ = −σ` for them);
//! * `|vy_k| ≤ s·lateral_speed_max`, `|ω_k| ≤ s·ω_max`;
//! * `|ω_k| ≤ s·κ_max·c_min·σ·v_k` when the robot has a curvature limit (the measured
//!   curvature divides by `sqrt((c_k·v_k)² + ε_κ²) ≥ c_min·|v_k|`);
//! * `a·σ·v_k ± b·vy_k ± c·ω_k ≤ s·max` (every sign) when the embodiment declares a coupled
//!   limit `a·|v| + b·|vy| + c·|ω| ≤ max`: with the gear fixed, `|v_k| = σ·v_k`, and the
//!   measured `c_k·|v_k|`, `c_k·|vy_k|` are no larger;
//! * `|v_k − v_{k−1}| ≤ s_a·a_max·dt − (1 − c_min)·v_top` (`s_a = 1 − acceleration_margin`,
//!   `v_top = max(v_max, v_reverse_max)`): the measured change `c_k·v_k − c_{k−1}·v_{k−1}`
//!   differs from `v_k − v_{k−1}` by at most `(1 − c_min)·v_top` (2.5 % of diablo's
//!   `a_max·dt`); and `|v_1 − v_0| ≤ s_a·a_max·dt/2`
//!   from the robot's current speed `v_0`: the first segment's speed is a mean over its step,
//!   which a ramp from `v_0` at `a_max` reaches in half a step. Planned so, the tracking
//!   controller's feed-forward ([`crate::embodiment::plan_feedforward`]) changes no faster than
//!   `s_a·a_max` even at the 20 Hz control rate, and the margin is room for its feedback.
//!
//! The objective is the distance to the target poses `p̂` (the guided sample):
//! `Σ_k ‖xy_k(ξ) − x̂y_k‖² + w_θ·wrap(θ_k(ξ) − θ̂_k)² + ρ·dt²·‖ξ_k − ξ_k⁰‖²`, with `w_θ` =
//! [`ProjectionSettings::heading_weight`] and `ρ` = [`ProjectionSettings::effort`] (a small
//! trust region). It is minimised by Gauss-Newton: linearise the rollout around the current
//! twists (`e_k = S_x·e_{k−1} + S_w·δξ_k` for the pose change `e_k`, the step Jacobians of
//! [`crate::se2::euler_step_jacobians`]), solve the convex QP in `(δξ, e)`, repeat
//! [`ProjectionSettings::iterations`] times. The QP is a linear-quadratic control problem
//! with stage-wise constraints; it is solved by its structure (`lq`: an interior-point method
//! whose Newton steps are Riccati recursions), and by Clarabel on the sparse, banded problem
//! with the poses kept as variables (about 6·T of them) when that gives up, which also
//! certifies an infeasible start ([`ProjectionSolver`]). The constraints do not depend on the
//! linearisation, so every iterate is feasible; the iterations only bring the plan closer to
//! the target.
//!
//! A plan that already satisfies every limit (TFS = 1) is returned unchanged, bit for bit.

mod assembly;
mod lq;
mod solver;

use crate::feasibility;
use crate::limits::Limits;
use crate::se2::{Pose2, Twist2, euler_step_jacobians, wrap_angle};
use clarabel::algebra::CscMatrix;
use clarabel::solver::{
    DefaultSettingsBuilder, DefaultSolver, IPSolver, NonnegativeConeT, SolverStatus, ZeroConeT,
};
use serde::{Deserialize, Serialize};

use assembly::{
    Rows, coupled_signs, dynamics_rows, limit_rows, objective_linear, objective_matrix,
};
use solver::solve_step;
pub use solver::{CLARABEL_TOLERANCE, ProjectionSolver};

/// Largest number of Gauss-Newton iterations of the correction
/// ([`ProjectionSettings::iterations`]): the planner uses 1 (a second moved plans by under
/// 1 mm); each costs a QP (about 1 ms) per candidate.
pub const MAX_PROJECTION_ITERATIONS: usize = 100;

/// Settings of the last-step correction (TOML table `[human2nav.projection]`, every field
/// optional). Defaults: `enabled = true`, `iterations = 1`, `margin = 0.01`,
/// `acceleration_margin = 0.1`, `heading_weight = 0.1`, `effort = 0.01`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ProjectionSettings {
    /// Apply the correction after Algorithm 1 (it is never applied without guidance).
    pub enabled: bool,
    /// Gauss-Newton iterations (1 to [`MAX_PROJECTION_ITERATIONS`]); each solves one QP. The first one already gives a
    /// feasible plan; later ones only re-linearise (on held-out windows a second one changed the
    /// mean correction by under 1 mm for about 1 ms per candidate, see `planner.toml`).
    pub iterations: usize,
    /// Relative margin kept inside every limit, in `[0, 0.5)`.
    pub margin: f64,
    /// Relative margin kept inside `a_max`, in `[0, 0.5)`: room for the tracking controller's
    /// feedback on top of the planned acceleration.
    pub acceleration_margin: f64,
    /// Weight `w_θ` of the heading error against the position error (m²/rad², ≥ 0).
    pub heading_weight: f64,
    /// Weight `ρ` of the change of the twists (≥ 0, a trust region for the linearisation).
    pub effort: f64,
}

impl Default for ProjectionSettings {
    fn default() -> Self {
        Self {
            enabled: true,
            iterations: 1,
            margin: 0.01,
            acceleration_margin: 0.1,
            heading_weight: 0.1,
            effort: 0.01,
        }
    }
}

/// Why a plan could not be corrected.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum ProjectionError {
    /// A setting is out of range.
    #[error("invalid projection setting `{field}`: {message}")]
    InvalidSettings {
        /// The setting's TOML key.
        field: &'static str,
        /// What is wrong with its value.
        message: String,
    },
    /// The plan to correct has a non-finite pose.
    #[error("the target plan has a non-finite pose")]
    NonFinite,
    /// The QP has no solution: no plan within the limits starts at the current speed.
    #[error(
        "no feasible plan from the current speed {speed:.3} m/s (the QP solver reports {status})"
    )]
    Infeasible {
        /// The robot's current forward speed, m/s.
        speed: f64,
        /// The solver's status.
        status: String,
    },
}

impl ProjectionSettings {
    /// Checks every field; the error names the first offending one.
    pub fn validate(&self) -> Result<(), ProjectionError> {
        let bad = |field, message: &str| {
            Err(ProjectionError::InvalidSettings {
                field,
                message: message.to_string(),
            })
        };
        if self.iterations == 0 {
            return bad("iterations", "must be at least 1");
        }
        if self.iterations > MAX_PROJECTION_ITERATIONS {
            return bad(
                "iterations",
                &format!("must be at most {MAX_PROJECTION_ITERATIONS}"),
            );
        }
        if !(self.margin.is_finite() && (0.0..0.5).contains(&self.margin)) {
            return bad("margin", "must be in [0, 0.5)");
        }
        if !(self.acceleration_margin.is_finite() && (0.0..0.5).contains(&self.acceleration_margin))
        {
            return bad("acceleration_margin", "must be in [0, 0.5)");
        }
        if !(self.heading_weight.is_finite() && self.heading_weight >= 0.0) {
            return bad("heading_weight", "must be finite and ≥ 0");
        }
        if !(self.effort.is_finite() && self.effort >= 0.0) {
            return bad("effort", "must be finite and ≥ 0");
        }
        Ok(())
    }
}

/// The result of [`project`].
#[derive(Clone, Debug, PartialEq)]
pub struct Projected {
    /// The `T` corrected future poses (ego frame, pose 0 = identity not included).
    pub poses: Vec<Pose2>,
    /// QPs solved (0 when the target was already feasible).
    pub iterations: usize,
    /// Mean distance (m) between the corrected and the target positions.
    pub displacement: f64,
}

/// `sin(x)/x`, the chord factor of an arc turning by `2x`.
fn sinc(x: f64) -> f64 {
    if x.abs() < 1e-6 {
        1.0 - x * x / 6.0
    } else {
        x.sin() / x
    }
}

/// Poses of the twists `xi` (`[T, 3]`) from the identity.
fn rollout(xi: &[f64], dt: f64) -> Vec<Pose2> {
    let mut p = Pose2::IDENTITY;
    xi.chunks_exact(3)
        .map(|w| {
            p = p.euler_step(Twist2::from_slice(w), dt);
            p
        })
        .collect()
}

/// The closest plan to `target` (the `T` future poses in the ego frame, the robot at the
/// identity moving with `initial_velocity`) that satisfies `limits` (see the module docs).
pub fn project(
    target: &[Pose2],
    dt: f64,
    limits: &Limits,
    initial_velocity: Twist2,
    settings: &ProjectionSettings,
) -> Result<Projected, ProjectionError> {
    project_with(
        target,
        dt,
        limits,
        initial_velocity,
        settings,
        &mut ProjectionSolver::default(),
    )
}

/// [`project`] with a solver kept from earlier corrections (see [`ProjectionSolver`]).
pub fn project_with(
    target: &[Pose2],
    dt: f64,
    limits: &Limits,
    initial_velocity: Twist2,
    settings: &ProjectionSettings,
    solver: &mut ProjectionSolver,
) -> Result<Projected, ProjectionError> {
    settings.validate()?;
    if !target.iter().all(|p| p.is_finite()) {
        return Err(ProjectionError::NonFinite);
    }
    let with_start: Vec<Pose2> = std::iter::once(Pose2::IDENTITY)
        .chain(target.iter().copied())
        .collect();
    if target.is_empty() || feasibility::tfs_plan(&with_start, dt, limits, initial_velocity) >= 1.0
    {
        return Ok(Projected {
            poses: target.to_vec(),
            iterations: 0,
            displacement: 0.0,
        });
    }
    let t = target.len();
    let mut xi: Vec<f64> = with_start
        .windows(2)
        .flat_map(|w| w[0].between(w[1]).log().scale(1.0 / dt).to_array())
        .collect();
    let gear = if xi.chunks_exact(3).map(|w| w[0]).sum::<f64>() < 0.0 {
        -1.0
    } else {
        1.0
    };
    for _ in 0..settings.iterations {
        let delta = solve_step(
            &xi,
            target,
            dt,
            limits,
            initial_velocity,
            gear,
            settings,
            solver,
        )?;
        for (x, d) in xi.iter_mut().zip(&delta) {
            *x += d;
        }
    }
    let poses = rollout(&xi, dt);
    if !poses.iter().all(|p| p.is_finite()) {
        return Err(ProjectionError::NonFinite);
    }
    let displacement = poses
        .iter()
        .zip(target)
        .map(|(a, b)| (a.x - b.x).hypot(a.y - b.y))
        .sum::<f64>()
        / t as f64;
    Ok(Projected {
        poses,
        iterations: settings.iterations,
        displacement,
    })
}

#[cfg(test)]
mod tests;
