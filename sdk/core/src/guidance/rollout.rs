//! The forward pass: the workspace set up from the initial poses, the Lie-group Euler rollout
//! (and its completion when a deadline cut it short) and Φ with its gradient at the end.

use super::*;
use crate::se2::euler_step_batch;

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

/// Forward rollout `x_{i+1} = x_i·exp(Δt·(f(x_i, t_i) + u_i))`, filling `xs` and `ws`.
/// `xs[0..m]` must already hold `x_0`. Returns the number of steps taken: `N`, or fewer when
/// `deadline` passed before a step's network call (the later states are then stale).
pub(super) fn forward(
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
        let t = flow_time(i, n);
        let (done, rest) = ws.xs.split_at_mut((i + 1) * m);
        let x = &done[i * m..];
        model.velocity(x, t, cond, &mut ws.fout)?;
        if !all_finite(&ws.fout) {
            return Err(GuidanceError::NonFinite {
                stage: "flow velocity",
                iteration,
            });
        }
        ws.evaluated[i * m..(i + 1) * m].copy_from_slice(x);
        let w = &mut ws.ws[i * m..(i + 1) * m];
        let u = &ws.u[i * m..(i + 1) * m];
        let next = &mut rest[..m];
        euler_advance(x, &ws.fout, u, dt, w, next);
        if !all_finite(next) {
            return Err(GuidanceError::NonFinite {
                stage: "rollout",
                iteration,
            });
        }
    }
    Ok(n)
}

/// One step of a rollout: the velocity `w = f + u` of every waypoint, and the waypoint it
/// reaches, `next = x·exp(dt·w)`.
pub(crate) fn euler_advance(
    x: &[f64],
    f: &[f64],
    u: &[f64],
    dt: f64,
    w: &mut [f64],
    next: &mut [f64],
) {
    for (w, (f, u)) in w.iter_mut().zip(f.iter().zip(u)) {
        *w = f + u;
    }
    next.copy_from_slice(x);
    euler_step_batch(next, w, dt);
}

/// The flow time of integration step `i` of `n`: `i·Δt` with `Δt = 1/n`, as every rollout
/// computes it (a velocity looked up by time must use the same bits).
pub(crate) fn flow_time(i: usize, n: usize) -> f64 {
    i as f64 * (1.0 / n as f64)
}

/// Completes a rollout cut short after `from ≥ 1` steps: the steps `from … N − 1` continue at
/// each waypoint's last velocity `w_{from−1}` (no network call).
pub(super) fn extrapolate(ws: &mut GuidanceWorkspace, from: usize) {
    let m = ws.size();
    let n = ws.steps;
    let dt = 1.0 / n as f64;
    for i in from..n {
        ws.ws.copy_within((from - 1) * m..from * m, i * m);
        let (done, rest) = ws.xs.split_at_mut((i + 1) * m);
        let x = &done[i * m..];
        let next = &mut rest[..m];
        next.copy_from_slice(x);
        euler_step_batch(next, &ws.ws[i * m..(i + 1) * m], dt);
    }
}

/// Φ and ∇Φ of the final state with the identity prepended; fills `phi` and `ext_grad`.
pub(super) fn terminal_cost(
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

pub(super) fn start(
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
