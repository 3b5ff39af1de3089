//! The paper variant of Algorithm 1 (module docs, "The paper variant"): its iterations, and the
//! two parts of the backward pass only it uses: the point `x_i ⊕ u_{t_i}` of the model's VJP
//! (line 8) and the co-state in the body frame (line 12).

use super::*;

/// The paper variant: exactly `M` iterations of Algorithm 1 on every sample (module docs, "The
/// paper variant"), fewer only when the deadline cuts them short. The rollout in `ws` is the
/// first iteration's line 5.
pub(super) fn iterate_paper(
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

/// `(R(θ)ᵀ·(v_x, v_y), v_θ)`: a coordinate gradient at a pose of heading `θ` as the gradient
/// with respect to a right perturbation `x·exp(δ)` of that pose (same norm).
pub(super) fn to_body(theta: f64, v: &[f64]) -> [f64; 3] {
    let (s, c) = theta.sin_cos();
    [c * v[0] + s * v[1], -s * v[0] + c * v[1], v[2]]
}

/// `shifted = x_i ⊕ u_{t_i} = x_i·exp(u_{t_i})` per waypoint, with `u_{t_i} = Δt·u_i` the
/// control as a displacement in the algebra (the point of line 8).
pub(super) fn shift_by_controls(ws: &mut GuidanceWorkspace, i: usize, dt: f64) {
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
