//! The built-in soft-margin terms of Eq. 8 (speed, reverse speed, acceleration, yaw rate,
//! curvature, lateral speed, and the embodiment's coupled limit).
//!
//! Each term is the mean over its quantity's samples of the soft margin
//!
//! `C(q, L) = softplus(γ·(|q|_ε / L − 1 + δ)) / γ`
//!
//! with `γ` the softplus sharpness and `δ` the margin of [`GuidanceWeights`](crate::GuidanceWeights)
//! (the penalty starts to rise at `(1 − δ)·L`, and for `|q| ≫ L` it grows like `|q|/L`). The
//! absolute value is smoothed as `|q|_ε = L·(sqrt((q/L)² + ε²) − ε)` with
//! [`SMOOTH_ABS_EPS`] `ε = 10⁻³`, so it is exactly 0 at `q = 0`, differentiable everywhere and
//! never off by more than `ε·L`.
//!
//! Quantities and samples (finite differences as in [`crate::trajectory`]; `T` poses give
//! `T − 1` segments):
//!
//! | kind | samples | argument of the softplus |
//! |---|---|---|
//! | [`BuiltinKind::Speed`] | `v_i`, `T − 1` | `γ(v/v_max − 1 + δ)`: the forward part only, reversing is judged by the reverse term against its own limit |
//! | [`BuiltinKind::Reverse`] | `v_i`, `T − 1` | `γ(−v/v_reverse_max − 1 + δ)` |
//! | [`BuiltinKind::Acceleration`] | `a_init` and `a_i`, `T − 1` | `γ(|a|_ε/a_max − 1 + δ)` |
//! | [`BuiltinKind::YawRate`] | `ω_i`, `T − 1` | `γ(|ω|_ε/ω_max − 1 + δ)` |
//! | [`BuiltinKind::Curvature`] | `κ_i`, `T − 1` | `γ(|κ|_ε/κ_max − 1 + δ)`; no cost when `κ_max` is `None` |
//! | [`BuiltinKind::Lateral`] | `vy_i`, `T − 1` | `γ(|vy|_ε/lateral_speed_max − 1 + δ)` |
//! | [`BuiltinKind::Coupled`] | `(v_i, vy_i, ω_i)`, `T − 1` | `γ((a·|v|_ε + b·|vy|_ε + c·|ω|_ε)/max − 1 + δ)` with the embodiment's [`CoupledLimit`](crate::limits::CoupledLimit); no cost without one |
//!
//! The acceleration term always includes the initial acceleration from
//! `ctx.initial_velocity.vx`, so a plan that starts at a speed the robot cannot reach in one
//! step is penalised. The limits come from the [`ConstraintContext`] at evaluation time.

use super::{ConstraintContext, ConstraintError, ConstraintTerm, TrajBatch};
use crate::trajectory::{SegmentJet, curvature, segment_jet};
use serde::{Deserialize, Serialize};

/// `ε` of the smoothed absolute value `|r|_ε = sqrt(r² + ε²) − ε` of a limit ratio `r = q/L`.
pub const SMOOTH_ABS_EPS: f64 = 1e-3;

/// Numerically stable `softplus(z) = ln(1 + eᶻ)`.
#[inline]
pub fn softplus(z: f64) -> f64 {
    z.max(0.0) + (-z.abs()).exp().ln_1p()
}

/// The logistic function `σ(z) = 1/(1 + e⁻ᶻ)`, the derivative of [`softplus`].
#[inline]
pub fn sigmoid(z: f64) -> f64 {
    if z >= 0.0 {
        1.0 / (1.0 + (-z).exp())
    } else {
        let e = z.exp();
        e / (1.0 + e)
    }
}

/// The shape of the soft margin of Eq. 8: sharpness `γ` and margin `δ`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct SoftMargin {
    /// Softplus sharpness `γ` (> 0).
    pub gamma: f64,
    /// Tolerance margin `δ`: the penalty starts to rise at `(1 − δ)·limit`.
    pub delta: f64,
}

impl SoftMargin {
    /// `softplus(γ(r − 1 + δ))/γ` of a signed ratio `r` and its derivative with respect to `r`
    /// (one-sided: only large positive `r` is penalised).
    #[inline]
    pub fn upper(&self, r: f64) -> (f64, f64) {
        (
            self.upper_value(r),
            sigmoid(self.gamma * (r - 1.0 + self.delta)),
        )
    }

    /// The value of [`Self::upper`] alone.
    #[inline]
    pub fn upper_value(&self, r: f64) -> f64 {
        softplus(self.upper_argument(r)) / self.gamma
    }

    /// The value of [`Self::abs`] alone.
    #[inline]
    pub fn abs_value(&self, r: f64) -> f64 {
        softplus(self.abs_argument(r)) / self.gamma
    }

    /// The argument `γ(r − 1 + δ)` of the softplus of [`Self::upper_value`].
    #[inline]
    fn upper_argument(&self, r: f64) -> f64 {
        self.gamma * (r - 1.0 + self.delta)
    }

    /// The argument of the softplus of [`Self::abs_value`]: [`Self::upper_argument`] of
    /// `|r|_ε`.
    #[inline]
    fn abs_argument(&self, r: f64) -> f64 {
        let s = (r * r + SMOOTH_ABS_EPS * SMOOTH_ABS_EPS).sqrt();
        self.upper_argument(s - SMOOTH_ABS_EPS)
    }

    /// The two-sided margin of Eq. 8, `softplus(γ(|r|_ε − 1 + δ))/γ`, and its derivative with
    /// respect to `r`.
    #[inline]
    pub fn abs(&self, r: f64) -> (f64, f64) {
        let s = (r * r + SMOOTH_ABS_EPS * SMOOTH_ABS_EPS).sqrt();
        let (p, dp) = self.upper(s - SMOOTH_ABS_EPS);
        (p, dp * r / s)
    }
}

/// Which motion quantity a [`BuiltinTerm`] penalises.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum BuiltinKind {
    /// Forward speed against `v_max`.
    Speed,
    /// Reverse speed against `v_reverse_max`.
    Reverse,
    /// Longitudinal acceleration against `a_max` (including the initial acceleration).
    Acceleration,
    /// Yaw rate against `omega_max`.
    YawRate,
    /// Curvature against `kappa_max` (nothing when the robot has no curvature limit).
    Curvature,
    /// Body-frame lateral speed against `lateral_speed_max`.
    Lateral,
    /// The embodiment's coupled limit `a·|v| + b·|vy| + c·|ω|` against its `max` (nothing when
    /// the robot has none).
    Coupled,
}

impl BuiltinKind {
    /// All kinds, in the order Φ lists them.
    pub const ALL: [BuiltinKind; 7] = [
        BuiltinKind::Speed,
        BuiltinKind::Reverse,
        BuiltinKind::Acceleration,
        BuiltinKind::YawRate,
        BuiltinKind::Curvature,
        BuiltinKind::Lateral,
        BuiltinKind::Coupled,
    ];

    /// The stable name used by [`ConstraintTerm::name`] and in reports.
    pub fn name(self) -> &'static str {
        match self {
            BuiltinKind::Speed => "speed",
            BuiltinKind::Reverse => "reverse",
            BuiltinKind::Acceleration => "acceleration",
            BuiltinKind::YawRate => "yaw_rate",
            BuiltinKind::Curvature => "curvature",
            BuiltinKind::Lateral => "lateral",
            BuiltinKind::Coupled => "coupled",
        }
    }
}

/// One soft-margin term of Eq. 8 on one motion quantity (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BuiltinTerm {
    /// The motion quantity penalised, and so the limit it is measured against.
    pub kind: BuiltinKind,
    /// Sharpness `γ` and margin `δ` of the penalty.
    pub margin: SoftMargin,
}

impl BuiltinTerm {
    /// The unweighted term on `kind` (its weight `λ` is applied by [`super::Phi`]).
    pub const fn new(kind: BuiltinKind, margin: SoftMargin) -> Self {
        Self { kind, margin }
    }

    fn fail(&self, message: String) -> ConstraintError {
        ConstraintError::Failed {
            term: self.kind.name().to_owned(),
            message,
        }
    }

    /// The limit this term uses, `None` when the robot has none (curvature, coupled).
    fn limit(
        &self,
        ctx: &ConstraintContext<'_>,
    ) -> Result<Option<(f64, &'static str)>, ConstraintError> {
        let l = ctx.limits;
        let (value, field) = match self.kind {
            BuiltinKind::Speed => (l.v_max, "v_max"),
            BuiltinKind::Reverse => (l.v_reverse_max, "v_reverse_max"),
            BuiltinKind::Acceleration => (l.a_max, "a_max"),
            BuiltinKind::YawRate => (l.omega_max, "omega_max"),
            BuiltinKind::Curvature => match l.kappa_max {
                Some(k) => (k, "kappa_max"),
                None => return Ok(None),
            },
            BuiltinKind::Lateral => (l.lateral_speed_max, "lateral_speed_max"),
            BuiltinKind::Coupled => match &l.coupled {
                Some(c) => {
                    c.validate().map_err(|(field, message)| {
                        self.fail(format!("coupled limit: {field} = {message}"))
                    })?;
                    (c.max, "coupled.max")
                }
                None => return Ok(None),
            },
        };
        if !(value.is_finite() && value > 0.0) {
            return Err(self.fail(format!(
                "limit {field} = {value} must be finite and positive"
            )));
        }
        Ok(Some((value, field)))
    }

    /// Penalty and its derivative with respect to the quantity `q`, for limit `limit`.
    #[inline]
    fn penalty(&self, q: f64, limit: f64) -> (f64, f64) {
        let inv = 1.0 / limit;
        let (p, dp) = match self.kind {
            // The coupled quantity is a sum of smoothed magnitudes, never negative.
            BuiltinKind::Speed | BuiltinKind::Coupled => self.margin.upper(q * inv),
            BuiltinKind::Reverse => {
                let (p, dp) = self.margin.upper(-q * inv);
                (p, -dp)
            }
            _ => self.margin.abs(q * inv),
        };
        (p, dp * inv)
    }

    /// The argument of the softplus of [`Self::penalty`]'s value: the value is
    /// `softplus(argument)/γ`, the same arithmetic as [`Self::penalty`].
    #[inline]
    fn penalty_argument(&self, q: f64, limit: f64) -> f64 {
        let inv = 1.0 / limit;
        match self.kind {
            BuiltinKind::Speed | BuiltinKind::Coupled => self.margin.upper_argument(q * inv),
            BuiltinKind::Reverse => self.margin.upper_argument(-q * inv),
            _ => self.margin.abs_argument(q * inv),
        }
    }

    /// The quantity of a segment from its values `(v, vy, ω)`, as [`Self::quantity`] computes
    /// it.
    #[inline]
    fn quantity_value(&self, [v, vy, omega]: [f64; 3], ctx: &ConstraintContext<'_>) -> f64 {
        match self.kind {
            BuiltinKind::Coupled => match &ctx.limits.coupled {
                Some(c) => coupled_value([v, vy, omega], c),
                None => 0.0,
            },
            BuiltinKind::Speed | BuiltinKind::Reverse | BuiltinKind::Acceleration => v,
            BuiltinKind::YawRate => omega,
            BuiltinKind::Lateral => vy,
            BuiltinKind::Curvature => curvature(v, omega),
        }
    }

    /// Adds this term's cost of every trajectory into `cost` from the segment values of the
    /// batch ([`Segments`]), without the gradient: the cost [`ConstraintTerm::evaluate`]
    /// gives, to the bit, for a fraction of the work. The segment values are shared by every
    /// built-in term of Φ; the leading segments a trajectory shares with the one before it
    /// ([`Segments::fill`]) are summed once, and a softplus whose argument repeats the last
    /// one to the bit (a robot's lateral speed that is zero up to rounding, a straight path's
    /// yaw rate) is not computed again.
    pub(crate) fn add_costs(
        &self,
        segments: &mut Segments,
        ctx: &ConstraintContext<'_>,
        cost: &mut [f64],
    ) -> Result<(), ConstraintError> {
        let Some((limit, _)) = self.limit(ctx)? else {
            return Ok(());
        };
        let n_seg = segments.per_trajectory;
        if n_seg == 0 {
            return Ok(());
        }
        let (dt, inv_n, gamma) = (ctx.dt, 1.0 / n_seg as f64, self.margin.gamma);
        let Segments {
            values,
            shared,
            running,
            ..
        } = segments;
        // `running[i]`: the sum over segments 0..=i of the trajectory before, which a
        // trajectory sharing those segments continues from (the same additions in the same
        // order, so the same bits).
        running.clear();
        running.resize(n_seg, 0.0);
        let mut last: Option<(u64, f64)> = None;
        let mut value = |z: f64| match last {
            Some((bits, v)) if bits == z.to_bits() => v,
            _ => {
                let v = softplus(z) / gamma;
                last = Some((z.to_bits(), v));
                v
            }
        };
        for ((c, segs), &start) in cost
            .iter_mut()
            .zip(values.chunks_exact(n_seg))
            .zip(shared.iter())
        {
            let mut sum = match start {
                0 => 0.0,
                k => running[k - 1],
            };
            for i in start..n_seg {
                let q = if self.kind == BuiltinKind::Acceleration {
                    let prev = if i == 0 {
                        ctx.initial_velocity.vx
                    } else {
                        segs[i - 1][0]
                    };
                    (segs[i][0] - prev) / dt
                } else {
                    self.quantity_value(segs[i], ctx)
                };
                sum += value(self.penalty_argument(q, limit));
                running[i] = sum;
            }
            *c += sum * inv_n;
        }
        Ok(())
    }

    /// The quantity of a segment and its gradient over the segment's six coordinates.
    #[inline]
    fn quantity(&self, jet: &SegmentJet, ctx: &ConstraintContext<'_>) -> (f64, [f64; 6]) {
        match self.kind {
            BuiltinKind::Coupled => match &ctx.limits.coupled {
                Some(c) => coupled_quantity(jet, c),
                None => (0.0, [0.0; 6]),
            },
            BuiltinKind::Speed | BuiltinKind::Reverse => (jet.v, jet.dv),
            BuiltinKind::YawRate => (jet.omega, jet.domega),
            BuiltinKind::Lateral => (jet.vy, jet.dvy),
            BuiltinKind::Curvature => jet.curvature(),
            // Handled separately: it couples two segments.
            BuiltinKind::Acceleration => (jet.v, jet.dv),
        }
    }

    /// Cost of one trajectory `[T, 3]`, with its gradient added (scaled by `scale`) into `grad`.
    fn accumulate(
        &self,
        traj: &[f64],
        ctx: &ConstraintContext<'_>,
        limit: f64,
        grad: &mut [f64],
    ) -> f64 {
        let t = traj.len() / 3;
        let n_seg = t - 1;
        let dt = ctx.dt;
        let inv_n = 1.0 / n_seg as f64;
        let mut cost = 0.0;
        if self.kind == BuiltinKind::Acceleration {
            // a_init = (v_0 − v_init)/dt, then a_i = (v_{i+1} − v_i)/dt.
            let mut prev = segment_jet(&traj[0..3], &traj[3..6], dt);
            let (p, dp) = self.penalty((prev.v - ctx.initial_velocity.vx) / dt, limit);
            cost += p;
            let g = dp * inv_n / dt;
            for j in 0..6 {
                grad[j] += g * prev.dv[j];
            }
            for i in 1..n_seg {
                let jet = segment_jet(&traj[3 * i..3 * i + 3], &traj[3 * i + 3..3 * i + 6], dt);
                let (p, dp) = self.penalty((jet.v - prev.v) / dt, limit);
                cost += p;
                let g = dp * inv_n / dt;
                let (lo, hi) = grad.split_at_mut(3 * i);
                for j in 0..6 {
                    hi[j] += g * jet.dv[j];
                }
                // The previous segment spans poses i−1 and i: coordinates 3(i−1) … 3i+2.
                let base = 3 * (i - 1);
                for j in 0..3 {
                    lo[base + j] -= g * prev.dv[j];
                    hi[j] -= g * prev.dv[3 + j];
                }
                prev = jet;
            }
        } else {
            for i in 0..n_seg {
                let jet = segment_jet(&traj[3 * i..3 * i + 3], &traj[3 * i + 3..3 * i + 6], dt);
                let (q, dq) = self.quantity(&jet, ctx);
                let (p, dp) = self.penalty(q, limit);
                cost += p;
                let g = dp * inv_n;
                let out = &mut grad[3 * i..3 * i + 6];
                for j in 0..6 {
                    out[j] += g * dq[j];
                }
            }
        }
        cost * inv_n
    }
}

/// `a·|v|_ε + b·|vy|_ε + c·|ω|_ε` of a segment and its gradient, each magnitude smoothed as in
/// [`SoftMargin::abs`] with `ε` relative to the limit's `max` (exactly 0 at rest).
#[inline]
fn coupled_quantity(jet: &SegmentJet, c: &crate::limits::CoupledLimit) -> (f64, [f64; 6]) {
    let eps = SMOOTH_ABS_EPS * c.max;
    let q = coupled_value([jet.v, jet.vy, jet.omega], c);
    let mut dq = [0.0; 6];
    for (coef, x, dx) in [
        (c.v, jet.v, &jet.dv),
        (c.lateral, jet.vy, &jet.dvy),
        (c.omega, jet.omega, &jet.domega),
    ] {
        if coef == 0.0 {
            continue;
        }
        let s = (x * x + eps * eps).sqrt();
        let g = coef * x / s;
        for (d, dxj) in dq.iter_mut().zip(dx) {
            *d += g * dxj;
        }
    }
    (q, dq)
}

/// [`coupled_quantity`] without its gradient (the same arithmetic for the value).
#[inline]
fn coupled_value(x: [f64; 3], c: &crate::limits::CoupledLimit) -> f64 {
    let eps = SMOOTH_ABS_EPS * c.max;
    let mut q = 0.0;
    for (coef, x) in [c.v, c.lateral, c.omega].into_iter().zip(x) {
        if coef == 0.0 {
            continue;
        }
        let s = (x * x + eps * eps).sqrt();
        q += coef * (s - eps);
    }
    q
}

/// The values `(v, vy, ω)` of every segment of a batch of trajectories, computed once (each
/// needs a sine and a cosine) and read by every built-in term.
#[derive(Clone, Debug, Default)]
pub(crate) struct Segments {
    values: Vec<[f64; 3]>,
    per_trajectory: usize,
    /// Per trajectory: how many of its leading segments are those of the trajectory before it,
    /// to the bit (0 for the first). Candidates rolled out from one start often share their
    /// first poses (the robot's motions share their first segment per first target).
    shared: Vec<usize>,
    /// [`BuiltinTerm::add_costs`]' running sums of the trajectory before.
    running: Vec<f64>,
}

impl Segments {
    /// Fills the values of `batch` at time step `dt`, exactly as [`segment_jet`] computes them
    /// (a segment between the same two poses as the one before it is copied).
    pub(crate) fn fill(&mut self, batch: &TrajBatch<'_>, dt: f64) {
        self.values.clear();
        self.shared.clear();
        let n_seg = batch.horizon.saturating_sub(1);
        self.per_trajectory = n_seg;
        for b in 0..batch.batch {
            let traj = batch.trajectory(b);
            // Segment i joins poses i and i + 1: shared while both are.
            let shared = match b {
                0 => 0,
                _ => {
                    let before = batch.trajectory(b - 1);
                    let poses = traj
                        .chunks_exact(3)
                        .zip(before.chunks_exact(3))
                        .take_while(|(p, q)| {
                            p.iter().zip(*q).all(|(x, y)| x.to_bits() == y.to_bits())
                        })
                        .count();
                    poses.saturating_sub(1).min(n_seg)
                }
            };
            self.shared.push(shared);
            let start = self.values.len();
            if shared > 0 {
                self.values
                    .extend_from_within(start - n_seg..start - n_seg + shared);
            }
            self.values.extend((shared..n_seg).map(|i| {
                let jet = segment_jet(&traj[3 * i..3 * i + 3], &traj[3 * i + 3..3 * i + 6], dt);
                [jet.v, jet.vy, jet.omega]
            }));
        }
    }
}

/// Checks the buffers against the batch and the context's time step.
pub(crate) fn check_buffers(
    name: &str,
    batch: &TrajBatch<'_>,
    ctx: &ConstraintContext<'_>,
    cost: &[f64],
    grad: &[f64],
) -> Result<(), ConstraintError> {
    check_cost_buffer(name, batch, cost)?;
    if grad.len() != batch.data.len() {
        return Err(ConstraintError::Shape(format!(
            "`{name}`: gradient buffer holds {} values for {} pose coordinates",
            grad.len(),
            batch.data.len()
        )));
    }
    check_dt(name, ctx)
}

/// The cost buffer must hold one value per trajectory of the batch.
pub(crate) fn check_cost_buffer(
    name: &str,
    batch: &TrajBatch<'_>,
    cost: &[f64],
) -> Result<(), ConstraintError> {
    if cost.len() != batch.batch {
        return Err(ConstraintError::Shape(format!(
            "`{name}`: cost buffer holds {} values for {} trajectories",
            cost.len(),
            batch.batch
        )));
    }
    Ok(())
}

/// The context's time step must be finite and positive.
pub(crate) fn check_dt(name: &str, ctx: &ConstraintContext<'_>) -> Result<(), ConstraintError> {
    if !(ctx.dt.is_finite() && ctx.dt > 0.0) {
        return Err(ConstraintError::Failed {
            term: name.to_owned(),
            message: format!("time step dt = {} s must be finite and positive", ctx.dt),
        });
    }
    Ok(())
}

impl ConstraintTerm for BuiltinTerm {
    fn name(&self) -> &str {
        self.kind.name()
    }

    /// A mean of softplus values, per trajectory (its cost-only path sums the segments
    /// a trajectory shares with the one before once, with the same additions).
    fn separable_nonnegative(&self) -> bool {
        true
    }

    fn evaluate(
        &self,
        batch: TrajBatch<'_>,
        ctx: &ConstraintContext<'_>,
        cost: &mut [f64],
        grad: &mut [f64],
    ) -> Result<(), ConstraintError> {
        check_buffers(self.name(), &batch, ctx, cost, grad)?;
        let Some((limit, _)) = self.limit(ctx)? else {
            return Ok(());
        };
        if batch.horizon < 2 {
            return Ok(());
        }
        let n = batch.horizon * 3;
        for b in 0..batch.batch {
            cost[b] += self.accumulate(
                batch.trajectory(b),
                ctx,
                limit,
                &mut grad[b * n..(b + 1) * n],
            );
        }
        Ok(())
    }

    /// The cost alone, without the gradient: the same values as `evaluate`.
    fn cost(
        &self,
        batch: TrajBatch<'_>,
        ctx: &ConstraintContext<'_>,
        cost: &mut [f64],
    ) -> Result<(), ConstraintError> {
        check_cost_buffer(self.name(), &batch, cost)?;
        check_dt(self.name(), ctx)?;
        let mut segments = Segments::default();
        segments.fill(&batch, ctx.dt);
        self.add_costs(&mut segments, ctx, cost)
    }
}
