//! Feasibility-guided sampling (paper Algorithm 1, E-MSA with a PMP adjoint), generic over
//! [`FlowModel`] so it runs and is tested without libtorch.
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
//! the factor `Δt`), per waypoint:
//!
//! * `μ_N = clip(∇_{x_N} Φ)` (Alg. 1 line 6),
//! * `∂J/∂u_i = S_wᵀ·μ_{i+1}`,
//! * `μ_i = clip(S_xᵀ·μ_{i+1} + (∂f/∂x_i)ᵀ·S_wᵀ·μ_{i+1})` (lines 7-10), the second product by
//!   [`FlowModel::velocity_vjp`] with cotangent `S_wᵀ·μ_{i+1}`; `μ_0` is never needed, so the
//!   backward pass makes `N − 1` VJP calls.
//!
//! `clip(·)` rescales each waypoint's 3-vector to a Euclidean norm of at most
//! [`GuidanceSettings::clip`].
//!
//! # Control update (Alg. 1 line 12)
//!
//! `u_i ← β·u_i − γ·clip(∂J/∂u_i)` with `γ` = [`GuidanceSettings::learning_rate`] and
//! `β` = [`GuidanceSettings::momentum`]. Without clipping this is exactly gradient descent with
//! step `γ` on `Φ(x_N) + (1 − β)/(2γ)·Σ_i ‖u_i‖²`: `β < 1` is the effort penalty `∫L(u)` of
//! Eq. 7 that keeps the intervention minimal, `β = 1` plain gradient descent.
//!
//! # Iterations and early stop
//!
//! One iteration is a backward pass, a control update and a new forward rollout; the last
//! rollout is the result (line 14). The first rollout (`u = 0`) is the unguided sample. A sample
//! whose `Φ` is below [`GuidanceSettings::tolerance`] is frozen (its controls are not updated,
//! a feasible sample is left exactly as it is); the loop stops once every sample is frozen
//! (so in particular once their mean `Φ` is below the tolerance), or after `M` iterations.
//! Network calls: `N` for the first rollout, then `2N − 1` per iteration.
//!
//! Nothing non-finite leaves: a non-finite pose, velocity, cost or gradient is a
//! [`GuidanceError::NonFinite`] naming the stage.
//!
//! All buffers live in a reusable [`GuidanceWorkspace`]; once it has seen a batch of a given
//! shape, guidance allocates nothing but its result.

pub mod analytic;

use crate::constraint::{ConstraintContext, ConstraintError, Phi, PhiScratch, TrajBatch};
use crate::flow::{FlowCondition, FlowError, FlowModel};
use crate::se2::{Pose2, Twist2, euler_step_jacobians, transpose_apply};
use serde::{Deserialize, Serialize};

/// Parameters of Algorithm 1 (TOML table, every field optional).
///
/// Defaults: `enabled = true`, `steps_n = 10`, `iterations_m = 8`, `learning_rate = 50.0`,
/// `momentum = 0.9`, `clip = 10.0`, `tolerance = 1e-3`. See the module docs for what each does.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct GuidanceSettings {
    /// When false, sampling is the plain rollout (the "w/o guidance" ablation).
    pub enabled: bool,
    /// Number of Euler integration steps `N` (≥ 1).
    pub steps_n: usize,
    /// Maximum number of optimisation iterations `M` (0 disables guidance).
    pub iterations_m: usize,
    /// Step size `γ` of the control update (Algorithm 1's γ; not the softplus sharpness γ of
    /// Eq. 8, which is [`GuidanceWeights::gamma`](crate::GuidanceWeights)). Finite, ≥ 0.
    pub learning_rate: f64,
    /// `β` of the control update, in `[0, 1]`.
    pub momentum: f64,
    /// Largest Euclidean norm of a waypoint's co-state or control gradient (> 0; `inf` turns
    /// clipping off).
    pub clip: f64,
    /// A sample whose Φ is below this is left alone (finite, ≥ 0).
    pub tolerance: f64,
}

impl Default for GuidanceSettings {
    fn default() -> Self {
        Self {
            enabled: true,
            steps_n: 10,
            iterations_m: 8,
            learning_rate: 50.0,
            momentum: 0.9,
            clip: 10.0,
            tolerance: 1e-3,
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
    #[error("invalid guidance setting `{field}`: {message}")]
    InvalidSettings {
        field: &'static str,
        message: String,
    },
    #[error("cannot parse guidance settings: {0}")]
    Parse(String),
    #[error("shape mismatch: {0}")]
    Shape(String),
    #[error(transparent)]
    Flow(#[from] FlowError),
    #[error(transparent)]
    Constraint(#[from] ConstraintError),
    #[error("non-finite value in the {stage} of iteration {iteration}")]
    NonFinite {
        stage: &'static str,
        iteration: usize,
    },
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
    samples: usize,
    horizon: usize,
    steps: usize,
    /// Rollout states `x_0 … x_N`, `(N + 1)·K·T·3`.
    xs: Vec<f64>,
    /// Velocities `w_i = f(x_i) + u_i`, `N·K·T·3`.
    ws: Vec<f64>,
    /// Controls `u_i`, `N·K·T·3`.
    u: Vec<f64>,
    /// Gradient `∂J/∂u_i`, `N·K·T·3`.
    grad_u: Vec<f64>,
    mu: Vec<f64>,
    cot: Vec<f64>,
    fout: Vec<f64>,
    vjp: Vec<f64>,
    /// Final samples with the current pose prepended, `K·(T + 1)·3`, and Φ's gradient there.
    ext: Vec<f64>,
    ext_grad: Vec<f64>,
    phi: Vec<f64>,
    active: Vec<bool>,
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
        self.grad_u.resize(steps * m, 0.0);
        for b in [&mut self.mu, &mut self.cot, &mut self.fout, &mut self.vjp] {
            b.resize(m, 0.0);
        }
        let e = samples * (horizon + 1) * 3;
        self.ext.resize(e, 0.0);
        self.ext_grad.resize(e, 0.0);
        self.phi.resize(samples, 0.0);
        self.active.resize(samples, true);
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
/// `xs[0..m]` must already hold `x_0`.
fn forward(
    model: &(impl FlowModel + ?Sized),
    cond: &FlowCondition,
    ws: &mut GuidanceWorkspace,
    iteration: usize,
) -> Result<(), GuidanceError> {
    let m = ws.size();
    let n = ws.steps;
    let dt = 1.0 / n as f64;
    for i in 0..n {
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
    Ok(())
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

/// Adjoint backward pass: fills `grad_u` with `∂Φ(x_N)/∂u_i` (co-states clipped to `clip`).
fn backward(
    model: &(impl FlowModel + ?Sized),
    cond: &FlowCondition,
    ws: &mut GuidanceWorkspace,
    clip: f64,
    iteration: usize,
) -> Result<(), GuidanceError> {
    let (k, t) = (ws.samples, ws.horizon);
    let m = ws.size();
    let n = ws.steps;
    let dt = 1.0 / n as f64;
    // μ_N: ∇Φ at the T generated poses (pose 0 of the extended batch is fixed).
    for b in 0..k {
        let src = &ws.ext_grad[(b * (t + 1) + 1) * 3..(b + 1) * (t + 1) * 3];
        ws.mu[b * t * 3..(b + 1) * t * 3].copy_from_slice(src);
    }
    for c in ws.mu.chunks_exact_mut(3) {
        clip3(c, clip);
    }
    for i in (0..n).rev() {
        let x = &ws.xs[i * m..(i + 1) * m];
        let w = &ws.ws[i * m..(i + 1) * m];
        let g = &mut ws.grad_u[i * m..(i + 1) * m];
        // Cotangent S_wᵀ·μ_{i+1}: the control gradient and the input of the VJP.
        for j in 0..m / 3 {
            let r = 3 * j..3 * j + 3;
            let (_, sw) = euler_step_jacobians(
                Pose2::from_slice(&x[r.clone()]),
                Twist2::from_slice(&w[r.clone()]),
                dt,
            );
            let mu = [ws.mu[3 * j], ws.mu[3 * j + 1], ws.mu[3 * j + 2]];
            let c = transpose_apply(&sw, mu);
            g[r.clone()].copy_from_slice(&c);
            ws.cot[r].copy_from_slice(&c);
        }
        if i == 0 {
            break;
        }
        let t_i = i as f64 * dt;
        model.velocity_vjp(x, t_i, cond, &ws.cot, &mut ws.fout, &mut ws.vjp)?;
        if !all_finite(&ws.vjp) {
            return Err(GuidanceError::NonFinite {
                stage: "flow vector-Jacobian product",
                iteration,
            });
        }
        // μ_i = clip(S_xᵀ·μ_{i+1} + vjp).
        for j in 0..m / 3 {
            let r = 3 * j..3 * j + 3;
            let (sx, _) = euler_step_jacobians(
                Pose2::from_slice(&x[r.clone()]),
                Twist2::from_slice(&w[r.clone()]),
                dt,
            );
            let mu = [ws.mu[3 * j], ws.mu[3 * j + 1], ws.mu[3 * j + 2]];
            let back = transpose_apply(&sx, mu);
            let out = &mut ws.mu[r.clone()];
            for d in 0..3 {
                out[d] = back[d] + ws.vjp[3 * j + d];
            }
            clip3(out, clip);
        }
    }
    if !all_finite(&ws.grad_u) {
        return Err(GuidanceError::NonFinite {
            stage: "adjoint pass",
            iteration,
        });
    }
    Ok(())
}

fn start(
    model: &(impl FlowModel + ?Sized),
    x0: &[f64],
    steps_n: usize,
    ws: &mut GuidanceWorkspace,
) -> Result<(), GuidanceError> {
    if steps_n == 0 {
        return Err(GuidanceError::InvalidSettings {
            field: "steps_n",
            message: "must be at least 1".into(),
        });
    }
    let (k, t) = sample_count(model, x0)?;
    if !all_finite(x0) {
        return Err(GuidanceError::NonFinite {
            stage: "initial poses",
            iteration: 0,
        });
    }
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
    forward(model, cond, ws, 0)?;
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
    forward(model, cond, ws, 0)?;
    terminal_cost(phi, ctx, ws, 0)?;
    backward(model, cond, ws, f64::INFINITY, 0)?;
    grad.copy_from_slice(&ws.grad_u);
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
    settings.validate()?;
    start(model, x0, settings.steps_n, ws)?;
    forward(model, cond, ws, 0)?;
    terminal_cost(phi, ctx, ws, 0)?;
    let unguided = ws.final_state().to_vec();
    let phi_before = ws.phi.clone();
    let mut iterations_run = 0;
    if settings.enabled {
        let m = ws.size();
        let per_sample = ws.horizon * 3;
        for iteration in 1..=settings.iterations_m {
            let mut any = false;
            for (a, p) in ws.active.iter_mut().zip(&ws.phi) {
                *a = *p >= settings.tolerance;
                any |= *a;
            }
            if !any {
                break;
            }
            backward(model, cond, ws, settings.clip, iteration)?;
            for i in 0..ws.steps {
                let u = &mut ws.u[i * m..(i + 1) * m];
                let g = &mut ws.grad_u[i * m..(i + 1) * m];
                for (b, active) in ws.active.iter().enumerate() {
                    if !active {
                        continue;
                    }
                    let r = b * per_sample..(b + 1) * per_sample;
                    for (uc, gc) in u[r.clone()]
                        .chunks_exact_mut(3)
                        .zip(g[r].chunks_exact_mut(3))
                    {
                        clip3(gc, settings.clip);
                        for d in 0..3 {
                            uc[d] = settings.momentum * uc[d] - settings.learning_rate * gc[d];
                        }
                    }
                }
            }
            forward(model, cond, ws, iteration)?;
            terminal_cost(phi, ctx, ws, iteration)?;
            iterations_run = iteration;
        }
    }
    Ok(GuidanceResult {
        samples: ws.samples,
        horizon: ws.horizon,
        unguided,
        guided: ws.final_state().to_vec(),
        phi_before,
        phi_after: ws.phi.clone(),
        iterations_run,
    })
}
