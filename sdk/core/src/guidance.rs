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
//! phi_before` for every sample. A restored sample is back where the last backward pass
//! computed its direction, so the next backward pass does not compute it again: it asks the
//! network only for the other samples, at the states the rollout just evaluated (where the
//! model may still hold the forward pass), and is skipped when every sample was restored.
//! The direction is the same to the bit, as the network's rows do not depend on each other.
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
//! per iteration (`μ_0` is never needed), `N` when every sample was restored.
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

mod adaptive;
mod adjoint;
mod iterations;
mod paper;
mod precondition;
mod rollout;
mod sampling;
mod settings;

use adaptive::iterate_adaptive;
use adjoint::{Direction, backward};
use iterations::{Iterations, iteration_step, optimise};
use paper::{iterate_paper, shift_by_controls, to_body};
use precondition::{TwistMetric, solve3};
pub(crate) use rollout::{euler_advance, flow_time};
use rollout::{extrapolate, forward, start, terminal_cost};
pub use sampling::{
    control_gradient, guide_subset, guide_subset_until, sample, sample_guided, sample_guided_until,
};
pub use settings::{
    GuidanceSettings, GuidanceVariant, MAX_ITERATIONS_M, MAX_LAST_STEP_ITERATIONS, MAX_STEPS_N,
    PaperSettings, STEP_GROW, STEP_SHRINK,
};

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
    /// The states `x_0 … x_{N−1}` at which the last rollout called the model, `N·K·T·3`: the
    /// backward pass asks for its VJPs there, where the model may keep the forward passes.
    /// They differ from `xs` only in samples restored since.
    evaluated: Vec<f64>,
    /// Per sample: `dir` holds the direction at its current iterate (it was restored to the
    /// iterate where the last backward pass computed it), so the next backward pass skips it.
    dir_current: Vec<bool>,
    /// Never mark a direction current (tests: the reference that recomputes every one).
    recompute_directions: bool,
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
    saved_ext: Vec<f64>,
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
        self.evaluated.resize(steps * m, 0.0);
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
        self.dir_current.clear();
        self.dir_current.resize(samples, false);
        self.gxi.resize(horizon * 3, 0.0);
        self.tri.resize(horizon, 0.0);
    }

    /// Remembers the current iterate (states, velocities, controls, Φ, the final poses and ∇Φ
    /// there).
    fn save(&mut self) {
        self.saved_xs.clone_from(&self.xs);
        self.saved_ws.clone_from(&self.ws);
        self.saved_u.clone_from(&self.u);
        self.saved_phi.clone_from(&self.phi);
        self.saved_ext.clone_from(&self.ext);
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
                self.dir_current[b] = !self.recompute_directions;
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
        self.saved_ext[e.clone()].copy_from_slice(&self.ext[e.clone()]);
        self.saved_ext_grad[e.clone()].copy_from_slice(&self.ext_grad[e]);
        let n = self.steps;
        let last = (n - 1) * m + b * per..(n - 1) * m + (b + 1) * per;
        let fin = n * m + b * per..n * m + (b + 1) * per;
        self.saved_xs[fin.clone()].copy_from_slice(&self.xs[fin]);
        self.saved_ws[last.clone()].copy_from_slice(&self.ws[last.clone()]);
        self.saved_u[last.clone()].copy_from_slice(&self.u[last]);
    }

    /// Sample `b`'s states, velocities, controls, Φ, final poses and ∇Φ back to the saved
    /// iterate.
    fn restore(&mut self, b: usize) {
        let m = self.size();
        let per = self.horizon * 3;
        let per_ext = (self.horizon + 1) * 3;
        self.phi[b] = self.saved_phi[b];
        let e = b * per_ext..(b + 1) * per_ext;
        self.ext[e.clone()].copy_from_slice(&self.saved_ext[e.clone()]);
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

#[cfg(test)]
mod tests;
