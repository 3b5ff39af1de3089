//! The adaptive variant's iterations (module docs, "The adaptive variant") and the last-step
//! iterations that may follow them ("Last-step iterations").

use super::*;

/// Adam's `β₁`, `β₂` and `ε` in the last-step iterations (the usual defaults).
const ADAM_BETA1: f64 = 0.9;
const ADAM_BETA2: f64 = 0.999;
const ADAM_EPS: f64 = 1e-8;

/// The adaptive variant's iterations.
pub(super) fn iterate_adaptive(
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
