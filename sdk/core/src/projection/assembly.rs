//! The pieces of a Gauss-Newton step's QP: the linearised rollout and the limits as rows of a
//! sparse matrix (with the acceleration bounds), and the objective.

use super::*;

/// Column of the pose-change variable `e_k` (component `r`) among `3·T` twist changes.
fn e_col(n: usize, k: usize, r: usize) -> usize {
    n + 3 * k + r
}

/// The linearised rollout as equalities: `e_k − S_w·δξ_k − S_x·e_{k−1} = 0`, `e_0 = 0`, with
/// the step Jacobians at the current twists. Keeping the poses as variables makes every matrix
/// sparse and banded.
pub(super) fn dynamics_rows(xi: &[f64], poses: &[Pose2], dt: f64, rows: &mut Rows) {
    let n = xi.len();
    let mut prev = Pose2::IDENTITY;
    for (k, w) in xi.chunks_exact(3).enumerate() {
        let (sx, sw) = euler_step_jacobians(prev, Twist2::from_slice(w), dt);
        for r in 0..3 {
            let mut row = vec![(e_col(n, k, r), 1.0)];
            for c in 0..3 {
                row.push((3 * k + c, -sw[r][c]));
                if k > 0 {
                    row.push((e_col(n, k - 1, c), -sx[r][c]));
                }
            }
            rows.push(&row);
        }
        prev = poses[k];
    }
}

/// `P` of the objective `½zᵀPz + qᵀz` (diagonal), scaled by `1/dt²` so that its entries are of
/// order one: the effort `ρ` on every variable, the pose weights on the pose changes.
pub(super) fn objective_matrix(n: usize, dt: f64, settings: &ProjectionSettings) -> CscMatrix<f64> {
    let w = [1.0, 1.0, settings.heading_weight];
    let scale = 1.0 / (dt * dt);
    let mut diag = vec![settings.effort; 2 * n];
    for (i, d) in diag[n..].iter_mut().enumerate() {
        *d = w[i % 3] * scale;
    }
    CscMatrix::new(
        2 * n,
        2 * n,
        (0..=2 * n).collect(),
        (0..2 * n).collect(),
        diag,
    )
}

/// `q` of the objective: the pose weights times the current distance to the target.
pub(super) fn objective_linear(
    poses: &[Pose2],
    target: &[Pose2],
    dt: f64,
    settings: &ProjectionSettings,
) -> Vec<f64> {
    let n = 3 * target.len();
    let w = [1.0, 1.0, settings.heading_weight];
    let scale = 1.0 / (dt * dt);
    let mut q = vec![0.0; 2 * n];
    for (k, (p, g)) in poses.iter().zip(target).enumerate() {
        let r = [p.x - g.x, p.y - g.y, wrap_angle(p.theta - g.theta)];
        for d in 0..3 {
            q[e_col(n, k, d)] = w[d] * r[d] * scale;
        }
    }
    q
}

/// The limits as rows `A·δ ≤ b − A·ξ` (constraints `A·(ξ + δ) ≤ b` on the new twists) appended
/// to `rows`; returns their right-hand sides.
pub(super) fn limit_rows(
    xi: &[f64],
    dt: f64,
    limits: &Limits,
    initial_velocity: Twist2,
    gear: f64,
    settings: &ProjectionSettings,
    rows: &mut Rows,
) -> Vec<f64> {
    let AccelerationBounds {
        c_min,
        da,
        da_first,
        braking,
    } = AccelerationBounds::new(dt, limits, initial_velocity, gear, settings);
    let s = 1.0 - settings.margin;
    let mut rhs = Vec::new();
    let mut push = |row: &[(usize, f64)], bound: f64| {
        let ax: f64 = row.iter().map(|(c, a)| a * xi[*c]).sum();
        rows.push(row);
        rhs.push(bound - ax);
    };
    let speed_limit = |dir: f64| {
        if dir > 0.0 {
            limits.v_max
        } else {
            limits.v_reverse_max
        }
    };
    for k in 0..xi.len() / 3 {
        let (iv, ivy, iw) = (3 * k, 3 * k + 1, 3 * k + 2);
        let dir = if k + 1 < braking { -gear } else { gear };
        push(&[(iv, dir)], s * speed_limit(dir));
        push(&[(iv, -dir)], 0.0);
        push(&[(ivy, 1.0)], s * limits.lateral_speed_max);
        push(&[(ivy, -1.0)], s * limits.lateral_speed_max);
        push(&[(iw, 1.0)], s * limits.omega_max);
        push(&[(iw, -1.0)], s * limits.omega_max);
        if let Some(kappa) = limits.kappa_max {
            let kv = s * kappa * c_min * dir;
            push(&[(iw, 1.0), (iv, -kv)], 0.0);
            push(&[(iw, -1.0), (iv, -kv)], 0.0);
        }
        if let Some(c) = &limits.coupled {
            for [sy, sw] in coupled_signs(limits) {
                let row: Vec<(usize, f64)> =
                    [(iv, c.v * dir), (ivy, sy * c.lateral), (iw, sw * c.omega)]
                        .into_iter()
                        .filter(|(_, a)| *a != 0.0)
                        .collect();
                push(&row, s * c.max);
            }
        }
        if k == 0 {
            push(&[(iv, 1.0)], da_first + initial_velocity.vx);
            push(&[(iv, -1.0)], da_first - initial_velocity.vx);
        } else {
            let pv = 3 * (k - 1);
            push(&[(iv, 1.0), (pv, -1.0)], da);
            push(&[(iv, -1.0), (pv, 1.0)], da);
        }
    }
    rhs
}

/// The signs `(of vy, of ω)` of the coupled limit's rows per segment: both signs of each
/// magnitude whose coefficient is not 0 (1, 2 or 4 rows; none without a coupled limit).
pub(super) fn coupled_signs(limits: &Limits) -> Vec<[f64; 2]> {
    let Some(c) = &limits.coupled else {
        return Vec::new();
    };
    let signs = |coef: f64| {
        if coef == 0.0 {
            vec![1.0]
        } else {
            vec![1.0, -1.0]
        }
    };
    signs(c.lateral)
        .into_iter()
        .flat_map(|sy| signs(c.omega).into_iter().map(move |sw| [sy, sw]))
        .collect()
}

/// The speed-change bounds of [`limit_rows`] and the segments that brake first.
struct AccelerationBounds {
    /// The smallest chord factor: `c_k` lies in `[c_min, 1]` once `|ω_k| ≤ ω_max`; the bounds
    /// hold for every `c_k` in that range, so they need no linearisation.
    c_min: f64,
    /// Largest change of speed between consecutive segments.
    da: f64,
    /// From the current speed to the first segment's mean speed: half a step of ramp.
    da_first: f64,
    /// A robot moving against the plan's gear brakes first: the segments before the one that
    /// can reach zero speed keep the robot's direction, the later ones the plan's gear.
    braking: usize,
}

impl AccelerationBounds {
    fn new(
        dt: f64,
        limits: &Limits,
        initial_velocity: Twist2,
        gear: f64,
        settings: &ProjectionSettings,
    ) -> Self {
        let c_min = sinc(0.5 * limits.omega_max * dt);
        let s_a = 1.0 - settings.acceleration_margin;
        let da = (s_a * limits.a_max * dt - (1.0 - c_min) * limits.v_max.max(limits.v_reverse_max))
            .max(0.0);
        let da_first = 0.5 * s_a * limits.a_max * dt;
        let braking = if gear * initial_velocity.vx < 0.0 && da > 0.0 {
            1 + ((initial_velocity.vx.abs() - da_first) / da)
                .ceil()
                .max(0.0) as usize
        } else {
            0
        };
        Self {
            c_min,
            da,
            da_first,
            braking,
        }
    }
}

/// A sparse matrix built row by row as `(row, column, value)` triplets, compressed by
/// Clarabel's [`CscMatrix::new_from_triplets`] (which sorts by column, then row, and keeps
/// explicit zeros: every correction of one structure has the same pattern, which the cached
/// solver's in-place updates rely on).
pub(super) struct Rows {
    cols: usize,
    pub(super) count: usize,
    pub(super) i: Vec<usize>,
    pub(super) j: Vec<usize>,
    pub(super) v: Vec<f64>,
}

impl Rows {
    pub(super) fn new(cols: usize) -> Self {
        Self {
            cols,
            count: 0,
            i: Vec::new(),
            j: Vec::new(),
            v: Vec::new(),
        }
    }

    /// Appends a row given by its `(column, value)` entries, each column at most once.
    fn push(&mut self, row: &[(usize, f64)]) {
        for &(c, v) in row {
            self.i.push(self.count);
            self.j.push(c);
            self.v.push(v);
        }
        self.count += 1;
    }

    /// The rows as [`lq::StageRow`]s with right-hand sides `rhs`: each row's columns must be
    /// twist components of one segment `k` and, at most, the speed of segment `k − 1` (`None`
    /// otherwise). Rows come out in the order pushed.
    pub(super) fn stage_rows(&self, rhs: &[f64]) -> Option<Vec<lq::StageRow>> {
        let mut out: Vec<lq::StageRow> = (0..self.count)
            .map(|_| lq::StageRow {
                stage: usize::MAX,
                u: [0.0; 3],
                p: 0.0,
                b: 0.0,
            })
            .collect();
        // The stage of a row is that of its last twist column; a row touching segment k − 1's
        // speed also touches segment k.
        for (&r, &c) in self.i.iter().zip(&self.j) {
            let s = &mut out[r].stage;
            *s = if *s == usize::MAX {
                c / 3
            } else {
                (*s).max(c / 3)
            };
        }
        for ((&r, &c), &v) in self.i.iter().zip(&self.j).zip(&self.v) {
            let row = &mut out[r];
            if c / 3 == row.stage {
                row.u[c % 3] += v;
            } else if row.stage > 0 && c == 3 * (row.stage - 1) {
                row.p += v;
            } else {
                return None;
            }
        }
        for (row, &b) in out.iter_mut().zip(rhs) {
            if row.stage == usize::MAX {
                return None;
            }
            row.b = b;
        }
        out.windows(2)
            .all(|w| w[0].stage <= w[1].stage)
            .then_some(out)
    }

    pub(super) fn into_csc(self) -> CscMatrix<f64> {
        CscMatrix::new_from_triplets(self.count, self.cols, self.i, self.j, self.v)
    }
}
