//! The adaptive variant's preconditioner (module docs, "The adaptive variant"): the terminal
//! co-state in the plan's segment twists, and the 3×3 solve of the Gauss-Newton direction (which
//! the last-step iterations use too).

use super::*;

/// The preconditioner of the terminal co-state: steepest descent in the space of the plan's
/// segment twists instead of its poses (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct TwistMetric {
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
    pub(super) fn new(ctx: &ConstraintContext<'_>, steps_n: usize) -> Self {
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
    pub(super) fn apply(
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
pub(super) fn solve3(a: &Jacobian3, v: [f64; 3]) -> Option<[f64; 3]> {
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
