//! The conditional flow-matching objective on SE(2) (paper Eq. 3–4), in plain `f64`.
//!
//! Per waypoint, a source pose `x0 = exp(ξ0)` and a data pose `x1` are joined by the geodesic
//! `x_t = x0·exp(t·ξ)` with `ξ = log(x0⁻¹x1)` (Eq. 4). Its body velocity `x_t⁻¹·ẋ_t` is the
//! constant `ξ`, which is the regression target. The paper prints the target as
//! `u_t = log(x_t⁻¹x1)`; since `x_t⁻¹x1 = exp((1 − t)·ξ)`, that expression equals
//! `(1 − t)·ξ`, and only after dividing by `(1 − t)` is it the velocity of Eq. 4 that the
//! Euler integrator of Eq. 5 expects. We compute `ξ` directly (no division, stable as
//! `t → 1`); the tests check it against `log(x_t⁻¹x1)/(1 − t)` and against a finite
//! difference of the interpolation.
//!
//! Flow time during training is drawn from a shifted Beta distribution following π0:
//! `t = s·(1 − u)` with `u ~ Beta(α, β)`, defaults `α = 1.5`, `β = 1`, `s = 0.999`, which
//! puts more weight on small `t` (close to the source, where the velocity field is hardest)
//! and never samples `t = 1`. Inference uses the uniform grid `t_i = i/N`.

use human2nav_core::se2::{Pose2, Twist2};
use rand::Rng;
use rand_distr::{Beta, Distribution, StandardNormal};
use serde::{Deserialize, Serialize};

use crate::error::CfmError;

/// The constant body velocity `ξ = log(x0⁻¹x1)` of the geodesic from `x0` to `x1`.
pub fn target_velocity(x0: Pose2, x1: Pose2) -> Twist2 {
    x0.between(x1).log()
}

/// The geodesic interpolant `x_t = x0·exp(t·ξ)` of Eq. 4 for a precomputed `ξ`.
pub fn geodesic_point(x0: Pose2, xi: Twist2, t: f64) -> Pose2 {
    x0.compose(Pose2::exp(xi.scale(t)))
}

/// The paper's printed target `log(x_t⁻¹x1)` divided by `(1 − t)`: the velocity of Eq. 4
/// written in terms of the current point. Equal to [`target_velocity`] for `t < 1`.
pub fn target_velocity_from(xt: Pose2, x1: Pose2, t: f64) -> Twist2 {
    xt.between(x1).log().scale(1.0 / (1.0 - t))
}

/// Draws `k` source trajectories of `horizon` poses, flat `[k, horizon, 3]`: every pose is
/// `exp(ξ0)` with `ξ0 ~ N(0, diag(std²))` independently per waypoint.
///
/// `std` is the model's [`human2nav_core::FlowModel::source_std`] (metric units) — `[1, 1, 1]`
/// for a model working in normalised units.
pub fn sample_source<R: Rng + ?Sized>(
    k: usize,
    horizon: usize,
    std: [f64; 3],
    rng: &mut R,
) -> Vec<f64> {
    let mut out = Vec::with_capacity(k * horizon * 3);
    for _ in 0..k * horizon {
        out.extend_from_slice(&Pose2::exp(normal_twist(std, rng)).to_array());
    }
    out
}

/// One draw of `ξ0 ~ N(0, diag(std²))`.
pub fn normal_twist<R: Rng + ?Sized>(std: [f64; 3], rng: &mut R) -> Twist2 {
    let mut n = || -> f64 { StandardNormal.sample(rng) };
    Twist2::new(std[0] * n(), std[1] * n(), std[2] * n())
}

/// The training distribution of flow time: `t = s·(1 − u)`, `u ~ Beta(α, β)`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TimeDistribution {
    /// Beta shape `α`. Default 1.5.
    pub alpha: f64,
    /// Beta shape `β`. Default 1.0.
    pub beta: f64,
    /// Upper end `s` of `t`. Default 0.999.
    pub s: f64,
}

impl Default for TimeDistribution {
    fn default() -> Self {
        Self {
            alpha: 1.5,
            beta: 1.0,
            s: 0.999,
        }
    }
}

impl TimeDistribution {
    /// Checks the shapes are positive and `0 < s ≤ 1`.
    pub fn validate(&self) -> Result<(), CfmError> {
        if !(self.alpha.is_finite() && self.alpha > 0.0) {
            return Err(CfmError::option(
                "train.time.alpha",
                "must be finite and > 0",
            ));
        }
        if !(self.beta.is_finite() && self.beta > 0.0) {
            return Err(CfmError::option(
                "train.time.beta",
                "must be finite and > 0",
            ));
        }
        if !(self.s > 0.0 && self.s <= 1.0) {
            return Err(CfmError::option("train.time.s", "must lie in (0, 1]"));
        }
        Ok(())
    }

    /// A sampler for this distribution (fails when the options are invalid).
    pub fn sampler(&self) -> Result<TimeSampler, CfmError> {
        self.validate()?;
        let beta = Beta::new(self.alpha, self.beta)
            .map_err(|e| CfmError::option("train.time", e.to_string()))?;
        Ok(TimeSampler { beta, s: self.s })
    }

    /// The mean of `t`: `s·β/(α + β)`.
    pub fn mean(&self) -> f64 {
        self.s * self.beta / (self.alpha + self.beta)
    }
}

/// Draws flow times from a [`TimeDistribution`].
#[derive(Clone, Copy, Debug)]
pub struct TimeSampler {
    beta: Beta<f64>,
    s: f64,
}

impl TimeSampler {
    /// One draw of `t`.
    pub fn sample<R: Rng + ?Sized>(&self, rng: &mut R) -> f64 {
        self.s * (1.0 - self.beta.sample(rng))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;
    use proptest::prelude::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    fn pose() -> impl Strategy<Value = Pose2> {
        (-5.0..5.0f64, -5.0..5.0f64, -3.0..3.0f64).prop_map(|(x, y, t)| Pose2::new(x, y, t))
    }

    proptest! {
        /// The target is the velocity of the interpolation: a central finite difference of
        /// `x_t` in the body frame, `log(x_t⁻¹·x_{t+h})/h`, matches `ξ`; and it equals the
        /// paper's expression divided by `(1 − t)`.
        #[test]
        fn target_is_velocity_of_geodesic(x0 in pose(), x1 in pose(), t in 0.05..0.95f64) {
            let xi = target_velocity(x0, x1);
            let h = 1e-5;
            let a = geodesic_point(x0, xi, t - h);
            let b = geodesic_point(x0, xi, t + h);
            let xt = geodesic_point(x0, xi, t);
            let fd = a.between(b).log().scale(1.0 / (2.0 * h));
            // Central difference of the body velocity; error O(h²).
            prop_assert!((fd.vx - xi.vx).abs() < 1e-6 * (1.0 + xi.vx.abs()));
            prop_assert!((fd.vy - xi.vy).abs() < 1e-6 * (1.0 + xi.vy.abs()));
            prop_assert!((fd.omega - xi.omega).abs() < 1e-6 * (1.0 + xi.omega.abs()));
            let paper = target_velocity_from(xt, x1, t);
            prop_assert!((paper.vx - xi.vx).abs() < 1e-8 * (1.0 + xi.vx.abs()));
            prop_assert!((paper.vy - xi.vy).abs() < 1e-8 * (1.0 + xi.vy.abs()));
            prop_assert!((paper.omega - xi.omega).abs() < 1e-8 * (1.0 + xi.omega.abs()));
            // Without the division the printed expression is (1 − t)·ξ, not the velocity.
            let printed = xt.between(x1).log();
            prop_assert!((printed.vx - (1.0 - t) * xi.vx).abs() < 1e-8 * (1.0 + xi.vx.abs()));
        }

        /// Eq. 4 hits both end points.
        #[test]
        fn geodesic_end_points(x0 in pose(), x1 in pose()) {
            let xi = target_velocity(x0, x1);
            let end = geodesic_point(x0, xi, 1.0);
            prop_assert!((end.x - x1.x).abs() < 1e-9 && (end.y - x1.y).abs() < 1e-9);
            prop_assert!(human2nav_core::se2::wrap_angle(end.theta - x1.theta).abs() < 1e-9);
            let start = geodesic_point(x0, xi, 0.0);
            prop_assert!((start.x - x0.x).abs() < 1e-12);
        }
    }

    #[test]
    fn one_euler_step_of_the_target_reaches_the_data() {
        // Integrating the constant target with Eq. 5 from x0 over [0, 1] in any number of
        // steps lands on x1.
        let x0 = Pose2::new(0.3, -0.2, 0.4);
        let x1 = Pose2::new(2.0, 1.0, -0.7);
        let xi = target_velocity(x0, x1);
        let mut x = x0;
        for _ in 0..7 {
            x = x.euler_step(xi, 1.0 / 7.0);
        }
        assert_relative_eq!(x.x, x1.x, epsilon = 1e-12);
        assert_relative_eq!(x.y, x1.y, epsilon = 1e-12);
        assert_relative_eq!(x.theta, x1.theta, epsilon = 1e-12);
    }

    #[test]
    fn source_moments_match_std() {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let std = [0.5, 2.0, 0.3];
        let n = 40_000;
        let x = sample_source(n / 10, 10, std, &mut rng);
        assert_eq!(x.len(), n * 3);
        // Map back to the algebra and check the per-component variance.
        let mut var = [0.0; 3];
        for p in x.chunks_exact(3) {
            let xi = Pose2::from_slice(p).log().to_array();
            for c in 0..3 {
                var[c] += xi[c] * xi[c] / n as f64;
            }
        }
        for c in 0..3 {
            assert_relative_eq!(var[c].sqrt(), std[c], max_relative = 0.03);
        }
    }

    #[test]
    fn time_distribution_mean_and_range() {
        let d = TimeDistribution::default();
        let s = d.sampler().unwrap();
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let n = 50_000;
        let mut mean = 0.0;
        for _ in 0..n {
            let t = s.sample(&mut rng);
            assert!((0.0..=d.s).contains(&t));
            mean += t / n as f64;
        }
        // s·β/(α+β) = 0.999·1/2.5.
        assert_relative_eq!(mean, d.mean(), epsilon = 5e-3);
        assert_relative_eq!(d.mean(), 0.3996, epsilon = 1e-12);
        assert!(TimeDistribution { alpha: 0.0, ..d }.sampler().is_err());
    }
}
