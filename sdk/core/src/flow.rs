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
