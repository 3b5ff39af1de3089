//! The entry points: plain sampling, the control gradient, and Algorithm 1 on new samples or
//! on a subset of a rollout, each with its `_until` form that stops at a deadline.

use super::*;

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
