//! The flow-model interface used by sampling and feasibility guidance.
//!
//! A flow model is a learned velocity field `f(x, t, c)` over trajectories of `T` SE(2) poses:
//! for each waypoint it returns a body-frame velocity in se(2) (paper Eq. 2), and it can pull a
//! cotangent back through itself (a vector-Jacobian product), which is all Algorithm 1 needs.
//! The `flow` crate implements it with libtorch; tests implement it analytically. Poses are in
//! the ego frame of the planning instant, in metres and radians; any normalisation is the
//! model's own business.

use serde::{Deserialize, Serialize};

/// The conditioning `c` of the flow model: the BEV raster, the goal and the ego velocity, all in
/// the ego frame at the planning instant.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FlowCondition {
    /// `[3, H, W]` raster (occupancy, v_x, v_y), row-major; see [`crate::bev`].
    pub bev: Vec<f32>,
    /// Goal `[x, y]` in the ego frame, metres.
    pub goal: [f64; 2],
    /// Ego velocity `[v_x, v_y]` in the ego frame, m/s.
    pub velocity: [f64; 2],
}

/// One group of a batched velocity call ([`FlowModel::velocity_batch`]): trajectories under
/// one condition at one flow time.
#[derive(Clone, Copy, Debug)]
pub struct FlowQuery<'a> {
    /// Poses, flat `[K, T, 3]`.
    pub x: &'a [f64],
    /// Flow time.
    pub t: f64,
    /// The condition of all `K` trajectories.
    pub cond: &'a FlowCondition,
}

/// Why a flow model failed.
#[derive(Debug, thiserror::Error)]
pub enum FlowError {
    /// An input or output buffer of the wrong size; the message gives the sizes.
    #[error("shape mismatch: {0}")]
    Shape(String),
    /// The implementation itself failed (a libtorch error, say); the message is its own.
    #[error("flow model backend error: {0}")]
    Backend(String),
    /// The model returned a NaN or an infinity.
    #[error("flow model produced a non-finite value")]
    NonFinite,
}

/// A learned (or analytic) velocity field over batches of trajectories.
///
/// Arrays are flat `[K, T, 3]` (`K` samples of `T` poses `x, y, θ`; velocities `v_x, v_y, ω`).
/// One condition is shared by the whole batch.
pub trait FlowModel {
    /// Number of poses `T` per trajectory.
    fn horizon(&self) -> usize;

    /// Per-component standard deviation `[σ_x, σ_y, σ_θ]` of the source distribution in the
    /// metric units of this trait: samplers draw `x0 = exp(ξ0)` per waypoint with
    /// `ξ0 ~ N(0, diag(σ²))` (paper: `N(0, I)` in the model's normalised coordinates; a model
    /// that scales translations by `s` internally reports `[s, s, 1]`).
    fn source_std(&self) -> [f64; 3] {
        [1.0, 1.0, 1.0]
    }

    /// Writes `f(x, t, c)` into `out` (same shape as `x`).
    fn velocity(
        &self,
        x: &[f64],
        t: f64,
        cond: &FlowCondition,
        out: &mut [f64],
    ) -> Result<(), FlowError>;

    /// Writes `f(x, t, c)` into `out` and the vector-Jacobian product
    /// `cotangentᵀ · ∂f/∂x` into `vjp` (both the shape of `x`).
    fn velocity_vjp(
        &self,
        x: &[f64],
        t: f64,
        cond: &FlowCondition,
        cotangent: &[f64],
        out: &mut [f64],
        vjp: &mut [f64],
    ) -> Result<(), FlowError>;

    /// The velocities of several groups of trajectories, each under its own condition and
    /// flow time, written one group after another into `out` (as long as all the groups'
    /// poses together). The same values as one [`Self::velocity`] per group, which is what
    /// this default does; a model may run the groups as one batch instead (the native network:
    /// one matrix product per layer for all of them). [`crate::human2nav::Human2Nav::plan_batch`]
    /// batches several planners' sampling through it.
    fn velocity_batch(&self, queries: &[FlowQuery<'_>], out: &mut [f64]) -> Result<(), FlowError> {
        velocity_each(self, queries, out)
    }

    /// Which network answers this model's calls: handles with the same `Some` value run the
    /// same weights, so that one of them can answer the others' queries in
    /// [`Self::velocity_batch`]. `None` (the default): unknown, nothing is batched across
    /// handles.
    fn network_id(&self) -> Option<usize> {
        None
    }
}

/// [`FlowModel::velocity_batch`] as one [`FlowModel::velocity`] per group (the trait's
/// default, for models that batch only sometimes).
pub fn velocity_each<M: FlowModel + ?Sized>(
    model: &M,
    queries: &[FlowQuery<'_>],
    out: &mut [f64],
) -> Result<(), FlowError> {
    let total: usize = queries.iter().map(|q| q.x.len()).sum();
    if out.len() != total {
        return Err(FlowError::Shape(format!(
            "batched velocity: {} output values for {total} input values",
            out.len()
        )));
    }
    let mut rest = out;
    for q in queries {
        let (o, r) = rest.split_at_mut(q.x.len());
        model.velocity(q.x, q.t, q.cond, o)?;
        rest = r;
    }
    Ok(())
}

/// `k` source samples of `t` poses each, flat `[k, t, 3]`: per waypoint `x0 = exp(ξ0)` with
/// `ξ0 ~ N(0, diag(std²))` ([`FlowModel::source_std`]), drawn from `rng` in waypoint order.
pub fn draw_source<R: rand::Rng + ?Sized>(
    std: [f64; 3],
    k: usize,
    t: usize,
    rng: &mut R,
) -> Vec<f64> {
    use rand_distr::{Distribution, StandardNormal};
    let mut x0 = vec![0.0; k * t * 3];
    for p in x0.chunks_exact_mut(3) {
        let mut xi = [0.0; 3];
        for (d, s) in xi.iter_mut().zip(std) {
            let z: f64 = StandardNormal.sample(rng);
            *d = z * s;
        }
        p.copy_from_slice(
            &crate::se2::Pose2::exp(crate::se2::Twist2::new(xi[0], xi[1], xi[2])).to_array(),
        );
    }
    x0
}

/// Classifier-free guidance on the crowd: `f_w(x, t, c) = f(x, t, c∅) + w·(f(x, t, c) − f(x, t, c∅))`
/// with `c∅` the same condition with an empty BEV raster (nobody around). `w = 1` is the model
/// itself; `w > 1` amplifies whatever the crowd in the raster changes in the field (Ho &
/// Salimans' guidance, with "no crowd" as the unconditional input, which every model has seen
/// in training wherever a walker was alone). It costs two network calls per call.
#[derive(Clone, Debug)]
pub struct CrowdGuidance<M> {
    /// The flow model.
    pub model: M,
    /// The guidance weight `w` (finite, ≥ 0).
    pub weight: f64,
}

impl<M> CrowdGuidance<M> {
    /// `model` with crowd guidance of weight `weight`; a weight that is negative or not finite
    /// is an error.
    pub fn new(model: M, weight: f64) -> Result<Self, FlowError> {
        if !(weight.is_finite() && weight >= 0.0) {
            return Err(FlowError::Shape(format!(
                "crowd guidance weight {weight} must be finite and ≥ 0"
            )));
        }
        Ok(Self { model, weight })
    }

    /// `cond` with its raster emptied.
    pub(crate) fn empty(cond: &FlowCondition) -> FlowCondition {
        FlowCondition {
            bev: vec![0.0; cond.bev.len()],
            ..cond.clone()
        }
    }

    /// `out ← out∅ + w·(out − out∅)`.
    pub(crate) fn combine(&self, out: &mut [f64], unconditional: &[f64]) {
        for (o, u) in out.iter_mut().zip(unconditional) {
            *o = u + self.weight * (*o - u);
        }
    }
}

impl<M: FlowModel> FlowModel for CrowdGuidance<M> {
    fn horizon(&self) -> usize {
        self.model.horizon()
    }

    fn source_std(&self) -> [f64; 3] {
        self.model.source_std()
    }

    fn velocity(
        &self,
        x: &[f64],
        t: f64,
        cond: &FlowCondition,
        out: &mut [f64],
    ) -> Result<(), FlowError> {
        self.model.velocity(x, t, cond, out)?;
        if self.weight != 1.0 {
            let mut unconditional = vec![0.0; out.len()];
            self.model
                .velocity(x, t, &Self::empty(cond), &mut unconditional)?;
            self.combine(out, &unconditional);
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
        self.model.velocity_vjp(x, t, cond, cotangent, out, vjp)?;
        if self.weight != 1.0 {
            let (mut unconditional, mut vjp_unconditional) =
                (vec![0.0; out.len()], vec![0.0; vjp.len()]);
            self.model.velocity_vjp(
                x,
                t,
                &Self::empty(cond),
                cotangent,
                &mut unconditional,
                &mut vjp_unconditional,
            )?;
            self.combine(out, &unconditional);
            self.combine(vjp, &vjp_unconditional);
        }
        Ok(())
    }
}

/// A reference to a flow model is one: adapters such as [`CrowdGuidance`] can borrow the
/// model they wrap.
impl<M: FlowModel + ?Sized> FlowModel for &M {
    fn horizon(&self) -> usize {
        (**self).horizon()
    }

    fn source_std(&self) -> [f64; 3] {
        (**self).source_std()
    }

    fn velocity(
        &self,
        x: &[f64],
        t: f64,
        cond: &FlowCondition,
        out: &mut [f64],
    ) -> Result<(), FlowError> {
        (**self).velocity(x, t, cond, out)
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
        (**self).velocity_vjp(x, t, cond, cotangent, out, vjp)
    }

    fn velocity_batch(&self, queries: &[FlowQuery<'_>], out: &mut [f64]) -> Result<(), FlowError> {
        (**self).velocity_batch(queries, out)
    }

    fn network_id(&self) -> Option<usize> {
        (**self).network_id()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `f = (1 + s)·x` with `s` the raster's first value: a field the crowd changes.
    struct Scaled;

    impl FlowModel for Scaled {
        fn horizon(&self) -> usize {
            1
        }
        fn velocity(
            &self,
            x: &[f64],
            _t: f64,
            c: &FlowCondition,
            out: &mut [f64],
        ) -> Result<(), FlowError> {
            let s = 1.0 + f64::from(c.bev[0]);
            for (o, v) in out.iter_mut().zip(x) {
                *o = s * v;
            }
            Ok(())
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
            self.velocity(x, t, c, out)?;
            let s = 1.0 + f64::from(c.bev[0]);
            for (g, w) in vjp.iter_mut().zip(cotangent) {
                *g = s * w;
            }
            Ok(())
        }
    }

    #[test]
    fn crowd_guidance_extrapolates_from_the_empty_raster() {
        let cond = FlowCondition {
            bev: vec![0.5],
            goal: [0.0, 0.0],
            velocity: [0.0, 0.0],
        };
        let x = [1.0, 2.0, 3.0];
        let run = |w: f64| {
            let g = CrowdGuidance::new(Scaled, w).unwrap();
            let (mut out, mut vjp) = ([0.0; 3], [0.0; 3]);
            g.velocity_vjp(&x, 0.5, &cond, &[1.0, 1.0, 1.0], &mut out, &mut vjp)
                .unwrap();
            let mut plain = [0.0; 3];
            g.velocity(&x, 0.5, &cond, &mut plain).unwrap();
            assert_eq!(plain, out);
            (out, vjp)
        };
        // Empty raster: f = x; observed: 1.5·x; w = 3: x + 3·0.5·x = 2.5·x.
        assert_eq!(run(1.0), ([1.5, 3.0, 4.5], [1.5; 3]));
        assert_eq!(run(0.0), ([1.0, 2.0, 3.0], [1.0; 3]));
        assert_eq!(run(3.0), ([2.5, 5.0, 7.5], [2.5; 3]));
        assert!(CrowdGuidance::new(Scaled, -1.0).is_err());
        assert!(CrowdGuidance::new(Scaled, f64::NAN).is_err());
    }
}
