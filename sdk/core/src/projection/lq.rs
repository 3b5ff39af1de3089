//! The last-step correction's QP solved by its structure: a primal-dual interior-point method
//! (Mehrotra's predictor-corrector) whose Newton steps are linear-quadratic control problems,
//! each solved by one backward Riccati recursion and one forward rollout.
//!
//! # The problem
//!
//! Controls `u_k = δξ_k ∈ ℝ³` (the change of segment `k`'s twist), states `e_k ∈ ℝ³` (the
//! linearised change of pose `k`) with `e_k = A_k·e_{k−1} + B_k·u_k`, `e_{−1} = 0`:
//!
//! `min Σ_k ½ρ·|u_k|² + ½·e_kᵀ·W·e_k + q_kᵀ·e_k`  subject to rows
//! `a_u·u_k + a_p·u_{k−1,v} ≤ b` (a row of stage `k` may also hold the previous segment's speed
//! change: the acceleration limit).
//!
//! This is the QP that [`super::solve_step`] hands Clarabel with the states as variables and
//! the dynamics as equalities. Clarabel factorises its ~`6T + 10T` sparse KKT system at every
//! iteration; here the Newton system is an LQ problem in the augmented state
//! `x_k = (e_k, u_{k,v})` (4 numbers: the speed change is carried so the next stage's
//! acceleration rows can see it) and control `u_k` (3), so each step costs `O(T)` products of
//! 4×4 matrices.
//!
//! # Newton step
//!
//! With slacks `s` (`C·u + s = d`), multipliers `λ`, `Σ = diag(λ/s)` and the residuals
//! `r_d = ∇f + Cᵀλ`, `r_p = C·u + s − d`, `r_c = s∘λ − σμ` (plus Mehrotra's second-order term),
//! the step `Δu` minimises `½·Δuᵀ(∇²f + CᵀΣC)Δu + gᵀΔu` with `g = r_d − Cᵀ((r_c − λ∘r_p)/s)`;
//! then `Δs = −r_p − C·Δu` and `Δλ = (λ∘(C·Δu + r_p) − r_c)/s`. `∇²f` is the LQ cost through the
//! dynamics (`ρ` on the controls, `W` on the states), `CᵀΣC` adds per-stage terms on
//! `(u_{k−1,v}, u_k)`.

/// A 3×3 matrix, row-major.
type M3 = [[f64; 3]; 3];
/// A 4×4 matrix over the augmented state `(e, u_v)`.
type M4 = [[f64; 4]; 4];
/// A 3×4 matrix (control × augmented state).
type M34 = [[f64; 4]; 3];

/// One inequality row of stage `stage`: `u·u_stage + p·u_{stage−1, v} ≤ b` (`p` is 0 at
/// stage 0).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct StageRow {
    pub stage: usize,
    pub u: [f64; 3],
    pub p: f64,
    pub b: f64,
}

/// The problem of the module docs.
pub(super) struct LqProblem<'a> {
    /// `A_k` (the pose Jacobian of step `k`).
    pub a: &'a [M3],
    /// `B_k` (the twist Jacobian of step `k`, `dt` included).
    pub b: &'a [M3],
    /// The diagonal of `W`.
    pub w: [f64; 3],
    /// `q_k`.
    pub q: &'a [[f64; 3]],
    /// `ρ > 0`.
    pub effort: f64,
    /// The rows, in stage order.
    pub rows: &'a [StageRow],
}

/// Largest number of interior-point iterations before the solver gives up (the caller then
/// falls back to Clarabel, which can also certify infeasibility).
const MAX_ITERATIONS: usize = 60;
/// Relative tolerance on the primal residual (the rows, in m/s).
const TOLERANCE: f64 = 1e-9;
/// Relative tolerance on the dual residual, the gradient of the Lagrangian (relative to the
/// largest pose-error gradient, `W·r`). Round-off keeps it above about 1e-8 of that once the
/// largest `λ/s` reach 1e15, and iterating on from there makes the Newton systems singular.
const DUAL_TOLERANCE: f64 = 1e-7;
/// Largest mean complementarity `sᵀλ/m` of a solution (the rows are in m/s and the
/// multipliers of order one to a hundred: 1e-10 leaves every active row within 1e-8 of its
/// bound, far inside the 1 % margin the rows keep).
const GAP_TOLERANCE: f64 = 1e-10;
/// A mean complementarity past which the iterates are taken to diverge (an infeasible
/// problem: its multipliers grow without bound).
const DIVERGED: f64 = 1e12;
/// Fraction of the distance to the boundary a step may go.
const STEP_TO_BOUNDARY: f64 = 0.99;

/// Why the structured solver gave up.
#[derive(Debug, PartialEq)]
pub(super) enum LqError {
    /// A Newton system was not positive definite, or a value became non-finite.
    Breakdown,
    /// No convergence within [`MAX_ITERATIONS`] (also what an infeasible problem gives).
    NotConverged,
}

/// The solver's scratch, kept from call to call (every buffer is overwritten).
#[derive(Clone, Debug, Default)]
pub(super) struct LqWorkspace {
    u: Vec<[f64; 3]>,
    s: Vec<f64>,
    /// `1/s`, refreshed with `s` (the Newton steps divide by every slack several times).
    inv_s: Vec<f64>,
    lam: Vec<f64>,
    e: Vec<[f64; 3]>,
    /// Per row, the weight of its coefficients in the Newton step's linear term.
    y: Vec<f64>,
    rd: Vec<[f64; 3]>,
    rp: Vec<f64>,
    rc: Vec<f64>,
    g: Vec<[f64; 3]>,
    du: Vec<[f64; 3]>,
    ds: Vec<f64>,
    dl: Vec<f64>,
    chol: Vec<M3>,
    gain: Vec<M34>,
    hux: Vec<M34>,
    kff: Vec<[f64; 3]>,
}

/// Row `i`'s value `a_u·u_k + a_p·u_{k−1,v}`.
#[inline]
fn row_value(r: &StageRow, u: &[[f64; 3]]) -> f64 {
    let k = r.stage;
    let mut v = r.u[0] * u[k][0] + r.u[1] * u[k][1] + r.u[2] * u[k][2];
    if k > 0 {
        v += r.p * u[k - 1][0];
    }
    v
}

/// `out += Cᵀ·y`, the rows' terms added in row order. The rows come in stage order, so each
/// stage's run of rows adds into values held in registers (through memory, every row's sum
/// waited for the previous row's store).
fn add_ct(rows: &[StageRow], y: &[f64], out: &mut [[f64; 3]]) {
    let mut i = 0;
    while i < rows.len() {
        let k = rows[i].stage;
        let mut acc = out[k];
        let mut prev = if k > 0 { out[k - 1][0] } else { 0.0 };
        while i < rows.len() && rows[i].stage == k {
            let (r, yi) = (&rows[i], y[i]);
            for c in 0..3 {
                acc[c] += r.u[c] * yi;
            }
            prev += r.p * yi;
            i += 1;
        }
        out[k] = acc;
        if k > 0 {
            out[k - 1][0] = prev;
        }
    }
}

/// Cholesky factor (lower) of a 3×3 symmetric positive-definite matrix.
fn cholesky3(m: &M3) -> Option<M3> {
    let mut l = [[0.0; 3]; 3];
    for i in 0..3 {
        for j in 0..=i {
            let mut sum = m[i][j];
            for k in 0..j {
                sum -= l[i][k] * l[j][k];
            }
            if i == j {
                if !(sum > 0.0 && sum.is_finite()) {
                    return None;
                }
                l[i][i] = sum.sqrt();
            } else {
                l[i][j] = sum / l[j][j];
            }
        }
    }
    Some(l)
}

/// `x` with `L·Lᵀ·x = b`.
fn chol_solve(l: &M3, b: [f64; 3]) -> [f64; 3] {
    let mut y = [0.0; 3];
    for i in 0..3 {
        let mut s = b[i];
        for k in 0..i {
            s -= l[i][k] * y[k];
        }
        y[i] = s / l[i][i];
    }
    let mut x = [0.0; 3];
    for i in (0..3).rev() {
        let mut s = y[i];
        for k in i + 1..3 {
            s -= l[k][i] * x[k];
        }
        x[i] = s / l[i][i];
    }
    x
}

/// The augmented dynamics `x_k = Â·x_{k−1} + B̂·u_k`: `Â = [[A, 0], [0, 0]]`,
/// `B̂ = [[B], [1, 0, 0]]`. Applied without forming them.
#[inline]
fn step(a: &M3, b: &M3, x: &[f64; 4], u: &[f64; 3]) -> [f64; 4] {
    let mut out = [0.0; 4];
    for r in 0..3 {
        out[r] = a[r][0] * x[0]
            + a[r][1] * x[1]
            + a[r][2] * x[2]
            + b[r][0] * u[0]
            + b[r][1] * u[1]
            + b[r][2] * u[2];
    }
    out[3] = u[0];
    out
}

impl LqWorkspace {
    fn reset(&mut self, t: usize, m: usize) {
        let z3 = [0.0; 3];
        for v in [
            &mut self.u,
            &mut self.e,
            &mut self.rd,
            &mut self.g,
            &mut self.du,
            &mut self.kff,
        ] {
            v.clear();
            v.resize(t, z3);
        }
        for v in [
            &mut self.s,
            &mut self.inv_s,
            &mut self.lam,
            &mut self.y,
            &mut self.rp,
            &mut self.rc,
            &mut self.ds,
            &mut self.dl,
        ] {
            v.clear();
            v.resize(m, 0.0);
        }
        self.chol.resize(t, [[0.0; 3]; 3]);
        self.gain.resize(t, [[0.0; 4]; 3]);
        self.hux.resize(t, [[0.0; 4]; 3]);
    }
}

/// Solves the problem; returns `δξ` flat (`3·T`).
pub(super) fn solve(p: &LqProblem<'_>, ws: &mut LqWorkspace) -> Result<Vec<f64>, LqError> {
    let t = p.a.len();
    let m = p.rows.len();
    ws.reset(t, m);
    // Mehrotra's starting point: from u = 0, s = λ = 1, take the full affine Newton step and
    // bring every slack and multiplier back to at least 1 (the infeasible start is what the
    // primal residual is for).
    ws.s.fill(1.0);
    ws.lam.fill(1.0);
    residuals(p, ws);
    factor(p, ws)?;
    for i in 0..m {
        ws.rc[i] = ws.s[i] * ws.lam[i];
    }
    newton(p, ws);
    for k in 0..t {
        ws.u[k] = ws.du[k];
    }
    for i in 0..m {
        ws.s[i] = (ws.s[i] + ws.ds[i]).abs().max(1.0);
        ws.lam[i] = (ws.lam[i] + ws.dl[i]).abs().max(1.0);
    }
    let scale_p = 1.0 + p.rows.iter().map(|r| r.b.abs()).fold(0.0, f64::max);
    let scale_d = 1.0
        + p.q
            .iter()
            .flat_map(|q| q.iter().map(|v| v.abs()))
            .fold(0.0, f64::max);
    for _ in 0..MAX_ITERATIONS {
        residuals(p, ws);
        let mu = if m == 0 {
            0.0
        } else {
            ws.s.iter().zip(&ws.lam).map(|(s, l)| s * l).sum::<f64>() / m as f64
        };
        let rp = ws.rp.iter().fold(0.0f64, |a, v| a.max(v.abs()));
        let rd = ws
            .rd
            .iter()
            .flat_map(|v| v.iter().map(|x| x.abs()))
            .fold(0.0f64, f64::max);
        if !(mu.is_finite() && rp.is_finite() && rd.is_finite()) {
            return Err(LqError::Breakdown);
        }
        // Multipliers running away while the rows stay violated: an infeasible problem (the
        // caller's fallback certifies it).
        if mu > DIVERGED {
            return Err(LqError::NotConverged);
        }
        if rp <= TOLERANCE * scale_p && rd <= DUAL_TOLERANCE * scale_d && mu <= GAP_TOLERANCE {
            return Ok(ws.u.iter().flatten().copied().collect());
        }
        factor(p, ws)?;
        // Predictor (affine) step: r_c = s∘λ. (The elementwise loops run over slices zipped
        // together, so that they run four rows at a time.)
        for ((rc, &s), &lam) in ws.rc.iter_mut().zip(&ws.s).zip(&ws.lam) {
            *rc = s * lam;
        }
        newton(p, ws);
        let alpha = step_length(ws);
        let mu_aff = (0..m)
            .map(|i| (ws.s[i] + alpha * ws.ds[i]) * (ws.lam[i] + alpha * ws.dl[i]))
            .sum::<f64>()
            / m.max(1) as f64;
        let sigma = if mu > 0.0 {
            (mu_aff / mu).powi(3).min(1.0)
        } else {
            0.0
        };
        // Corrector: r_c = s∘λ + Δs_aff∘Δλ_aff − σμ (`Δs`, `Δλ` still hold the affine step).
        let shift = sigma * mu;
        let rows = ws.rc.iter_mut().zip(ws.s.iter().zip(&ws.lam));
        for ((rc, (&s, &lam)), (&ds, &dl)) in rows.zip(ws.ds.iter().zip(&ws.dl)) {
            *rc = s * lam + ds * dl - shift;
        }
        newton(p, ws);
        let alpha = (STEP_TO_BOUNDARY * step_length(ws)).min(1.0);
        for (u, du) in ws.u.iter_mut().flatten().zip(ws.du.iter().flatten()) {
            *u += alpha * du;
        }
        for (s, ds) in ws.s.iter_mut().zip(&ws.ds) {
            *s += alpha * ds;
        }
        for (lam, dl) in ws.lam.iter_mut().zip(&ws.dl) {
            *lam += alpha * dl;
        }
    }
    Err(LqError::NotConverged)
}

/// The largest `α ≤ 1` that keeps `s + α·Δs` and `λ + α·Δλ` non-negative. Without branches
/// (whether a step shrinks a slack is a coin toss to the branch predictor) and four rows at a
/// time: a minimum is exact, so the order it is taken in does not change it.
fn step_length(ws: &LqWorkspace) -> f64 {
    #[inline(always)]
    fn lesser(a: f64, b: f64) -> f64 {
        if b < a { b } else { a }
    }
    /// The step bound of one row's slack and multiplier, taken into `a`.
    #[inline(always)]
    fn take(a: f64, s: f64, ds: f64, lam: f64, dl: f64) -> f64 {
        let bound = |v: f64, d: f64| if d < 0.0 { -v / d } else { f64::INFINITY };
        lesser(lesser(a, bound(s, ds)), bound(lam, dl))
    }
    fn quads(v: &[f64]) -> std::slice::ChunksExact<'_, f64> {
        v.chunks_exact(4)
    }
    let mut lanes = [1.0f64; 4];
    let rows = quads(&ws.s)
        .zip(quads(&ws.ds))
        .zip(quads(&ws.lam).zip(quads(&ws.dl)));
    for ((s, ds), (lam, dl)) in rows {
        for j in 0..4 {
            lanes[j] = take(lanes[j], s[j], ds[j], lam[j], dl[j]);
        }
    }
    let first = lanes.into_iter().fold(1.0, lesser);
    let tail = ws.s.len() / 4 * 4;
    (tail..ws.s.len()).fold(first, |a, i| {
        take(a, ws.s[i], ws.ds[i], ws.lam[i], ws.dl[i])
    })
}

/// `e` by rollout, `C·u`, `r_p = C·u + s − d` and `r_d = ∇f + Cᵀλ` (the gradient by the
/// adjoint recursion).
fn residuals(p: &LqProblem<'_>, ws: &mut LqWorkspace) {
    let t = p.a.len();
    let mut x = [0.0; 4];
    for k in 0..t {
        x = step(&p.a[k], &p.b[k], &x, &ws.u[k]);
        ws.e[k] = [x[0], x[1], x[2]];
    }
    for (i, r) in p.rows.iter().enumerate() {
        ws.rp[i] = row_value(r, &ws.u) + ws.s[i] - r.b;
    }
    // Apart from the rows' gathers, so that the divisions run four at a time.
    for (inv, &s) in ws.inv_s.iter_mut().zip(&ws.s) {
        *inv = 1.0 / s;
    }
    // Co-state of e_k: c_k = W·e_k + q_k + A_{k+1}ᵀ·c_{k+1}; ∂f/∂u_k = ρ·u_k + B_kᵀ·c_k.
    let mut co = [0.0; 3];
    for k in (0..t).rev() {
        let mut c = [0.0; 3];
        for r in 0..3 {
            c[r] = p.w[r] * ws.e[k][r] + p.q[k][r];
        }
        if k + 1 < t {
            let a = &p.a[k + 1];
            for r in 0..3 {
                c[r] += (0..3).map(|j| a[j][r] * co[j]).sum::<f64>();
            }
        }
        let b = &p.b[k];
        for r in 0..3 {
            ws.rd[k][r] = p.effort * ws.u[k][r] + (0..3).map(|j| b[j][r] * c[j]).sum::<f64>();
        }
        co = c;
    }
    add_ct(p.rows, &ws.lam, &mut ws.rd);
}

/// The backward Riccati recursion's matrices for `Σ = λ/s`: per stage the Cholesky factor of
/// `H_uu`, the gain `K = −H_uu⁻¹·H_ux` and `H_ux` (what [`newton`] needs for any right-hand
/// side).
fn factor(p: &LqProblem<'_>, ws: &mut LqWorkspace) -> Result<(), LqError> {
    let t = p.a.len();
    let mut big_p: M4 = [[0.0; 4]; 4];
    let mut row = p.rows.len();
    for k in (0..t).rev() {
        for r in 0..3 {
            big_p[r][r] += p.w[r];
        }
        // Row terms of stage k over y = (u_{k−1,v}, u_k): σ·a·aᵀ.
        let mut m_uu = [[0.0; 3]; 3];
        let mut m_up = [0.0; 3];
        let mut m_pp = 0.0;
        while row > 0 && p.rows[row - 1].stage == k {
            row -= 1;
            let r = &p.rows[row];
            let sigma = ws.lam[row] * ws.inv_s[row];
            for i in 0..3 {
                for j in 0..3 {
                    m_uu[i][j] += sigma * r.u[i] * r.u[j];
                }
                m_up[i] += sigma * r.u[i] * r.p;
            }
            m_pp += sigma * r.p * r.p;
        }
        let (a, b) = (&p.a[k], &p.b[k]);
        // B̂ᵀP and ÂᵀP (Â, B̂ as in `step`).
        let mut btp = [[0.0; 4]; 3];
        for i in 0..3 {
            for j in 0..4 {
                btp[i][j] = (0..3).map(|r| b[r][i] * big_p[r][j]).sum::<f64>()
                    + if i == 0 { big_p[3][j] } else { 0.0 };
            }
        }
        let mut huu = m_uu;
        for i in 0..3 {
            huu[i][i] += p.effort;
            for j in 0..3 {
                huu[i][j] += (0..3).map(|r| btp[i][r] * b[r][j]).sum::<f64>()
                    + if j == 0 { btp[i][3] } else { 0.0 };
            }
        }
        let mut hux: M34 = [[0.0; 4]; 3];
        for i in 0..3 {
            for j in 0..3 {
                hux[i][j] = (0..3).map(|r| btp[i][r] * a[r][j]).sum::<f64>();
            }
            hux[i][3] = m_up[i];
        }
        // Near the solution some λ/s reach 1e15 and round-off can leave H_uu (positive
        // definite in exact arithmetic: ρ > 0) just short of it: a relative nudge restores it.
        let l = cholesky3(&huu)
            .or_else(|| {
                let nudge = 1e-12
                    * huu
                        .iter()
                        .enumerate()
                        .map(|(i, r)| r[i])
                        .fold(1.0, f64::max);
                for (i, r) in huu.iter_mut().enumerate() {
                    r[i] += nudge;
                }
                cholesky3(&huu)
            })
            .ok_or(LqError::Breakdown)?;
        let mut gain: M34 = [[0.0; 4]; 3];
        for j in 0..4 {
            let col = chol_solve(&l, [hux[0][j], hux[1][j], hux[2][j]]);
            for i in 0..3 {
                gain[i][j] = -col[i];
            }
        }
        // P ← ÂᵀPÂ + M_pp + H_uxᵀ·K (symmetric).
        let mut np: M4 = [[0.0; 4]; 4];
        for i in 0..3 {
            for j in 0..3 {
                np[i][j] = (0..3)
                    .map(|r| a[r][i] * (0..3).map(|c| big_p[r][c] * a[c][j]).sum::<f64>())
                    .sum();
            }
        }
        np[3][3] = m_pp;
        for i in 0..4 {
            for j in 0..4 {
                np[i][j] += (0..3).map(|r| hux[r][i] * gain[r][j]).sum::<f64>();
            }
        }
        for i in 0..4 {
            for j in 0..i {
                let v = 0.5 * (np[i][j] + np[j][i]);
                np[i][j] = v;
                np[j][i] = v;
            }
        }
        big_p = np;
        ws.chol[k] = l;
        ws.gain[k] = gain;
        ws.hux[k] = hux;
    }
    Ok(())
}

/// One Newton direction for the current `r_c` (module docs), with the matrices of [`factor`].
fn newton(p: &LqProblem<'_>, ws: &mut LqWorkspace) {
    let t = p.a.len();
    // g = r_d − Cᵀ((r_c − λ∘r_p)/s).
    ws.g.copy_from_slice(&ws.rd);
    for i in 0..p.rows.len() {
        ws.y[i] = (ws.lam[i] * ws.rp[i] - ws.rc[i]) * ws.inv_s[i];
    }
    add_ct(p.rows, &ws.y, &mut ws.g);
    // Backward: the value's linear term v (over the augmented state) and the feed-forward.
    let mut v = [0.0; 4];
    for k in (0..t).rev() {
        let (a, b) = (&p.a[k], &p.b[k]);
        let mut hu = ws.g[k];
        for i in 0..3 {
            hu[i] += (0..3).map(|r| b[r][i] * v[r]).sum::<f64>() + if i == 0 { v[3] } else { 0.0 };
        }
        let kff = chol_solve(&ws.chol[k], hu).map(|x| -x);
        let mut nv = [0.0; 4];
        for i in 0..3 {
            nv[i] = (0..3).map(|r| a[r][i] * v[r]).sum();
        }
        for i in 0..4 {
            nv[i] += (0..3).map(|r| ws.hux[k][r][i] * kff[r]).sum::<f64>();
        }
        v = nv;
        ws.kff[k] = kff;
    }
    // Forward rollout of the step.
    let mut x = [0.0; 4];
    for k in 0..t {
        let gk = &ws.gain[k];
        let mut du = ws.kff[k];
        for i in 0..3 {
            du[i] += (0..4).map(|j| gk[i][j] * x[j]).sum::<f64>();
        }
        ws.du[k] = du;
        x = step(&p.a[k], &p.b[k], &x, &du);
    }
    for (i, r) in p.rows.iter().enumerate() {
        ws.ds[i] = -ws.rp[i] - row_value(r, &ws.du);
    }
    // `C·Δu + r_p` is `−Δs` (`(−a) − b` rounds as `−(a + b)`; only a zero's sign can
    // differ, which no later step sees), so this loop needs no gathers and runs four rows at
    // a time.
    let rows = ws.dl.iter_mut().zip(&ws.ds).zip(&ws.lam);
    for (((dl, &ds), &lam), (&rc, &inv_s)) in rows.zip(ws.rc.iter().zip(&ws.inv_s)) {
        *dl = (lam * -ds - rc) * inv_s;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// Rows of stages `0..t` in stage order, some stages without rows.
    fn rows(rng: &mut ChaCha8Rng, t: usize) -> Vec<StageRow> {
        let mut rows = Vec::new();
        for stage in 0..t {
            for _ in 0..rng.random_range(0..5) {
                rows.push(StageRow {
                    stage,
                    u: [0, 1, 2].map(|_| rng.random_range(-2.0..2.0)),
                    p: rng.random_range(-1.0..1.0),
                    b: 0.0,
                });
            }
        }
        rows
    }

    #[test]
    fn add_ct_adds_every_rows_terms_in_row_order() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        for t in [1, 2, 7, 32] {
            let rows = rows(&mut rng, t);
            let y: Vec<f64> = rows.iter().map(|_| rng.random_range(-3.0..3.0)).collect();
            let start: Vec<[f64; 3]> = (0..t)
                .map(|_| [0, 1, 2].map(|_| rng.random_range(-1.0..1.0)))
                .collect();
            // The definition, one row at a time through memory.
            let mut want = start.clone();
            for (r, &yi) in rows.iter().zip(&y) {
                for c in 0..3 {
                    want[r.stage][c] += r.u[c] * yi;
                }
                if r.stage > 0 {
                    want[r.stage - 1][0] += r.p * yi;
                }
            }
            let mut got = start;
            add_ct(&rows, &y, &mut got);
            let bits = |v: &[[f64; 3]]| v.iter().flatten().map(|x| x.to_bits()).collect::<Vec<_>>();
            assert_eq!(bits(&got), bits(&want), "T = {t}");
        }
    }

    #[test]
    fn step_length_is_the_largest_step_that_keeps_every_slack_and_multiplier() {
        let mut rng = ChaCha8Rng::seed_from_u64(4);
        for m in 0..14 {
            let mut ws = LqWorkspace::default();
            ws.reset(1, m);
            for i in 0..m {
                ws.s[i] = rng.random_range(0.01..2.0);
                ws.lam[i] = rng.random_range(0.01..2.0);
                ws.ds[i] = rng.random_range(-3.0..1.0);
                ws.dl[i] = rng.random_range(-3.0..1.0);
            }
            let mut want = 1.0f64;
            for i in 0..m {
                if ws.ds[i] < 0.0 {
                    want = want.min(-ws.s[i] / ws.ds[i]);
                }
                if ws.dl[i] < 0.0 {
                    want = want.min(-ws.lam[i] / ws.dl[i]);
                }
            }
            assert_eq!(step_length(&ws).to_bits(), want.to_bits(), "m = {m}");
        }
    }
}
