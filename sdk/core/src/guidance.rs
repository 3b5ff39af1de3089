//! Feasibility-guided sampling (paper Algorithm 1, E-MSA with a PMP adjoint), generic over
//! [`FlowModel`] so it runs and is tested without libtorch.
//!
//! Two variants share the rollout, the cost, the adjoint and the control update, selected by
//! [`GuidanceSettings::variant`]:
//!
//! * **paper** ([`GuidanceVariant::Paper`]): Algorithm 1 lines 5-14 as printed, see "The paper
//!   variant" below;
//! * **adaptive** ([`GuidanceVariant::Adaptive`], the default): the project's variant, see "The
//!   adaptive variant" below. It differs from the paper in five ways: the control update uses
//!   the exact gradient `∂J/∂u_i` (or a preconditioned form) instead of `μ_{t_i}`; the model's
//!   Jacobian is taken at `x_i` (exact for the forward pass) instead of `x_i + u_i`; the step is
//!   adaptive per sample with an early stop; `β = 1` by default; and a planner guides a
//!   shortlist of the samples.
//!
//! # Integration on SE(2)
//!
//! A sample is `T` waypoint poses, flat `[K, T, 3]` for `K` samples. Starting from given poses
//! `x_0` (the sampler draws `x_0 = exp(ξ_0)`, `ξ_0 ~ N(0, diag(σ²))` with `σ` from
//! [`FlowModel::source_std`]), `N` Lie-group Euler steps (Eq. 5) with the steering control of
//! Eq. 6 added in the algebra are taken, per waypoint:
//!
//! `x_{i+1} = x_i · exp(Δt·w_i)`, `w_i = f(x_i, t_i, c) + u_i`, `t_i = i/N`, `Δt = 1/N`.
//!
//! The stored control `u_i` is a velocity in the algebra, in both variants.
//!
//! # Cost
//!
//! `Φ` ([`Phi`]: the robot's built-in soft-margin terms plus any plugin terms) is evaluated on
//! each final sample with the robot's current pose, the identity of the ego frame, prepended as
//! pose 0: the model generates the `T` *future* poses and pose 0 is not a variable. The
//! objective is per sample; samples never interact.
//!
//! # Adjoint, carried in coordinates
//!
//! The co-state `μ_i` is the gradient of `Φ(x_N)` with respect to the **coordinates**
//! `(x, y, θ)` of every waypoint of `x_i`: the same chart in which the flow model's VJP
//! differentiates, and in which the step Jacobians have closed forms
//! ([`se2::euler_step_jacobians`](crate::se2::euler_step_jacobians); the angle wrap has
//! derivative 1). With `S_x = ∂(x·exp(Δt·w))/∂x` and `S_w = ∂(x·exp(Δt·w))/∂w` (which contains
//! the factor `Δt`) at the forward pass's `(x_i, w_i)`, per waypoint:
//!
//! * `μ_N = clip(∇_{x_N} Φ)` (Alg. 1 line 6),
//! * `∂J/∂u_i = S_wᵀ·μ_{i+1}`,
//! * `μ_i = clip(S_xᵀ·μ_{i+1} + (∂f/∂x)ᵀ·S_wᵀ·μ_{i+1})` (lines 7-10), the second product by
//!   [`FlowModel::velocity_vjp`] with cotangent `S_wᵀ·μ_{i+1}`, evaluated at `x_i` (adaptive:
//!   the exact adjoint of the rollout) or at `x_i ⊕ u_{t_i}` (paper, line 8).
//!
//! `clip(·)` rescales each waypoint's 3-vector to a Euclidean norm of at most the clip setting
//! ([`GuidanceSettings::clip`], [`PaperSettings::clip`]). [`control_gradient`] returns the
//! adaptive variant's gradient (unclipped) and is checked against finite differences in the
//! tests.
//!
//! # The paper variant
//!
//! Parameters [`PaperSettings`] (γ, β, clip) and [`GuidanceSettings::iterations_m`] (`M`),
//! [`GuidanceSettings::steps_n`] (`N`). The printed algorithm is written in a flat space with
//! the step `Δt` folded into `f`; on SE(2), with `a ⊕ ξ = a·exp(ξ)` (the right composition of
//! Eq. 5) and the control `u_{t_i}` of the paper a displacement in the algebra, each line is:
//!
//! * **line 3**: `u_{t_i} = 0`; `x_0` is given (the sampler's draw).
//! * **line 5**: `x_{i+1} = x_i ⊕ (Δt·f(x_i, t_i, c) + u_{t_i}) = x_i·exp(Δt·f(x_i, t_i, c) +
//!   u_{t_i})`. This is the rollout above with `u_{t_i} = Δt·u_i`: the workspace stores
//!   `u_i = u_{t_i}/Δt` so that both variants share one forward pass.
//! * **line 6**: `μ_T = clip(∇_{x_N} Φ(x_N))`, the co-state of the final poses in coordinates.
//! * **lines 7-10**: for `i = N−1` down to `0`, `μ_i = clip(∇_{x_i}J(x_i)ᵀ·μ_{i+1})` with the
//!   step Jacobian of line 5, `∇_{x_i}J = S_x + S_w·∂f/∂x`, whose model Jacobian `∂f/∂x` is
//!   taken at `x_i ⊕ u_{t_i} = x_i·exp(u_{t_i})` at flow time `t_i`, as line 8's
//!   `J(x) = x + u + f(x + u)` prescribes: the VJP is called at `x_i ⊕ u_{t_i}`, not at `x_i`.
//!   `S_x`, `S_w` are those of the step actually taken (line 5); in a flat chart (`S_x = I`,
//!   `S_w = Δt·I`) this is exactly `μ_i = μ_{i+1} + Δt·(∂f/∂x(x_i + u_i))ᵀ·μ_{i+1}`. Every
//!   `μ_i` is clipped, `μ_0` included (line 12 needs it).
//! * **line 12**: `u_{t_i} ← β·u_{t_i} − γ·μ_{t_i}` for every `i` and every sample, i.e.
//!   `u_i ← β·u_i − (γ/Δt)·μ̃_i` on the stored velocity. `u_{t_i}` lives in se(2) at `x_i`
//!   (body frame) while `μ_i` is carried in world coordinates, so the update uses `μ_{t_i}`
//!   in the same space: `μ̃_i = (R(θ_i)ᵀ·(μ_x, μ_y), μ_θ)`, the gradient with respect to a
//!   right perturbation `x_i·exp(δ)` (the identity in a flat chart; same norm, so the clip is
//!   unchanged). No adaptive step, no acceptance test.
//! * **lines 4 and 13**: exactly `M` iterations; no tolerance and no early stop.
//! * **line 14**: the rollout after the last update is the result.
//!
//! Network calls: `N` for the first rollout, then `2N` per iteration (`N` VJPs, `N` forward).
//!
//! Line 12 uses `μ_{t_i}`, the co-state *at* `x_i`. With line 5's forward pass the gradient
//! with respect to `u_{t_i}` is the pull-back of `μ_{i+1}` through the step (the adaptive
//! variant's direction); `μ_{t_i}` would be that gradient if the pass were `x_{i+1} = J(x_i)`
//! of line 8 (control applied before the flow step, so that `∂J/∂u = ∂J/∂x`). As printed the
//! update is therefore not an exact gradient step and Φ need not fall: on a field that maps
//! every `x_{N−1}` onto one target ([`analytic::GeodesicTarget`]) `μ_{t_{N−1}}`, and with it
//! every `μ_{t_i}`, vanishes and the samples are left as they are; and, with no acceptance
//! test, a step past the stiffness of Φ's acceleration term raises Φ (measured numbers in the
//! tests). β < 1 makes a control the co-states stop asking for decay geometrically (the
//! minimal-intervention effort of Eq. 7). Φ is returned before and after, as for the other
//! variant; a planner using this variant guides every sample.
//!
//! # The adaptive variant
//!
//! **Control update** (line 12): `u_i ← β·u_i − γ_k·d_i` with `γ_k` the step of sample `k`
//! (starting at [`GuidanceSettings::learning_rate`]) and `β` = [`GuidanceSettings::momentum`].
//! With `β < 1` and the plain direction this is gradient descent on `Φ(x_N) + (1 − β)/(2γ)·Σ_i
//! ‖u_i‖²`, the effort penalty `∫L(u)` of Eq. 7; `β = 1` (the default) leaves the intervention
//! to be bounded by the tolerance and the small number of iterations.
//!
//! **Plain direction** (`precondition = false`): `d_i = clip(∂J/∂u_i)`, the exact gradient.
//! On the kinematic costs of Φ this is badly conditioned: the quantities are first and second
//! finite differences of the poses at `dt = 0.1 s`, so a uniform over-speed only pulls the last
//! waypoint back (interior gradients cancel), while the acceleration term is `1/dt²` stiffer than
//! the speed term. Measured on the analytic fields of the tests, no fixed step removes a speed,
//! yaw-rate or lateral violation in 8 iterations; large steps diverge.
//!
//! **Preconditioned direction** (`precondition = true`; off by default, as it does not descend
//! on the trained model) adds two changes that keep
//! the algorithm's structure (forward pass, terminal gradient, adjoint, control update):
//!
//! 1. *Twist-space terminal co-state*: `μ_N = s·J·W·S·Jᵀ·clip(∇Φ)`, with `J` the Jacobian of the
//!    waypoints with respect to the segment twists `ξ_k = log(p_{k−1}⁻¹·p_k)/dt` of the plan
//!    (forward kinematics from the fixed current pose), `W = diag(v_max², lateral_speed_max²,
//!    ω_max²)` (each twist component in units of its limit), `S = (I + c·DᵀD)⁻¹` on the speed
//!    component (`D` the first difference anchored at the current speed,
//!    `c = (v_max/(a_max·dt))²`, which weighs acceleration against speed as Φ does) and
//!    `s = 1/(dt·Δt)²`. This is steepest descent in the segment twists instead of the poses:
//!    over-speed slows every segment at once, a heading change carries the rest of the plan
//!    along, and the speed correction is spread so as not to create acceleration violations.
//! 2. *Gauss-Newton control direction*: `d_i = Δt²·S_w⁻¹·μ_{i+1}` instead of `S_wᵀ·μ_{i+1}`,
//!    so that the realised first-order change of the waypoints is `−γ·μ` whatever the distortion
//!    of the exponential map (`S_w` is the Jacobian of the step with respect to the velocity).
//!    The co-states themselves are still propagated with the exact transposed Jacobians.
//!
//! Both directions are descent directions only to first order, so each sample has an adaptive
//! step (`adaptive_step = true`, the default): an update that raises the sample's Φ is undone
//! (states, controls and gradient restored, no extra network call) and its step multiplied by
//! [`STEP_SHRINK`]; an accepted one multiplies it by [`STEP_GROW`]. Hence `phi_after ≤
//! phi_before` for every sample.
//!
//! Known limit: the update moves waypoint *coordinates*; rotating a long remainder of the plan
//! is only linearised, so large yaw-rate and curvature violations are reduced but not always
//! removed within `M` iterations (see the tests for measured numbers).
//!
//! **Iterations and early stop.** One iteration is a backward pass, a control update and a new
//! forward rollout; the last accepted rollout is the result (line 14). The first rollout
//! (`u = 0`) is the unguided sample. A sample whose `Φ` is below [`GuidanceSettings::tolerance`]
//! is frozen (its controls are not updated, so a feasible sample is left exactly as it is); the
//! loop stops once every sample is frozen (so in particular once their mean `Φ` is below the
//! tolerance), or after `M` iterations. Network calls: `N` for the first rollout, then `2N − 1`
//! per iteration (`μ_0` is never needed).
//!
//! # Last-step iterations
//!
//! With [`GuidanceSettings::last_step_iterations`] `L > 0`, the adaptive variant follows its `M`
//! iterations with `L` iterations of line 12's update on the last control `u_{N−1}` alone. Its
//! path to `x_N` is the step `x_N = x_{N−1}·exp(Δt·(f(x_{N−1}) + u_{N−1}))`, whose network
//! output does not depend on `u_{N−1}`, so these iterations call no network: one costs an
//! evaluation of Φ on the batch. The step is Adam's (`β₁ = 0.9`, `β₂ = 0.999`) on each
//! waypoint coordinate's `clip(∇Φ)`, at most [`GuidanceSettings::last_step_rate`] metres
//! (radians) a coordinate and iteration; the control change that realises it to first order is
//! `S_w⁻¹·δx`. Every sample takes part, and each ends at its lowest-Φ iterate, so Φ never rises.
//!
//! Why: on the trained model the violations are local (acceleration and lateral jitter of
//! 0.1 s finite differences, ARCHITECTURE.md, "The guidance ablation"), Φ's soft margins are
//! nearly linear past the limit, and plain gradient steps through all `N` controls need
//! hundreds of iterations of `2N − 1` network calls. A per-coordinate step removes local
//! violations within about 100 cheap iterations. It is slow on a violation spread over the
//! whole plan (a uniform over-speed, yaw rate or curvature), which moving the last waypoints
//! first cannot fix quickly (measured in the tests). Off by default (`L = 0`): in closed loop
//! it did not raise the success rate (`sdk/configs/planner.toml`).
//!
//! # Both variants
//!
//! Nothing non-finite leaves: a non-finite pose, velocity, cost or gradient is a
//! [`GuidanceError::NonFinite`] naming the stage (a planner then falls back to stopping).
//!
//! All buffers live in a reusable [`GuidanceWorkspace`]; once it has seen a batch of a given
//! shape, guidance allocates nothing but its result.
//!
//! # Deadlines
//!
//! [`sample_guided_until`] and [`guide_subset_until`] take a [`Deadline`] and check it before
//! every network call, so a call ends at most one network call after it. A rollout cut short
//! after `i ≥ 1` steps continues the remaining `N − i` steps at each waypoint's last velocity
//! `w_{i−1}` (no network call: the one-jump estimate of the endpoint that flow matching
//! allows); a rollout cut before its first step is [`GuidanceError::DeadlineBeforeSampling`].
//! An iteration of Algorithm 1 cut short is undone, so the result is the last completed
//! iterate. [`GuidanceResult::steps_run`] and [`GuidanceResult::cut_short`] say what happened.

pub mod analytic;

use crate::constraint::{ConstraintContext, ConstraintError, Phi, PhiScratch, TrajBatch};
use crate::flow::{FlowCondition, FlowError, FlowModel};
use crate::planner::Deadline;
use crate::se2::{Jacobian3, Pose2, Twist2, euler_step_jacobians, transpose_apply};
use serde::{Deserialize, Serialize};

/// Which form of Algorithm 1 runs (`variant` in the TOML table).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum GuidanceVariant {
    /// The project's variant (the default): exact adjoint gradient `∂J/∂u_i`, optional
    /// preconditioning, per-sample adaptive step, samples below the tolerance frozen and an
    /// early stop; parameters [`GuidanceSettings::learning_rate`], [`GuidanceSettings::momentum`],
    /// [`GuidanceSettings::clip`], [`GuidanceSettings::tolerance`],
    /// [`GuidanceSettings::precondition`] and [`GuidanceSettings::adaptive_step`].
    #[default]
    Adaptive,
    /// Algorithm 1 as printed (module docs, "The paper variant"), with the parameters of
    /// [`GuidanceSettings::paper`]; the adaptive variant's parameters are ignored. A planner
    /// guides every sample with it.
    Paper,
}

impl GuidanceVariant {
    /// The name used in the TOML (`adaptive`, `paper`).
    pub fn name(self) -> &'static str {
        match self {
            GuidanceVariant::Adaptive => "adaptive",
            GuidanceVariant::Paper => "paper",
        }
    }
}

/// Parameters of the paper variant (the `paper` sub-table, every field optional).
///
/// Defaults: `learning_rate = 1e-4`, `momentum = 0.9`, `clip = 10.0`. The paper gives no
/// values: β = 0.9 is a choice (the common momentum default; a decay of 10 % of the control per
/// iteration), `clip` is the adaptive variant's, and γ is the best of a sweep on the analytic
/// fields of the tests (`paper_variant_step_sizes`: the violation cases on a constant field,
/// `N = 10`, `M = 8`; Φ falls to 0.24 of its value on average, while 5·10⁻⁴ and above raise
/// it). Not tuned on the trained model.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PaperSettings {
    /// `γ` of line 12, `u_{t_i} ← β·u_{t_i} − γ·μ_{t_i}`: metres (radians) of control per unit
    /// of co-state. Finite, > 0.
    pub learning_rate: f64,
    /// `β` of line 12, in `(0, 1]`: with `β < 1` a control the co-state no longer asks for
    /// decays geometrically, the effort penalty of Eq. 7.
    pub momentum: f64,
    /// Largest Euclidean norm of a waypoint's 3-vector in `μ_T` (line 6) and in every `μ_{t_i}`
    /// (line 10). Finite, > 0.
    pub clip: f64,
}

impl Default for PaperSettings {
    fn default() -> Self {
        Self {
            learning_rate: 1e-4,
            momentum: 0.9,
            clip: 10.0,
        }
    }
}

/// Parameters of Algorithm 1 (TOML table, every field optional).
///
/// Defaults: Algorithm 1 as tuned for the shipped planner (`sdk/configs/planner.toml`, where the
/// measurements behind them are; the planner itself ships with `iterations_m = 0`, see
/// [`Human2NavSettings`](crate::human2nav::Human2NavSettings)): `variant = "adaptive"`, `enabled = true`,
/// `steps_n = 5`, `iterations_m = 3`,
/// `learning_rate = 0.1`, `momentum = 1.0`, `clip = 10.0`, `tolerance = 0.01`,
/// `precondition = false` (on the trained model every preconditioned update raised Φ),
/// `adaptive_step = true`, `last_step_iterations = 0`, `last_step_rate = 0.01`, and the
/// [`PaperSettings`] defaults. See the module docs for what
/// each does. The analytic tests of the preconditioned direction use `steps_n = 10`,
/// `iterations_m = 8`, `learning_rate = 0.03` (a unit-less step there: 1 would move each
/// violated twist component by about its own limit per iteration). `enabled`, `steps_n` and `iterations_m` apply to both
/// variants; `learning_rate` to `adaptive_step` to the adaptive variant only, `paper` to the
/// paper variant only.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct GuidanceSettings {
    /// Which form of Algorithm 1 runs.
    pub variant: GuidanceVariant,
    /// Whether Algorithm 1 runs; when false, sampling is the plain rollout.
    pub enabled: bool,
    /// Number of Euler integration steps `N` (1 to [`MAX_STEPS_N`]).
    pub steps_n: usize,
    /// Number of optimisation iterations `M`: at most (adaptive) or exactly (paper); 0 disables
    /// guidance; at most [`MAX_ITERATIONS_M`].
    pub iterations_m: usize,
    /// Initial step size `γ` of the control update (Algorithm 1's γ; not the softplus sharpness
    /// γ of Eq. 8, which is [`GuidanceWeights::gamma`](crate::GuidanceWeights)). Finite, ≥ 0.
    pub learning_rate: f64,
    /// `β` of the control update, in `[0, 1]`.
    pub momentum: f64,
    /// Largest Euclidean norm of a waypoint's terminal gradient `∇Φ` (and, without
    /// preconditioning, of its co-states and control gradients); > 0, `inf` turns it off.
    pub clip: f64,
    /// A sample whose Φ is below this is left alone (finite, ≥ 0).
    pub tolerance: f64,
    /// Precondition the terminal co-state with `L·Lᵀ` (steepest descent in the waypoint
    /// increments, see the module docs).
    pub precondition: bool,
    /// Per-sample adaptive step: an update that raises a sample's Φ is undone and its step
    /// halved; an accepted one grows the step by half.
    pub adaptive_step: bool,
    /// The paper variant's `γ`, `β` and clip (validated whichever variant is selected).
    pub paper: PaperSettings,
    /// Adaptive variant: iterations of the control update on the last control `u_{N−1}` alone
    /// after the `M` full iterations (module docs, "Last-step iterations"). They call no
    /// network; 0 turns them off. At most [`MAX_LAST_STEP_ITERATIONS`].
    pub last_step_iterations: usize,
    /// Adam's step size in the last-step iterations: the largest move of a waypoint coordinate
    /// per iteration, in metres (radians for the heading); finite, > 0.
    pub last_step_rate: f64,
}

/// Largest number of Euler integration steps `N` ([`GuidanceSettings::steps_n`]). The planner
/// uses 5 (the default); each step costs a network call per iteration, so 1000 already
/// makes one planning call take minutes. A bound keeps a mistyped value an error instead of a
/// hang.
pub const MAX_STEPS_N: usize = 1000;

/// Largest number of guidance iterations `M` ([`GuidanceSettings::iterations_m`]); Algorithm 1
/// as tuned uses 3 (the default), the shipped planner 0. Each iteration costs `2N` network calls
/// (see [`MAX_STEPS_N`]).
pub const MAX_ITERATIONS_M: usize = 1000;

/// Largest number of last-step iterations ([`GuidanceSettings::last_step_iterations`]). One
/// costs one evaluation of Φ on the batch (no network call).
pub const MAX_LAST_STEP_ITERATIONS: usize = 10_000;

/// Adam's `β₁`, `β₂` and `ε` in the last-step iterations (the usual defaults).
const ADAM_BETA1: f64 = 0.9;
const ADAM_BETA2: f64 = 0.999;
const ADAM_EPS: f64 = 1e-8;

/// Factor applied to a sample's step size after an accepted update.
pub const STEP_GROW: f64 = 1.5;

/// Factor applied to a sample's step size after a rejected update.
pub const STEP_SHRINK: f64 = 0.5;

impl Default for GuidanceSettings {
    fn default() -> Self {
        Self {
            variant: GuidanceVariant::default(),
            enabled: true,
            steps_n: 5,
            iterations_m: 3,
            learning_rate: 0.1,
            momentum: 1.0,
            clip: 10.0,
            tolerance: 1e-2,
            precondition: false,
            adaptive_step: true,
            paper: PaperSettings::default(),
            last_step_iterations: 0,
            last_step_rate: 0.01,
        }
    }
}

impl GuidanceSettings {
    /// Checks every field; the error names the first offending one.
    pub fn validate(&self) -> Result<(), GuidanceError> {
        let bad = |field: &'static str, message: String| {
            Err(GuidanceError::InvalidSettings { field, message })
        };
        if self.steps_n == 0 {
            return bad("steps_n", "must be at least 1".into());
        }
        if self.steps_n > MAX_STEPS_N {
            return bad(
                "steps_n",
                format!("{} is more than the limit of {MAX_STEPS_N}", self.steps_n),
            );
        }
        if self.iterations_m > MAX_ITERATIONS_M {
            return bad(
                "iterations_m",
                format!(
                    "{} is more than the limit of {MAX_ITERATIONS_M}",
                    self.iterations_m
                ),
            );
        }
        if !(self.learning_rate.is_finite() && self.learning_rate >= 0.0) {
            return bad(
                "learning_rate",
                format!("{} must be finite and ≥ 0", self.learning_rate),
            );
        }
        if !(0.0..=1.0).contains(&self.momentum) {
            return bad("momentum", format!("{} must lie in [0, 1]", self.momentum));
        }
        if self.clip.is_nan() || self.clip <= 0.0 {
            return bad(
                "clip",
                format!("{} must be positive (inf disables clipping)", self.clip),
            );
        }
        if !(self.tolerance.is_finite() && self.tolerance >= 0.0) {
            return bad(
                "tolerance",
                format!("{} must be finite and ≥ 0", self.tolerance),
            );
        }
        if self.last_step_iterations > MAX_LAST_STEP_ITERATIONS {
            return bad(
                "last_step_iterations",
                format!(
                    "{} is more than the limit of {MAX_LAST_STEP_ITERATIONS}",
                    self.last_step_iterations
                ),
            );
        }
        if !(self.last_step_rate.is_finite() && self.last_step_rate > 0.0) {
            return bad(
                "last_step_rate",
                format!("{} must be finite and > 0", self.last_step_rate),
            );
        }
        let p = &self.paper;
        if !(p.learning_rate.is_finite() && p.learning_rate > 0.0) {
            return bad(
                "paper.learning_rate",
                format!("{} must be finite and > 0", p.learning_rate),
            );
        }
        if !(p.momentum > 0.0 && p.momentum <= 1.0) {
            return bad(
                "paper.momentum",
                format!("{} must lie in (0, 1]", p.momentum),
            );
        }
        if !(p.clip.is_finite() && p.clip > 0.0) {
            return bad("paper.clip", format!("{} must be finite and > 0", p.clip));
        }
        Ok(())
    }

    /// Parses and validates a TOML table such as `steps_n = 10\nlearning_rate = 40.0`.
    pub fn from_toml_str(text: &str) -> Result<Self, GuidanceError> {
        let s: Self = toml::from_str(text).map_err(|e| GuidanceError::Parse(e.to_string()))?;
        s.validate()?;
        Ok(s)
    }
}

/// Why sampling or guidance failed.
#[derive(Debug, thiserror::Error)]
pub enum GuidanceError {
    /// A setting is out of range.
    #[error("invalid guidance setting `{field}`: {message}")]
    InvalidSettings {
        /// The setting's TOML key (`iterations_m`, `paper.momentum`, ...).
        field: &'static str,
        /// What is wrong with its value.
        message: String,
    },
    /// The TOML text of the settings could not be parsed (syntax, unknown key, wrong type).
    #[error("cannot parse guidance settings: {0}")]
    Parse(String),
    /// The initial poses, sample indices or buffers do not fit the model or the workspace.
    #[error("shape mismatch: {0}")]
    Shape(String),
    /// The flow model failed.
    #[error(transparent)]
    Flow(#[from] FlowError),
    /// A constraint term of Φ failed.
    #[error(transparent)]
    Constraint(#[from] ConstraintError),
    /// A non-finite number appeared; nothing non-finite is returned.
    #[error("non-finite value in the {stage} of iteration {iteration}")]
    NonFinite {
        /// Where it appeared (`flow velocity`, `rollout`, `feasibility cost`, ...).
        stage: &'static str,
        /// The iteration of Algorithm 1 (0: the plain rollout).
        iteration: usize,
    },
    /// The deadline had passed before the first integration step, so there is no sample.
    #[error("the deadline passed before the first integration step")]
    DeadlineBeforeSampling,
}

/// What [`sample_guided`] returns. Trajectories are flat `[K, T, 3]` in the ego frame, without
/// the prepended current pose.
#[derive(Clone, Debug, PartialEq)]
pub struct GuidanceResult {
    /// Number of samples `K`.
    pub samples: usize,
    /// Poses per sample `T`.
    pub horizon: usize,
    /// The plain rollout (`u = 0`).
    pub unguided: Vec<f64>,
    /// The final rollout with the optimised controls (equal to `unguided` when guidance is off).
    pub guided: Vec<f64>,
    /// Φ of each unguided sample.
    pub phi_before: Vec<f64>,
    /// Φ of each guided sample.
    pub phi_after: Vec<f64>,
    /// Number of control updates made (≤ `iterations_m`).
    pub iterations_run: usize,
    /// Integration steps of the plain rollout that called the network: `steps_n` unless the
    /// deadline cut sampling short (the remaining steps then continued at the last velocity).
    pub steps_run: usize,
    /// True when the deadline ended sampling or guidance early.
    pub cut_short: bool,
}

impl GuidanceResult {
    /// Guided sample `k` as poses.
    pub fn guided_poses(&self, k: usize) -> Vec<Pose2> {
        let n = self.horizon * 3;
        self.guided[k * n..(k + 1) * n]
            .chunks_exact(3)
            .map(Pose2::from_slice)
            .collect()
    }

    /// Unguided sample `k` as poses.
    pub fn unguided_poses(&self, k: usize) -> Vec<Pose2> {
        let n = self.horizon * 3;
        self.unguided[k * n..(k + 1) * n]
            .chunks_exact(3)
            .map(Pose2::from_slice)
            .collect()
    }
}

/// Reusable buffers of guidance. Create once (e.g. per planner) and pass to every call.
#[derive(Clone, Debug, Default)]
pub struct GuidanceWorkspace {
    /// True when `xs`/`ws` hold a complete rollout with zero controls.
    plain: bool,
    samples: usize,
    horizon: usize,
    steps: usize,
    /// Rollout states `x_0 … x_N`, `(N + 1)·K·T·3`.
    xs: Vec<f64>,
    /// Velocities `w_i = f(x_i) + u_i`, `N·K·T·3`.
    ws: Vec<f64>,
    /// Controls `u_i`, `N·K·T·3`.
    u: Vec<f64>,
    /// Direction `d_i` of the control update, `N·K·T·3`: `∂J/∂u_i` or its preconditioned form
    /// (adaptive variant), `μ_{t_i}` (paper variant).
    dir: Vec<f64>,
    /// The co-state `μ_{i+1}`, then `μ_i`, during the backward pass.
    mu: Vec<f64>,
    /// Cotangent `S_wᵀ·μ_{i+1}` of the flow model's VJP.
    cot: Vec<f64>,
    /// `S_xᵀ·μ_{i+1}` per waypoint during the backward pass.
    back: Vec<f64>,
    /// `x_i ⊕ u_{t_i}`, where the paper variant evaluates the model's VJP (line 8).
    shifted: Vec<f64>,
    fout: Vec<f64>,
    vjp: Vec<f64>,
    /// Final samples with the current pose prepended, `K·(T + 1)·3`, and Φ's gradient there.
    ext: Vec<f64>,
    ext_grad: Vec<f64>,
    phi: Vec<f64>,
    active: Vec<bool>,
    /// Per-sample step size `γ_k` (adaptive).
    step: Vec<f64>,
    /// The last accepted iterate, restored for a sample whose Φ rose.
    saved_xs: Vec<f64>,
    saved_ws: Vec<f64>,
    saved_u: Vec<f64>,
    saved_phi: Vec<f64>,
    saved_ext_grad: Vec<f64>,
    /// Adam's first and second moments of the last-step iterations, `K·T·3`.
    adam_m: Vec<f64>,
    adam_v: Vec<f64>,
    /// Preconditioner scratch: twist-space gradient `[T, 3]` and a tridiagonal solve `[T]`.
    gxi: Vec<f64>,
    tri: Vec<f64>,
    scratch: PhiScratch,
}

impl GuidanceWorkspace {
    /// An empty workspace; buffers grow on first use.
    pub fn new() -> Self {
        Self::default()
    }

    fn prepare(&mut self, samples: usize, horizon: usize, steps: usize) {
        self.samples = samples;
        self.horizon = horizon;
        self.steps = steps;
        let m = samples * horizon * 3;
        self.xs.resize((steps + 1) * m, 0.0);
        self.ws.resize(steps * m, 0.0);
        self.u.resize(steps * m, 0.0);
        self.dir.resize(steps * m, 0.0);
        for b in [
            &mut self.mu,
            &mut self.cot,
            &mut self.back,
            &mut self.shifted,
            &mut self.fout,
            &mut self.vjp,
        ] {
            b.resize(m, 0.0);
        }
        let e = samples * (horizon + 1) * 3;
        self.ext.resize(e, 0.0);
        self.ext_grad.resize(e, 0.0);
        self.phi.resize(samples, 0.0);
        self.active.resize(samples, true);
        self.gxi.resize(horizon * 3, 0.0);
        self.tri.resize(horizon, 0.0);
    }

    /// Remembers the current iterate (states, velocities, controls, Φ and ∇Φ).
    fn save(&mut self) {
        self.saved_xs.clone_from(&self.xs);
        self.saved_ws.clone_from(&self.ws);
        self.saved_u.clone_from(&self.u);
        self.saved_phi.clone_from(&self.phi);
        self.saved_ext_grad.clone_from(&self.ext_grad);
    }

    /// Per active sample: keep the new iterate and grow the step when Φ did not rise, else
    /// restore the saved iterate and shrink the step.
    fn accept_or_restore(&mut self) {
        for b in 0..self.samples {
            if !self.active[b] {
                continue;
            }
            if self.phi[b] <= self.saved_phi[b] {
                self.step[b] *= STEP_GROW;
            } else {
                self.step[b] *= STEP_SHRINK;
                self.restore(b);
            }
        }
    }

    /// Every sample back to the saved iterate (an iteration the deadline cut short).
    fn restore_all(&mut self) {
        for b in 0..self.samples {
            self.restore(b);
        }
    }

    /// Sample `b`'s current iterate becomes its saved one (the last-step iterations keep each
    /// sample's best). Only the last step's states and controls change there.
    fn save_sample(&mut self, b: usize) {
        let m = self.size();
        let per = self.horizon * 3;
        let per_ext = (self.horizon + 1) * 3;
        self.saved_phi[b] = self.phi[b];
        let e = b * per_ext..(b + 1) * per_ext;
        self.saved_ext_grad[e.clone()].copy_from_slice(&self.ext_grad[e]);
        let n = self.steps;
        let last = (n - 1) * m + b * per..(n - 1) * m + (b + 1) * per;
        let fin = n * m + b * per..n * m + (b + 1) * per;
        self.saved_xs[fin.clone()].copy_from_slice(&self.xs[fin]);
        self.saved_ws[last.clone()].copy_from_slice(&self.ws[last.clone()]);
        self.saved_u[last.clone()].copy_from_slice(&self.u[last]);
    }

    /// Sample `b`'s states, velocities, controls, Φ and ∇Φ back to the saved iterate.
    fn restore(&mut self, b: usize) {
        let m = self.size();
        let per = self.horizon * 3;
        let per_ext = (self.horizon + 1) * 3;
        self.phi[b] = self.saved_phi[b];
        let e = b * per_ext..(b + 1) * per_ext;
        self.ext_grad[e.clone()].copy_from_slice(&self.saved_ext_grad[e]);
        for i in 0..=self.steps {
            let r = i * m + b * per..i * m + (b + 1) * per;
            self.xs[r.clone()].copy_from_slice(&self.saved_xs[r.clone()]);
            if i < self.steps {
                self.ws[r.clone()].copy_from_slice(&self.saved_ws[r.clone()]);
                self.u[r.clone()].copy_from_slice(&self.saved_u[r]);
            }
        }
    }

    fn size(&self) -> usize {
        self.samples * self.horizon * 3
    }

    /// The final rollout state `x_N`.
    fn final_state(&self) -> &[f64] {
        let m = self.size();
        &self.xs[self.steps * m..(self.steps + 1) * m]
    }
}

/// Number of samples in `x0`, after checking its shape against the model.
fn sample_count(
    model: &(impl FlowModel + ?Sized),
    x0: &[f64],
) -> Result<(usize, usize), GuidanceError> {
    let t = model.horizon();
    if t == 0 || x0.is_empty() || x0.len() % (3 * t) != 0 {
        return Err(GuidanceError::Shape(format!(
            "{} initial values are not whole trajectories of {t} poses × 3",
            x0.len()
        )));
    }
    Ok((x0.len() / (3 * t), t))
}

fn all_finite(v: &[f64]) -> bool {
    v.iter().all(|x| x.is_finite())
}

/// Rescales `v` to norm `max` if it is longer.
#[inline]
fn clip3(v: &mut [f64], max: f64) {
    let n2 = v[0] * v[0] + v[1] * v[1] + v[2] * v[2];
    if n2 > max * max {
        let s = max / n2.sqrt();
        v[0] *= s;
        v[1] *= s;
        v[2] *= s;
    }
}

/// Forward rollout `x_{i+1} = x_i·exp(Δt·(f(x_i, t_i) + u_i))`, filling `xs` and `ws`.
/// `xs[0..m]` must already hold `x_0`. Returns the number of steps taken: `N`, or fewer when
/// `deadline` passed before a step's network call (the later states are then stale).
fn forward(
    model: &(impl FlowModel + ?Sized),
    cond: &FlowCondition,
    ws: &mut GuidanceWorkspace,
    iteration: usize,
    deadline: &Deadline,
) -> Result<usize, GuidanceError> {
    let m = ws.size();
    let n = ws.steps;
    let dt = 1.0 / n as f64;
    for i in 0..n {
        if deadline.passed() {
            return Ok(i);
        }
        let t = i as f64 * dt;
        let (done, rest) = ws.xs.split_at_mut((i + 1) * m);
        let x = &done[i * m..];
        model.velocity(x, t, cond, &mut ws.fout)?;
        if !all_finite(&ws.fout) {
            return Err(GuidanceError::NonFinite {
                stage: "flow velocity",
                iteration,
            });
        }
        let w = &mut ws.ws[i * m..(i + 1) * m];
        let u = &ws.u[i * m..(i + 1) * m];
        for j in 0..m {
            w[j] = ws.fout[j] + u[j];
        }
        let next = &mut rest[..m];
        for ((p, v), o) in x
            .chunks_exact(3)
            .zip(w.chunks_exact(3))
            .zip(next.chunks_exact_mut(3))
        {
            let q = Pose2::from_slice(p).euler_step(Twist2::from_slice(v), dt);
            o.copy_from_slice(&q.to_array());
        }
        if !all_finite(next) {
            return Err(GuidanceError::NonFinite {
                stage: "rollout",
                iteration,
            });
        }
    }
    Ok(n)
}

/// Completes a rollout cut short after `from ≥ 1` steps: the steps `from … N − 1` continue at
/// each waypoint's last velocity `w_{from−1}` (no network call).
fn extrapolate(ws: &mut GuidanceWorkspace, from: usize) {
    let m = ws.size();
    let n = ws.steps;
    let dt = 1.0 / n as f64;
    for i in from..n {
        ws.ws.copy_within((from - 1) * m..from * m, i * m);
        let (done, rest) = ws.xs.split_at_mut((i + 1) * m);
        let x = &done[i * m..];
        let w = &ws.ws[i * m..(i + 1) * m];
        for ((p, v), o) in x
            .chunks_exact(3)
            .zip(w.chunks_exact(3))
            .zip(rest[..m].chunks_exact_mut(3))
        {
            let q = Pose2::from_slice(p).euler_step(Twist2::from_slice(v), dt);
            o.copy_from_slice(&q.to_array());
        }
    }
}

/// Φ and ∇Φ of the final state with the identity prepended; fills `phi` and `ext_grad`.
fn terminal_cost(
    phi: &Phi,
    ctx: &ConstraintContext<'_>,
    ws: &mut GuidanceWorkspace,
    iteration: usize,
) -> Result<(), GuidanceError> {
    let (k, t) = (ws.samples, ws.horizon);
    let m = ws.size();
    let n = ws.steps;
    for b in 0..k {
        let dst = &mut ws.ext[b * (t + 1) * 3..(b + 1) * (t + 1) * 3];
        dst[..3].copy_from_slice(&Pose2::IDENTITY.to_array());
        dst[3..].copy_from_slice(&ws.xs[n * m + b * t * 3..n * m + (b + 1) * t * 3]);
    }
    let batch = TrajBatch::new(&ws.ext, k, t + 1)?;
    phi.evaluate(batch, ctx, &mut ws.phi, &mut ws.ext_grad, &mut ws.scratch)?;
    if !all_finite(&ws.phi) || !all_finite(&ws.ext_grad) {
        return Err(GuidanceError::NonFinite {
            stage: "feasibility cost",
            iteration,
        });
    }
    Ok(())
}

/// The preconditioner of the terminal co-state: steepest descent in the space of the plan's
/// segment twists instead of its poses (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq)]
struct TwistMetric {
    /// Time step of the plan (s).
    dt: f64,
    /// Diagonal weight `W` of the twist components `(v, vy, ω)`.
    w: [f64; 3],
    /// Weight `c` of the acceleration smoothing `(I + c·DᵀD)⁻¹` of the speed component.
    c: f64,
    /// Overall scale `1/(dt·Δt)²`, so that a unit learning rate is a unit step in twist space
    /// through the last integration step.
    scale: f64,
}

impl TwistMetric {
    fn new(ctx: &ConstraintContext<'_>, steps_n: usize) -> Self {
        let l = ctx.limits;
        let sq = |v: f64| if v.is_finite() && v > 0.0 { v * v } else { 1.0 };
        let dt = ctx.dt;
        let flow_dt = 1.0 / steps_n as f64;
        Self {
            dt,
            w: [sq(l.v_max), sq(l.lateral_speed_max), sq(l.omega_max)],
            c: sq(l.v_max / (l.a_max * dt)),
            scale: 1.0 / (dt * flow_dt).powi(2),
        }
    }

    /// `μ ← scale·J·W·S·Jᵀ·μ` for every sample, `J = ∂(waypoints)/∂(segment twists)` along the
    /// plan in `ext` (`[K, T + 1, 3]`, pose 0 fixed) and `S` the speed smoothing.
    fn apply(
        &self,
        mu: &mut [f64],
        ext: &[f64],
        samples: usize,
        horizon: usize,
        gxi: &mut [f64],
        tri: &mut [f64],
    ) {
        let t = horizon;
        let dt = self.dt;
        for b in 0..samples {
            let poses = &ext[b * (t + 1) * 3..(b + 1) * (t + 1) * 3];
            let m = &mut mu[b * t * 3..(b + 1) * t * 3];
            let pose = |k: usize| Pose2::from_slice(&poses[3 * k..3 * k + 3]);
            // ξ_k with p_k = p_{k−1}·exp(dt·ξ_k) exactly.
            let twist = |k: usize| pose(k - 1).between(pose(k)).log().scale(1.0 / dt);
            // Jᵀ by reverse accumulation: λ_T = g_T, ∂/∂ξ_k = S_wᵀλ_k, λ_{k−1} = S_xᵀλ_k + g_{k−1}.
            let mut lambda = [m[3 * (t - 1)], m[3 * (t - 1) + 1], m[3 * (t - 1) + 2]];
            for k in (1..=t).rev() {
                let (sx, sw) = euler_step_jacobians(pose(k - 1), twist(k), dt);
                gxi[3 * (k - 1)..3 * k].copy_from_slice(&transpose_apply(&sw, lambda));
                if k >= 2 {
                    let back = transpose_apply(&sx, lambda);
                    for d in 0..3 {
                        lambda[d] = back[d] + m[3 * (k - 2) + d];
                    }
                }
            }
            smooth_speed(gxi, t, self.c, tri);
            for k in 0..t {
                for d in 0..3 {
                    gxi[3 * k + d] *= self.w[d] * self.scale;
                }
            }
            // J by forward accumulation: δp_0 = 0, δp_k = S_x·δp_{k−1} + S_w·δξ_k.
            let mut dp = [0.0; 3];
            for k in 1..=t {
                let (sx, sw) = euler_step_jacobians(pose(k - 1), twist(k), dt);
                let mut next = [0.0; 3];
                for r in 0..3 {
                    for c in 0..3 {
                        next[r] += sx[r][c] * dp[c] + sw[r][c] * gxi[3 * (k - 1) + c];
                    }
                }
                dp = next;
                m[3 * (k - 1)..3 * k].copy_from_slice(&dp);
            }
        }
    }
}

/// Replaces the speed components `g[3k]` by `(I + c·DᵀD)⁻¹·g`, `D` the first difference of the
/// segment speeds anchored at the (fixed) current speed: `DᵀD` is tridiagonal with diagonal
/// `2, …, 2, 1` and off-diagonals `−1`. Thomas algorithm, `scratch` holds `T` values.
fn smooth_speed(g: &mut [f64], t: usize, c: f64, scratch: &mut [f64]) {
    if c == 0.0 {
        return;
    }
    let diag = |k: usize| 1.0 + c * if k + 1 == t { 1.0 } else { 2.0 };
    let off = -c;
    // Forward sweep: scratch holds the modified super-diagonal.
    let mut denom = diag(0);
    scratch[0] = off / denom;
    g[0] /= denom;
    for k in 1..t {
        denom = diag(k) - off * scratch[k - 1];
        scratch[k] = off / denom;
        g[3 * k] = (g[3 * k] - off * g[3 * (k - 1)]) / denom;
    }
    for k in (0..t.saturating_sub(1)).rev() {
        g[3 * k] -= scratch[k] * g[3 * (k + 1)];
    }
}

/// `a⁻¹·v` for a 3×3 matrix by Cramer's rule, `None` when `a` is (nearly) singular.
fn solve3(a: &Jacobian3, v: [f64; 3]) -> Option<[f64; 3]> {
    let det = a[0][0] * (a[1][1] * a[2][2] - a[1][2] * a[2][1])
        - a[0][1] * (a[1][0] * a[2][2] - a[1][2] * a[2][0])
        + a[0][2] * (a[1][0] * a[2][1] - a[1][1] * a[2][0]);
    let scale = a.iter().flatten().fold(0.0f64, |m, x| m.max(x.abs()));
    if det.is_nan() || det.abs() <= 1e-12 * scale.powi(3) {
        return None;
    }
    let mut out = [0.0; 3];
    for c in 0..3 {
        let mut m = *a;
        for r in 0..3 {
            m[r][c] = v[r];
        }
        out[c] = (m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1])
            - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
            + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0]))
            / det;
    }
    Some(out)
}

/// What the backward pass leaves in `dir` for the control update, and how it treats the
/// co-states.
#[derive(Clone, Copy, Debug)]
enum Direction<'a> {
    /// `d_i = ∂J/∂u_i = S_wᵀ·μ_{i+1}`, every co-state clipped (the adaptive variant without
    /// preconditioning, and [`control_gradient`] with clipping off).
    Gradient,
    /// The adaptive variant with preconditioning: `μ_N` preconditioned by the metric,
    /// `d_i = Δt²·S_w⁻¹·μ_{i+1}`, the inner co-states not clipped.
    GaussNewton(&'a TwistMetric),
    /// The paper variant: the model's VJP at `x_i ⊕ u_{t_i}` (line 8), every co-state clipped
    /// (line 10), `d_i = μ_{t_i}` in `x_i`'s body frame (line 12), so `μ_0` is computed as well.
    CoState,
}

/// Adjoint backward pass (Alg. 1 lines 6-11): `μ_N = clip(∇_{x_N} Φ)`, then per step
/// `μ_i = clip(S_xᵀ·μ_{i+1} + (∂f/∂x)ᵀ·S_wᵀ·μ_{i+1})`, filling `dir` as `direction` says.
/// Returns false, with `dir` incomplete, when `deadline` passed before a network call.
fn backward(
    model: &(impl FlowModel + ?Sized),
    cond: &FlowCondition,
    ws: &mut GuidanceWorkspace,
    clip: f64,
    direction: Direction<'_>,
    iteration: usize,
    deadline: &Deadline,
) -> Result<bool, GuidanceError> {
    let (k, t) = (ws.samples, ws.horizon);
    let m = ws.size();
    let n = ws.steps;
    let dt = 1.0 / n as f64;
    // μ_N: ∇Φ at the T generated poses (pose 0 of the extended batch is fixed), clipped per
    // waypoint (line 6).
    for b in 0..k {
        let src = &ws.ext_grad[(b * (t + 1) + 1) * 3..(b + 1) * (t + 1) * 3];
        ws.mu[b * t * 3..(b + 1) * t * 3].copy_from_slice(src);
    }
    for c in ws.mu.chunks_exact_mut(3) {
        clip3(c, clip);
    }
    let mut clip_inner = clip;
    if let Direction::GaussNewton(metric) = direction {
        metric.apply(&mut ws.mu, &ws.ext, k, t, &mut ws.gxi, &mut ws.tri);
        // After preconditioning the co-states are steps, not gradients, and the adaptive step
        // bounds them.
        clip_inner = f64::INFINITY;
    }
    let paper = matches!(direction, Direction::CoState);
    for i in (0..n).rev() {
        pull_back_step(ws, i, dt, direction);
        if i == 0 && !paper {
            break;
        }
        if deadline.passed() {
            return Ok(false);
        }
        if paper {
            shift_by_controls(ws, i, dt);
        }
        let x = if paper {
            &ws.shifted[..]
        } else {
            &ws.xs[i * m..(i + 1) * m]
        };
        model.velocity_vjp(x, i as f64 * dt, cond, &ws.cot, &mut ws.fout, &mut ws.vjp)?;
        if !all_finite(&ws.vjp) {
            return Err(GuidanceError::NonFinite {
                stage: "flow vector-Jacobian product",
                iteration,
            });
        }
        // μ_i = clip(S_xᵀ·μ_{i+1} + vjp) (lines 9-10).
        let d = &mut ws.dir[i * m..(i + 1) * m];
        for (j, out) in ws.mu.chunks_exact_mut(3).enumerate() {
            for c in 0..3 {
                out[c] = ws.back[3 * j + c] + ws.vjp[3 * j + c];
            }
            clip3(out, clip_inner);
            if paper {
                // Line 12 subtracts μ_{t_i} from u_{t_i} ∈ se(2) at x_i: the co-state of a right
                // perturbation x_i·exp(δ), i.e. its translation part in x_i's body frame.
                let theta = ws.xs[i * m + 3 * j + 2];
                d[3 * j..3 * j + 3].copy_from_slice(&to_body(theta, out));
            }
        }
    }
    if !all_finite(&ws.dir) {
        return Err(GuidanceError::NonFinite {
            stage: "adjoint pass",
            iteration,
        });
    }
    Ok(true)
}

/// One step of the backward pass before the model's VJP: with `(S_x, S_w)` the Jacobians of the
/// step `x_{i+1} = x_i·exp(Δt·w_i)` at the forward pass's `(x_i, w_i)`, writes `S_xᵀ·μ_{i+1}`
/// into `back` and the cotangent `S_wᵀ·μ_{i+1}` into `cot`, and, for the adaptive directions,
/// `d_i` into `dir`.
fn pull_back_step(ws: &mut GuidanceWorkspace, i: usize, dt: f64, direction: Direction<'_>) {
    let m = ws.size();
    let x = &ws.xs[i * m..(i + 1) * m];
    let w = &ws.ws[i * m..(i + 1) * m];
    let d = &mut ws.dir[i * m..(i + 1) * m];
    for j in 0..m / 3 {
        let r = 3 * j..3 * j + 3;
        let (sx, sw) = euler_step_jacobians(
            Pose2::from_slice(&x[r.clone()]),
            Twist2::from_slice(&w[r.clone()]),
            dt,
        );
        let mu = [ws.mu[3 * j], ws.mu[3 * j + 1], ws.mu[3 * j + 2]];
        let c = transpose_apply(&sw, mu);
        ws.back[r.clone()].copy_from_slice(&transpose_apply(&sx, mu));
        ws.cot[r.clone()].copy_from_slice(&c);
        match direction {
            Direction::Gradient => d[r].copy_from_slice(&c),
            // The control moves along S_w⁻¹·μ·Δt² (Gauss-Newton through the step) so that the
            // realised change of the pose is the preconditioned direction.
            Direction::GaussNewton(_) => {
                let step = solve3(&sw, mu).map_or(c, |v| v.map(|e| e * dt * dt));
                d[r].copy_from_slice(&step);
            }
            Direction::CoState => {}
        }
    }
}

/// `(R(θ)ᵀ·(v_x, v_y), v_θ)`: a coordinate gradient at a pose of heading `θ` as the gradient
/// with respect to a right perturbation `x·exp(δ)` of that pose (same norm).
fn to_body(theta: f64, v: &[f64]) -> [f64; 3] {
    let (s, c) = theta.sin_cos();
    [c * v[0] + s * v[1], -s * v[0] + c * v[1], v[2]]
}

/// `shifted = x_i ⊕ u_{t_i} = x_i·exp(u_{t_i})` per waypoint, with `u_{t_i} = Δt·u_i` the
/// control as a displacement in the algebra (the point of line 8).
fn shift_by_controls(ws: &mut GuidanceWorkspace, i: usize, dt: f64) {
    let m = ws.size();
    let x = &ws.xs[i * m..(i + 1) * m];
    let u = &ws.u[i * m..(i + 1) * m];
    for ((p, v), o) in x
        .chunks_exact(3)
        .zip(u.chunks_exact(3))
        .zip(ws.shifted.chunks_exact_mut(3))
    {
        let q = Pose2::from_slice(p).euler_step(Twist2::from_slice(v), dt);
        o.copy_from_slice(&q.to_array());
    }
}

fn start(
    model: &(impl FlowModel + ?Sized),
    x0: &[f64],
    steps_n: usize,
    ws: &mut GuidanceWorkspace,
) -> Result<(), GuidanceError> {
    if steps_n == 0 || steps_n > MAX_STEPS_N {
        return Err(GuidanceError::InvalidSettings {
            field: "steps_n",
            message: format!("{steps_n} must lie in 1 to {MAX_STEPS_N}"),
        });
    }
    let (k, t) = sample_count(model, x0)?;
    if !all_finite(x0) {
        return Err(GuidanceError::NonFinite {
            stage: "initial poses",
            iteration: 0,
        });
    }
    ws.plain = false;
    ws.prepare(k, t, steps_n);
    ws.xs[..x0.len()].copy_from_slice(x0);
    ws.u.fill(0.0);
    Ok(())
}

/// Plain sampling: the `steps_n`-step Lie-group Euler rollout of `x0` (flat `[K, T, 3]`) under the
/// flow model, without guidance. Returns the final poses, `[K, T, 3]`.
pub fn sample(
    model: &(impl FlowModel + ?Sized),
    cond: &FlowCondition,
    x0: &[f64],
    steps_n: usize,
    ws: &mut GuidanceWorkspace,
) -> Result<Vec<f64>, GuidanceError> {
    start(model, x0, steps_n, ws)?;
    forward(model, cond, ws, 0, &Deadline::never())?;
    ws.plain = true;
    Ok(ws.final_state().to_vec())
}

/// The exact gradient of `Σ_k Φ(x_N^k)` with respect to the controls `u` (`N·K·T·3`, step-major)
/// without any clipping, written into `grad`; returns Φ per sample. This is the quantity the
/// guidance loop descends, exposed for tests and diagnostics.
pub fn control_gradient(
    model: &(impl FlowModel + ?Sized),
    cond: &FlowCondition,
    x0: &[f64],
    controls: &[f64],
    phi: &Phi,
    ctx: &ConstraintContext<'_>,
    steps_n: usize,
    ws: &mut GuidanceWorkspace,
    grad: &mut [f64],
) -> Result<Vec<f64>, GuidanceError> {
    start(model, x0, steps_n, ws)?;
    if controls.len() != ws.u.len() || grad.len() != ws.u.len() {
        return Err(GuidanceError::Shape(format!(
            "controls ({}) and gradient ({}) must both hold N·K·T·3 = {} values",
            controls.len(),
            grad.len(),
            ws.u.len()
        )));
    }
    ws.u.copy_from_slice(controls);
    let never = Deadline::never();
    forward(model, cond, ws, 0, &never)?;
    terminal_cost(phi, ctx, ws, 0)?;
    backward(
        model,
        cond,
        ws,
        f64::INFINITY,
        Direction::Gradient,
        0,
        &never,
    )?;
    grad.copy_from_slice(&ws.dir);
    Ok(ws.phi.clone())
}

/// Feasibility-guided sampling (Algorithm 1) of the samples starting at `x0` (flat
/// `[K, T, 3]`, `T = model.horizon()`). See the module docs for the method.
pub fn sample_guided(
    model: &(impl FlowModel + ?Sized),
    cond: &FlowCondition,
    x0: &[f64],
    phi: &Phi,
    ctx: &ConstraintContext<'_>,
    settings: &GuidanceSettings,
    ws: &mut GuidanceWorkspace,
) -> Result<GuidanceResult, GuidanceError> {
    sample_guided_until(model, cond, x0, phi, ctx, settings, ws, &Deadline::never())
}

/// [`sample_guided`] that starts no network call after `deadline` (module docs,
/// "Deadlines"). A rollout cut short leaves the workspace unusable for [`guide_subset`].
pub fn sample_guided_until(
    model: &(impl FlowModel + ?Sized),
    cond: &FlowCondition,
    x0: &[f64],
    phi: &Phi,
    ctx: &ConstraintContext<'_>,
    settings: &GuidanceSettings,
    ws: &mut GuidanceWorkspace,
    deadline: &Deadline,
) -> Result<GuidanceResult, GuidanceError> {
    settings.validate()?;
    start(model, x0, settings.steps_n, ws)?;
    let steps_run = forward(model, cond, ws, 0, deadline)?;
    if steps_run == 0 {
        return Err(GuidanceError::DeadlineBeforeSampling);
    }
    if steps_run < ws.steps {
        extrapolate(ws, steps_run);
        terminal_cost(phi, ctx, ws, 0)?;
        let poses = ws.final_state().to_vec();
        return Ok(GuidanceResult {
            samples: ws.samples,
            horizon: ws.horizon,
            unguided: poses.clone(),
            guided: poses,
            phi_before: ws.phi.clone(),
            phi_after: ws.phi.clone(),
            iterations_run: 0,
            steps_run,
            cut_short: true,
        });
    }
    ws.plain = true;
    optimise(model, cond, phi, ctx, settings, ws, deadline)
}

/// Algorithm 1 on the samples `keep` (ascending indices) of the rollout the previous
/// [`sample`] or [`sample_guided`] call left in `ws`, without integrating them again: the same
/// result as [`sample_guided`] on those samples' initial poses, `N` network calls cheaper. The
/// returned trajectories are in the order of `keep`. `settings.steps_n` must be the `N` of that
/// rollout.
pub fn guide_subset(
    model: &(impl FlowModel + ?Sized),
    cond: &FlowCondition,
    keep: &[usize],
    phi: &Phi,
    ctx: &ConstraintContext<'_>,
    settings: &GuidanceSettings,
    ws: &mut GuidanceWorkspace,
) -> Result<GuidanceResult, GuidanceError> {
    guide_subset_until(
        model,
        cond,
        keep,
        phi,
        ctx,
        settings,
        ws,
        &Deadline::never(),
    )
}

/// [`guide_subset`] that starts no network call after `deadline`: the result is the last
/// iterate of Algorithm 1 completed by then (module docs, "Deadlines").
pub fn guide_subset_until(
    model: &(impl FlowModel + ?Sized),
    cond: &FlowCondition,
    keep: &[usize],
    phi: &Phi,
    ctx: &ConstraintContext<'_>,
    settings: &GuidanceSettings,
    ws: &mut GuidanceWorkspace,
    deadline: &Deadline,
) -> Result<GuidanceResult, GuidanceError> {
    settings.validate()?;
    if !ws.plain || ws.steps != settings.steps_n || ws.samples == 0 {
        return Err(GuidanceError::Shape(format!(
            "the workspace must hold an unguided rollout with N = {} (it holds {} samples with \
             N = {}{})",
            settings.steps_n,
            ws.samples,
            ws.steps,
            if ws.plain {
                ""
            } else {
                ", not a plain rollout"
            }
        )));
    }
    if keep.is_empty()
        || keep.windows(2).any(|w| w[0] >= w[1])
        || keep.last().is_some_and(|&i| i >= ws.samples)
    {
        return Err(GuidanceError::Shape(format!(
            "sample indices {keep:?} must be ascending, distinct and below {}",
            ws.samples
        )));
    }
    // Compact every step's block to the kept samples. Destinations never pass their sources
    // (indices ascend), so copying front to back is safe in place.
    let per = ws.horizon * 3;
    let (m_old, m_new) = (ws.size(), keep.len() * per);
    for i in 0..=ws.steps {
        for (j, &src) in keep.iter().enumerate() {
            let (from, to) = (i * m_old + src * per, i * m_new + j * per);
            ws.xs.copy_within(from..from + per, to);
            if i < ws.steps {
                ws.ws.copy_within(from..from + per, to);
            }
        }
    }
    ws.prepare(keep.len(), ws.horizon, ws.steps);
    ws.u.fill(0.0);
    optimise(model, cond, phi, ctx, settings, ws, deadline)
}

/// Algorithm 1 from the plain rollout held in `ws` (controls zero).
fn optimise(
    model: &(impl FlowModel + ?Sized),
    cond: &FlowCondition,
    phi: &Phi,
    ctx: &ConstraintContext<'_>,
    settings: &GuidanceSettings,
    ws: &mut GuidanceWorkspace,
    deadline: &Deadline,
) -> Result<GuidanceResult, GuidanceError> {
    terminal_cost(phi, ctx, ws, 0)?;

    let unguided = ws.final_state().to_vec();
    let phi_before = ws.phi.clone();
    let run = match (settings.enabled, settings.variant) {
        (false, _) => Iterations::default(),
        (true, GuidanceVariant::Adaptive) => {
            iterate_adaptive(model, cond, phi, ctx, settings, ws, deadline)?
        }
        (true, GuidanceVariant::Paper) => {
            iterate_paper(model, cond, phi, ctx, settings, ws, deadline)?
        }
    };
    ws.plain = run.completed == 0;
    Ok(GuidanceResult {
        samples: ws.samples,
        horizon: ws.horizon,
        unguided,
        guided: ws.final_state().to_vec(),
        phi_before,
        phi_after: ws.phi.clone(),
        iterations_run: run.completed,
        steps_run: ws.steps,
        cut_short: run.cut_short,
    })
}

/// How an iteration loop of Algorithm 1 ended.
#[derive(Clone, Copy, Debug, Default)]
struct Iterations {
    /// Iterations completed (their result kept).
    completed: usize,
    /// True when the deadline ended the loop before `M` iterations or the early stop.
    cut_short: bool,
}

/// One iteration of Algorithm 1 under a deadline: saves the iterate (when `save` or a
/// deadline is set), runs the backward pass, the control update and the forward rollout with Φ,
/// and returns false, with the saved iterate restored, when the deadline cut it short.
fn iteration_step(
    model: &(impl FlowModel + ?Sized),
    cond: &FlowCondition,
    phi: &Phi,
    ctx: &ConstraintContext<'_>,
    ws: &mut GuidanceWorkspace,
    (clip, direction, momentum, clip_dir): (f64, Direction<'_>, f64, f64),
    save: bool,
    iteration: usize,
    deadline: &Deadline,
) -> Result<bool, GuidanceError> {
    let guarded = !deadline.is_never();
    if save || guarded {
        ws.save();
    }
    if !backward(model, cond, ws, clip, direction, iteration, deadline)? {
        ws.restore_all();
        return Ok(false);
    }
    update_controls(ws, momentum, clip_dir);
    if forward(model, cond, ws, iteration, deadline)? < ws.steps {
        ws.restore_all();
        return Ok(false);
    }
    terminal_cost(phi, ctx, ws, iteration)?;
    Ok(true)
}

/// The adaptive variant's iterations.
fn iterate_adaptive(
    model: &(impl FlowModel + ?Sized),
    cond: &FlowCondition,
    phi: &Phi,
    ctx: &ConstraintContext<'_>,
    settings: &GuidanceSettings,
    ws: &mut GuidanceWorkspace,
    deadline: &Deadline,
) -> Result<Iterations, GuidanceError> {
    ws.step.clear();
    ws.step.resize(ws.samples, settings.learning_rate);
    let metric = settings
        .precondition
        .then(|| TwistMetric::new(ctx, settings.steps_n));
    let (direction, clip_dir) = match &metric {
        Some(metric) => (Direction::GaussNewton(metric), f64::INFINITY),
        None => (Direction::Gradient, settings.clip),
    };
    let mut run = Iterations::default();
    for iteration in 1..=settings.iterations_m {
        let mut any = false;
        for (a, p) in ws.active.iter_mut().zip(&ws.phi) {
            *a = *p >= settings.tolerance;
            any |= *a;
        }
        if !any {
            break;
        }
        let step = (settings.clip, direction, settings.momentum, clip_dir);
        let save = settings.adaptive_step;
        if !iteration_step(model, cond, phi, ctx, ws, step, save, iteration, deadline)? {
            run.cut_short = true;
            break;
        }
        if settings.adaptive_step {
            ws.accept_or_restore();
        }
        run.completed = iteration;
    }
    if settings.last_step_iterations > 0 && !run.cut_short {
        last_step_iterations(phi, ctx, settings, ws, deadline)?;
    }
    Ok(run)
}

/// The last-step iterations (module docs, "Last-step iterations"): line 12's update restricted
/// to `u_{N−1}`, whose path to `x_N` crosses no network call, with Adam's per-coordinate step on
/// the waypoint gradient `∇Φ`, on every sample; each sample ends at its best iterate.
fn last_step_iterations(
    phi: &Phi,
    ctx: &ConstraintContext<'_>,
    settings: &GuidanceSettings,
    ws: &mut GuidanceWorkspace,
    deadline: &Deadline,
) -> Result<(), GuidanceError> {
    let (k, t) = (ws.samples, ws.horizon);
    let m = ws.size();
    let n = ws.steps;
    let dt = 1.0 / n as f64;
    let last = (n - 1) * m;
    let rate = settings.last_step_rate;
    ws.adam_m.clear();
    ws.adam_m.resize(m, 0.0);
    ws.adam_v.clear();
    ws.adam_v.resize(m, 0.0);
    // The saved iterate is each sample's best so far.
    ws.save();
    for iteration in 0..settings.last_step_iterations {
        if deadline.passed() {
            break;
        }
        for b in 0..k {
            let src = &ws.ext_grad[(b * (t + 1) + 1) * 3..(b + 1) * (t + 1) * 3];
            ws.mu[b * t * 3..(b + 1) * t * 3].copy_from_slice(src);
        }
        let bias1 = 1.0 - ADAM_BETA1.powi(iteration as i32 + 1);
        let bias2 = 1.0 - ADAM_BETA2.powi(iteration as i32 + 1);
        for j in 0..m / 3 {
            let r = 3 * j..3 * j + 3;
            clip3(&mut ws.mu[r.clone()], settings.clip);
            // Adam's step of the waypoint, then the control change that realises it to first
            // order through the step's Jacobian S_w (which contains Δt).
            let mut dx = [0.0; 3];
            for (e, d) in r.clone().zip(dx.iter_mut()) {
                let g = ws.mu[e];
                ws.adam_m[e] = ADAM_BETA1 * ws.adam_m[e] + (1.0 - ADAM_BETA1) * g;
                ws.adam_v[e] = ADAM_BETA2 * ws.adam_v[e] + (1.0 - ADAM_BETA2) * g * g;
                *d = -rate * (ws.adam_m[e] / bias1) / ((ws.adam_v[e] / bias2).sqrt() + ADAM_EPS);
            }
            let x = Pose2::from_slice(&ws.xs[last + r.start..last + r.end]);
            let w = &mut ws.ws[last + r.start..last + r.end];
            let (_, sw) = euler_step_jacobians(x, Twist2::from_slice(w), dt);
            let du = solve3(&sw, dx).unwrap_or(dx.map(|e| e / dt));
            let u = &mut ws.u[last + r.start..last + r.end];
            for e in 0..3 {
                u[e] += du[e];
                w[e] += du[e];
            }
            let q = x.euler_step(Twist2::from_slice(w), dt);
            ws.xs[n * m + r.start..n * m + r.end].copy_from_slice(&q.to_array());
        }
        if !all_finite(&ws.xs[n * m..]) {
            return Err(GuidanceError::NonFinite {
                stage: "last-step iterations",
                iteration,
            });
        }
        terminal_cost(phi, ctx, ws, iteration)?;
        for b in 0..k {
            if ws.phi[b] < ws.saved_phi[b] {
                ws.save_sample(b);
            }
        }
    }
    for b in 0..k {
        if ws.phi[b] > ws.saved_phi[b] {
            ws.restore(b);
        }
    }
    Ok(())
}

/// The paper variant: exactly `M` iterations of Algorithm 1 on every sample (module docs, "The
/// paper variant"), fewer only when the deadline cuts them short. The rollout in `ws` is the
/// first iteration's line 5.
fn iterate_paper(
    model: &(impl FlowModel + ?Sized),
    cond: &FlowCondition,
    phi: &Phi,
    ctx: &ConstraintContext<'_>,
    settings: &GuidanceSettings,
    ws: &mut GuidanceWorkspace,
    deadline: &Deadline,
) -> Result<Iterations, GuidanceError> {
    let p = settings.paper;
    // `u` holds velocities, `u_{t_i} = Δt·u_i`: line 12's step γ on `u_{t_i}` is γ/Δt on `u_i`.
    let dt = 1.0 / ws.steps as f64;
    ws.active.fill(true);
    ws.step.clear();
    ws.step.resize(ws.samples, p.learning_rate / dt);
    let mut run = Iterations::default();
    for iteration in 1..=settings.iterations_m {
        // Lines 6-11, line 12 (the co-states are already clipped), then line 5 of the next
        // iteration, or line 14 after the last, with Φ and ∇Φ for line 6.
        let step = (p.clip, Direction::CoState, p.momentum, f64::INFINITY);
        if !iteration_step(model, cond, phi, ctx, ws, step, false, iteration, deadline)? {
            run.cut_short = true;
            break;
        }
        run.completed = iteration;
    }
    Ok(run)
}

/// Line 12: `u_i ← β·u_i − γ_k·d_i` for every active sample `k` (`γ_k` its step), `d_i` first
/// clipped per waypoint to `clip_dir`.
fn update_controls(ws: &mut GuidanceWorkspace, momentum: f64, clip_dir: f64) {
    let m = ws.size();
    let per_sample = ws.horizon * 3;
    for i in 0..ws.steps {
        let u = &mut ws.u[i * m..(i + 1) * m];
        let g = &mut ws.dir[i * m..(i + 1) * m];
        for (b, active) in ws.active.iter().enumerate() {
            if !active {
                continue;
            }
            let lr = ws.step[b];
            let r = b * per_sample..(b + 1) * per_sample;
            for (uc, gc) in u[r.clone()]
                .chunks_exact_mut(3)
                .zip(g[r].chunks_exact_mut(3))
            {
                clip3(gc, clip_dir);
                for d in 0..3 {
                    uc[d] = momentum * uc[d] - lr * gc[d];
                }
            }
        }
    }
}

#[cfg(test)]
mod tests;
