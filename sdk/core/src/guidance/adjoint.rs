//! The adjoint backward pass (Alg. 1 lines 6-11): the co-states pulled back through each
//! Euler step and the flow model's vector-Jacobian product, and the direction it leaves.

use super::*;

/// What the backward pass leaves in `dir` for the control update, and how it treats the
/// co-states.
#[derive(Clone, Copy, Debug)]
pub(super) enum Direction<'a> {
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
pub(super) fn backward(
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
    if ws.dir_current.iter().all(|&c| c) {
        // Every sample is where its direction was computed (module docs, "The adaptive
        // variant").
        return Ok(true);
    }
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
        // A sample restored since the rollout keeps its direction: the VJP takes it at the
        // state the rollout evaluated, with no cotangent, so that the batch is the one whose
        // forward pass the model may keep; the other samples are at their states (the same
        // ones, unless every direction is recomputed).
        let x = if paper {
            &ws.shifted[..]
        } else {
            let per = 3 * t;
            let at = &mut ws.evaluated[i * m..(i + 1) * m];
            for (b, current) in ws.dir_current.iter().enumerate() {
                if !current {
                    let r = b * per..(b + 1) * per;
                    at[r.clone()].copy_from_slice(&ws.xs[i * m + r.start..i * m + r.end]);
                }
            }
            &ws.evaluated[i * m..(i + 1) * m]
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
/// `d_i` into `dir`; zeros for a sample whose direction is current (`dir` kept).
fn pull_back_step(ws: &mut GuidanceWorkspace, i: usize, dt: f64, direction: Direction<'_>) {
    let m = ws.size();
    let per = ws.horizon;
    let x = &ws.xs[i * m..(i + 1) * m];
    let w = &ws.ws[i * m..(i + 1) * m];
    let d = &mut ws.dir[i * m..(i + 1) * m];
    for j in 0..m / 3 {
        let r = 3 * j..3 * j + 3;
        if ws.dir_current[j / per] {
            ws.cot[r.clone()].fill(0.0);
            ws.back[r].fill(0.0);
            continue;
        }
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
