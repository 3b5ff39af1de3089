//! Analytic flow models with exact vector-Jacobian products, and a deterministic demo batch.
//!
//! They make sampling and guidance testable and benchmarkable without libtorch, and let other
//! crates (planner tests, benches) run the full pipeline on a known field:
//!
//! * [`LinearField`]: `f(x) = A·x + b` per waypoint, the simplest field with a non-zero
//!   Jacobian;
//! * [`ConstantField`]: `f_k = ξ_k`, independent of `x` and `t`; the rollout ends exactly at
//!   `x0_k·exp(ξ_k)` (a "neutral" field: every step's control reaches the end unchanged);
//! * [`GeodesicTarget`]: `f_k(x, t) = log(x_k⁻¹·x*_k) / (1 − t)`, the conditional flow-matching
//!   field towards a fixed target trajectory `x*` (Eq. 3-4); from any start the `N`-step Euler
//!   rollout on SE(2) follows the geodesic and lands exactly on `x*`. It contracts strongly
//!   near `t = 1`, as trained fields do.

use crate::flow::{FlowCondition, FlowError, FlowModel};
use crate::se2::{
    Jacobian3, Pose2, Twist2, compose_jacobians, inverse_jacobian, log_jacobian, transpose_apply,
};

/// The smallest `1 − t` used by [`GeodesicTarget`] (keeps the field finite at `t = 1`).
pub const MIN_REMAINING_TIME: f64 = 1e-3;

fn check(x: &[f64], horizon: usize, others: &[usize]) -> Result<(), FlowError> {
    if horizon == 0 || x.len() % (3 * horizon) != 0 {
        return Err(FlowError::Shape(format!(
            "{} values are not whole trajectories of {horizon} poses",
            x.len()
        )));
    }
    if let Some(bad) = others.iter().find(|&&n| n != x.len()) {
        return Err(FlowError::Shape(format!(
            "buffer of {bad} values for {} inputs",
            x.len()
        )));
    }
    Ok(())
}

/// `f(x) = A·x + b` applied to every waypoint's `(x, y, θ)`, read as a body twist.
#[derive(Clone, Debug, PartialEq)]
pub struct LinearField {
    /// Number of poses `T` per trajectory the field accepts.
    pub horizon: usize,
    /// Row-major `A`: `f_r = Σ_c a[r][c]·x_c + b_r`.
    pub a: Jacobian3,
    /// Offset `b`, the twist `[v_x, v_y, ω]` at `x = 0` (m/s, rad/s).
    pub b: [f64; 3],
}

impl FlowModel for LinearField {
    fn horizon(&self) -> usize {
        self.horizon
    }

    fn velocity(
        &self,
        x: &[f64],
        _t: f64,
        _c: &FlowCondition,
        out: &mut [f64],
    ) -> Result<(), FlowError> {
        check(x, self.horizon, &[out.len()])?;
        for (p, o) in x.chunks_exact(3).zip(out.chunks_exact_mut(3)) {
            for r in 0..3 {
                o[r] = self.a[r][0] * p[0] + self.a[r][1] * p[1] + self.a[r][2] * p[2] + self.b[r];
            }
        }
        Ok(())
    }

    fn velocity_vjp(
        &self,
        x: &[f64],
        t: f64,
        cond: &FlowCondition,
        cotangent: &[f64],
        out: &mut [f64],
        vjp: &mut [f64],
    ) -> Result<(), FlowError> {
        check(x, self.horizon, &[cotangent.len(), vjp.len()])?;
        self.velocity(x, t, cond, out)?;
        for (g, v) in cotangent.chunks_exact(3).zip(vjp.chunks_exact_mut(3)) {
            v.copy_from_slice(&transpose_apply(&self.a, [g[0], g[1], g[2]]));
        }
        Ok(())
    }
}

/// `f_k = ξ_k`: a fixed body twist per waypoint, `[T, 3]`, shared by every sample.
#[derive(Clone, Debug, PartialEq)]
pub struct ConstantField {
    /// The body twists `ξ_k`, flat `[T, 3]` (`v_x, v_y` in m/s, `ω` in rad/s); the length
    /// sets the horizon `T` and should be a multiple of 3.
    pub twists: Vec<f64>,
}

impl FlowModel for ConstantField {
    fn horizon(&self) -> usize {
        self.twists.len() / 3
    }

    fn velocity(
        &self,
        x: &[f64],
        _t: f64,
        _c: &FlowCondition,
        out: &mut [f64],
    ) -> Result<(), FlowError> {
        check(x, self.horizon(), &[out.len()])?;
        for o in out.chunks_exact_mut(self.twists.len()) {
            o.copy_from_slice(&self.twists);
        }
        Ok(())
    }

    fn velocity_vjp(
        &self,
        x: &[f64],
        t: f64,
        cond: &FlowCondition,
        cotangent: &[f64],
        out: &mut [f64],
        vjp: &mut [f64],
    ) -> Result<(), FlowError> {
        check(x, self.horizon(), &[cotangent.len(), vjp.len()])?;
        self.velocity(x, t, cond, out)?;
        vjp.fill(0.0);
        Ok(())
    }
}

/// Samples that land on one fixed path, waypoint `k` at `path_k` (ego frame), from source noise
/// of `source_std` (small: every sample is the same walk): a [`ConstantField`] of
/// `log(path_k)` started from (almost) the identity. What a test of the selection needs from a
/// flow model: a person's way, and nothing that reacts to the scene.
#[derive(Clone, Debug, PartialEq)]
pub struct FixedWalk {
    field: ConstantField,
    source_std: f64,
}

impl FixedWalk {
    /// Along `path`, one waypoint per pose (source noise 1e-4).
    pub fn along(path: impl IntoIterator<Item = crate::Pose2>) -> Self {
        let twists = path.into_iter().flat_map(|p| p.log().to_array()).collect();
        Self {
            field: ConstantField { twists },
            source_std: 1e-4,
        }
    }

    /// Straight ahead, `step` metres a waypoint, for `horizon` waypoints (source noise 1e-4).
    pub fn straight(step: f64, horizon: usize) -> Self {
        Self::along((1..=horizon).map(|k| crate::Pose2::new(step * k as f64, 0.0, 0.0)))
    }
}

impl FlowModel for FixedWalk {
    fn horizon(&self) -> usize {
        self.field.horizon()
    }

    fn source_std(&self) -> [f64; 3] {
        [self.source_std; 3]
    }

    fn velocity(
        &self,
        x: &[f64],
        t: f64,
        c: &FlowCondition,
        out: &mut [f64],
    ) -> Result<(), FlowError> {
        self.field.velocity(x, t, c, out)
    }

    fn velocity_vjp(
        &self,
        x: &[f64],
        t: f64,
        c: &FlowCondition,
        cotangent: &[f64],
        out: &mut [f64],
        vjp: &mut [f64],
    ) -> Result<(), FlowError> {
        self.field.velocity_vjp(x, t, c, cotangent, out, vjp)
    }
}

/// The flow-matching field towards a fixed target trajectory `x*` (`[T, 3]` poses, shared by
/// every sample): `f_k(x, t) = log(x_k⁻¹·x*_k) / max(1 − t, MIN_REMAINING_TIME)`.
#[derive(Clone, Debug, PartialEq)]
pub struct GeodesicTarget {
    /// The target poses `x*`, flat `[T, 3]` (`x, y` in m, `θ` in rad) in the samples' frame;
    /// the length sets the horizon `T` and should be a multiple of 3.
    pub target: Vec<f64>,
}

impl GeodesicTarget {
    fn scale(t: f64) -> f64 {
        1.0 / (1.0 - t).max(MIN_REMAINING_TIME)
    }
}

impl FlowModel for GeodesicTarget {
    fn horizon(&self) -> usize {
        self.target.len() / 3
    }

    fn velocity(
        &self,
        x: &[f64],
        t: f64,
        _c: &FlowCondition,
        out: &mut [f64],
    ) -> Result<(), FlowError> {
        check(x, self.horizon(), &[out.len()])?;
        let s = Self::scale(t);
        let n = self.target.len();
        for (xs, os) in x.chunks_exact(n).zip(out.chunks_exact_mut(n)) {
            for ((p, o), g) in xs
                .chunks_exact(3)
                .zip(os.chunks_exact_mut(3))
                .zip(self.target.chunks_exact(3))
            {
                let xi = Pose2::from_slice(p)
                    .between(Pose2::from_slice(g))
                    .log()
                    .scale(s);
                o.copy_from_slice(&xi.to_array());
            }
        }
        Ok(())
    }

    fn velocity_vjp(
        &self,
        x: &[f64],
        t: f64,
        cond: &FlowCondition,
        cotangent: &[f64],
        out: &mut [f64],
        vjp: &mut [f64],
    ) -> Result<(), FlowError> {
        check(x, self.horizon(), &[cotangent.len(), vjp.len()])?;
        self.velocity(x, t, cond, out)?;
        let s = Self::scale(t);
        let n = self.target.len();
        for ((xs, cs), vs) in x
            .chunks_exact(n)
            .zip(cotangent.chunks_exact(n))
            .zip(vjp.chunks_exact_mut(n))
        {
            for (((p, c), v), g) in xs
                .chunks_exact(3)
                .zip(cs.chunks_exact(3))
                .zip(vs.chunks_exact_mut(3))
                .zip(self.target.chunks_exact(3))
            {
                // f = s·log(inv(x) ∘ x*): chain log ← compose (first argument) ← inverse.
                let x = Pose2::from_slice(p);
                let inv = x.inverse();
                let rel = inv.compose(Pose2::from_slice(g));
                let (j_first, _) = compose_jacobians(inv, Pose2::from_slice(g));
                let mut back = transpose_apply(&log_jacobian(rel), [s * c[0], s * c[1], s * c[2]]);
                back = transpose_apply(&j_first, back);
                back = transpose_apply(&inverse_jacobian(x), back);
                v.copy_from_slice(&back);
            }
        }
        Ok(())
    }
}

/// A deterministic batch of `batch` varied trajectories of `horizon` poses at step `dt`, flat
/// `[B, T, 3]`, starting at the identity: forward speeds from 0.2 to 2.2 m/s, a little reversing,
/// lateral drift up to ±0.2 m/s and yaw rates up to ±1.25 rad/s, varying along the horizon. It
/// violates the limits of a typical wheeled robot in every way, which is what tests and benches
/// of the constraint terms want.
pub fn demo_batch(batch: usize, horizon: usize, dt: f64) -> Vec<f64> {
    // Low-discrepancy fractions from the golden ratio and √2 give a spread without a RNG.
    let frac = |a: f64| a - a.floor();
    let mut out = Vec::with_capacity(batch * horizon * 3);
    for b in 0..batch {
        let bf = b as f64;
        let h1 = frac(0.5 + bf * 0.618_033_988_749_895);
        let h2 = frac(0.25 + bf * 0.414_213_562_373_095);
        let h3 = frac(0.75 + bf * 0.324_717_957_244_746);
        let v = if b % 7 == 3 {
            -0.3 - 0.5 * h1
        } else {
            0.2 + 2.0 * h1
        };
        let vy = 0.4 * (h2 - 0.5);
        let w = 2.5 * (h3 - 0.5);
        let mut pose = Pose2::IDENTITY;
        for k in 0..horizon {
            out.extend_from_slice(&pose.to_array());
            let kf = k as f64;
            let twist = Twist2::new(
                v * (1.0 + 0.3 * (0.2 * kf + bf).sin()),
                vy,
                w * (0.15 * kf + 0.5 * bf).cos(),
            );
            pose = pose.euler_step(twist, dt);
        }
    }
    out
}
