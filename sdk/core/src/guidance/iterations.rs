//! The iteration loop of Algorithm 1 shared by both variants: from the plain rollout to the
//! result, one iteration under a deadline, and the control update (line 12).

use super::*;

/// Algorithm 1 from the plain rollout held in `ws` (controls zero).
pub(super) fn optimise(
    model: &(impl FlowModel + ?Sized),
    cond: &FlowCondition,
    phi: &Phi,
    ctx: &ConstraintContext<'_>,
    settings: &GuidanceSettings,
    ws: &mut GuidanceWorkspace,
    deadline: &Deadline,
) -> Result<GuidanceResult, GuidanceError> {
    terminal_cost(phi, ctx, ws, 0)?;
    // A subset of a rollout was not evaluated as such: its VJPs start from its own states.
    let evaluated = ws.steps * ws.size();
    ws.evaluated[..evaluated].copy_from_slice(&ws.xs[..evaluated]);

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
pub(super) struct Iterations {
    /// Iterations completed (their result kept).
    pub(super) completed: usize,
    /// True when the deadline ended the loop before `M` iterations or the early stop.
    pub(super) cut_short: bool,
}

/// One iteration of Algorithm 1 under a deadline: saves the iterate (when `save` or a
/// deadline is set), runs the backward pass, the control update and the forward rollout with Φ,
/// and returns false, with the saved iterate restored, when the deadline cut it short.
pub(super) fn iteration_step(
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
    ws.dir_current.fill(false);
    if forward(model, cond, ws, iteration, deadline)? < ws.steps {
        ws.restore_all();
        return Ok(false);
    }
    terminal_cost(phi, ctx, ws, iteration)?;
    Ok(true)
}

/// Line 12: `u_i ← β·u_i − γ_k·d_i` for every active sample `k` (`γ_k` its step), `d_i` first
/// clipped per waypoint to `clip_dir`.
fn update_controls(ws: &mut GuidanceWorkspace, momentum: f64, clip_dir: f64) {
    let m = ws.size();
    let per_sample = ws.horizon * 3;
    for i in 0..ws.steps {
        let u = &mut ws.u[i * m..(i + 1) * m];
        let g = &ws.dir[i * m..(i + 1) * m];
        for (b, active) in ws.active.iter().enumerate() {
            if !active {
                continue;
            }
            let lr = ws.step[b];
            let r = b * per_sample..(b + 1) * per_sample;
            for (uc, gc) in u[r.clone()].chunks_exact_mut(3).zip(g[r].chunks_exact(3)) {
                // Clipped in a copy: a restored sample takes the same direction again.
                let mut gc = [gc[0], gc[1], gc[2]];
                clip3(&mut gc, clip_dir);
                for d in 0..3 {
                    uc[d] = momentum * uc[d] - lr * gc[d];
                }
            }
        }
    }
}
