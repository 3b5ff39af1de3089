//! The QP of a Gauss-Newton step and who solves it: the structured solver first, Clarabel
//! (its solver cached across corrections) when that gives up.

use super::*;

/// The QP solver of the last correction, kept for the next: every correction of one robot
/// with one horizon has the same sparsity pattern (only values change), so a later QP only
/// overwrites the values of the first one's solver, which keeps its KKT structure, ordering and
/// symbolic factorisation (Clarabel's data updates), instead of building them again. A planner
/// keeps one per robot; the scaling of the first problem is reused for the later ones.
///
/// Each QP is first solved by its structure (`projection/lq.rs`: an interior-point method whose Newton
/// steps are Riccati recursions over the horizon, about ten times faster than the general
/// sparse solver); Clarabel solves it only when that gives up (no convergence, which is also
/// what an infeasible problem gives: Clarabel then certifies it).
pub struct ProjectionSolver {
    cached: Option<(QpStructure, DefaultSolver<f64>)>,
    structured: Option<lq::LqWorkspace>,
    clarabel_solves: usize,
    clarabel_tolerance: f64,
}

/// Clarabel's gap and feasibility tolerance when it solves a correction (a fallback of the
/// structured solver).
pub const CLARABEL_TOLERANCE: f64 = 1e-6;

impl Default for ProjectionSolver {
    fn default() -> Self {
        Self {
            cached: None,
            structured: Some(lq::LqWorkspace::default()),
            clarabel_solves: 0,
            clarabel_tolerance: CLARABEL_TOLERANCE,
        }
    }
}

impl ProjectionSolver {
    /// A solver that hands every QP to Clarabel with gap and feasibility tolerance
    /// `tolerance` ([`CLARABEL_TOLERANCE`] as a fallback): the reference the structured solver
    /// is tested (at 1e-10) and benchmarked (at the fallback's) against.
    pub fn clarabel_only(tolerance: f64) -> Self {
        Self {
            structured: None,
            clarabel_tolerance: tolerance,
            ..Self::default()
        }
    }

    /// How many QPs went to Clarabel so far (every one for [`Self::clarabel_only`]; for the
    /// default solver, those the structured solver gave up on).
    pub fn clarabel_solves(&self) -> usize {
        self.clarabel_solves
    }
}

impl std::fmt::Debug for ProjectionSolver {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ProjectionSolver")
            .field("structure", &self.cached.as_ref().map(|(k, _)| *k))
            .field("structured", &self.structured.is_some())
            .finish_non_exhaustive()
    }
}

/// One Gauss-Newton step: the change of the twists that minimises the linearised objective
/// subject to the (linear) limits.
///
/// Variables `z = [δξ_1 … δξ_T, e_1 … e_T]`: the change of the twists and the (linearised)
/// change of the poses it causes. The constraint matrix stacks the `3·T` dynamics equalities
/// ([`dynamics_rows`]) over the limit inequalities ([`limit_rows`]).
pub(super) fn solve_step(
    xi: &[f64],
    target: &[Pose2],
    dt: f64,
    limits: &Limits,
    initial_velocity: Twist2,
    gear: f64,
    settings: &ProjectionSettings,
    cache: &mut ProjectionSolver,
) -> Result<Vec<f64>, ProjectionError> {
    let n = 3 * target.len();
    let poses = rollout(xi, dt);
    if let Some(ws) = cache.structured.as_mut() {
        let mut rows = Rows::new(n);
        let rhs = limit_rows(xi, dt, limits, initial_velocity, gear, settings, &mut rows);
        if let Some(x) = solve_structured(xi, &poses, target, dt, settings, &rows, &rhs, ws) {
            return Ok(x);
        }
    }
    cache.clarabel_solves += 1;
    let mut rows = Rows::new(2 * n);
    dynamics_rows(xi, &poses, dt, &mut rows);
    let mut b = vec![0.0; n];
    b.extend(limit_rows(
        xi,
        dt,
        limits,
        initial_velocity,
        gear,
        settings,
        &mut rows,
    ));
    let qp = Qp {
        p: objective_matrix(n, dt, settings),
        q: objective_linear(&poses, target, dt, settings),
        a: rows.into_csc(),
        b,
        equalities: n,
    };
    let key = QpStructure {
        horizon: target.len(),
        curvature: limits.kappa_max.is_some(),
        coupled_rows: coupled_signs(limits).len(),
    };
    let infeasible = |status: String| ProjectionError::Infeasible {
        speed: initial_velocity.vx,
        status,
    };
    solve_cached(cache, key, &qp, infeasible).map(|x| x[..n].to_vec())
}

/// [`solve_step`]'s QP by [`lq::solve`]; `None` when a row does not have the stage structure
/// (it never happens for the rows of [`limit_rows`]) or the solver gives up.
#[allow(clippy::too_many_arguments)]
fn solve_structured(
    xi: &[f64],
    poses: &[Pose2],
    target: &[Pose2],
    dt: f64,
    settings: &ProjectionSettings,
    rows: &Rows,
    rhs: &[f64],
    ws: &mut lq::LqWorkspace,
) -> Option<Vec<f64>> {
    let t = target.len();
    let mut a = Vec::with_capacity(t);
    let mut b = Vec::with_capacity(t);
    let mut prev = Pose2::IDENTITY;
    for (k, w) in xi.chunks_exact(3).enumerate() {
        let (sx, sw) = euler_step_jacobians(prev, Twist2::from_slice(w), dt);
        a.push(sx);
        b.push(sw);
        prev = poses[k];
    }
    let scale = 1.0 / (dt * dt);
    let w = [scale, scale, settings.heading_weight * scale];
    let q: Vec<[f64; 3]> = poses
        .iter()
        .zip(target)
        .map(|(p, g)| {
            [
                w[0] * (p.x - g.x),
                w[1] * (p.y - g.y),
                w[2] * wrap_angle(p.theta - g.theta),
            ]
        })
        .collect();
    let stage_rows = rows.stage_rows(rhs)?;
    let problem = lq::LqProblem {
        a: &a,
        b: &b,
        w,
        q: &q,
        effort: settings.effort,
        rows: &stage_rows,
    };
    lq::solve(&problem, ws).ok()
}

/// What fixes the sparsity of a correction's QP: a cached solver is reused only for the same.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct QpStructure {
    horizon: usize,
    curvature: bool,
    coupled_rows: usize,
}

/// A convex QP `min ½zᵀPz + qᵀz` subject to `A·z + s = b`, `s ∈ {0}^equalities × ℝ₊^rest`.
struct Qp {
    p: CscMatrix<f64>,
    q: Vec<f64>,
    a: CscMatrix<f64>,
    b: Vec<f64>,
    equalities: usize,
}

/// Solves `qp` with the cached solver when the problem's structure `key` (horizon, curvature
/// limit) is the cached one's (only values are overwritten), else with a new solver that is
/// then cached. Returns the solution, all finite.
fn solve_cached<'c>(
    cache: &'c mut ProjectionSolver,
    key: QpStructure,
    qp: &Qp,
    infeasible: impl Fn(String) -> ProjectionError,
) -> Result<&'c [f64], ProjectionError> {
    let updated = match &mut cache.cached {
        Some((k, solver)) if *k == key => solver
            .update_P(&qp.p.nzval)
            .and_then(|()| solver.update_q(&qp.q))
            .and_then(|()| solver.update_A(&qp.a.nzval))
            .and_then(|()| solver.update_b(&qp.b))
            .is_ok(),
        _ => false,
    };
    if !updated {
        let cones = [
            ZeroConeT(qp.equalities),
            NonnegativeConeT(qp.b.len() - qp.equalities),
        ];
        let settings = qp_settings(cache.clarabel_tolerance)?;
        let solver = DefaultSolver::new(&qp.p, &qp.q, &qp.a, &qp.b, &cones, settings)
            .map_err(|e| infeasible(format!("a setup error: {e:?}")))?;
        cache.cached = Some((key, solver));
    }
    let Some((_, solver)) = cache.cached.as_mut() else {
        return Err(infeasible("no solver".into()));
    };
    solver.solve();
    match solver.solution.status {
        SolverStatus::Solved | SolverStatus::AlmostSolved
            if solver.solution.x.iter().all(|x| x.is_finite()) =>
        {
            Ok(&solver.solution.x)
        }
        status => Err(infeasible(format!("{status:?}"))),
    }
}

/// Clarabel's settings for the correction's QPs, with `tolerance` on the gap and feasibility.
fn qp_settings(tolerance: f64) -> Result<clarabel::solver::DefaultSettings<f64>, ProjectionError> {
    DefaultSettingsBuilder::default()
        .verbose(false)
        // Values are overwritten in place for the next correction (see ProjectionSolver):
        // the presolver must not drop rows, nor the input its zeros.
        .presolve_enable(false)
        .input_sparse_dropzeros(false)
        // Refinement's extra solves buy accuracy far below the tolerances below (about
        // −40 % solve time in the `projection` bench).
        .iterative_refinement_enable(false)
        // 1e-6 (default 1e-8; −19 % solve time for the car in the `projection` bench) leaves
        // the plan within about 3 mm of the optimum; 1e-10 within 1e-5 m (the structured
        // solver's agreement test).
        .tol_gap_abs(tolerance)
        .tol_gap_rel(tolerance)
        .tol_feas(tolerance)
        .build()
        .map_err(|e| ProjectionError::InvalidSettings {
            field: "solver",
            message: e.to_string(),
        })
}
