//! Sampling: the `N`-step Lie-group Euler integrator of Eq. 5, batched over `K` samples.
//!
//! The sampler only sees core's [`FlowModel`] trait, so it runs any flow model (network,
//! analytic test field, plugin proxy). Flow time follows the uniform grid `t_i = i/N`,
//! `Δt = 1/N`, and every waypoint advances as `X ← X·exp(Δt·V)`.

use crate::cfm::sample_source;
use human2nav_core::flow::{FlowCondition, FlowError, FlowModel};
use human2nav_core::se2::euler_step_batch;
use rand::Rng;

/// Integrates `x` (flat `[K, T, 3]`, modified in place) from `t = 0` to `t = 1` in `steps`
/// Euler steps on SE(2).
pub fn integrate<M: FlowModel + ?Sized>(
    model: &M,
    x: &mut [f64],
    cond: &FlowCondition,
    steps: usize,
) -> Result<(), FlowError> {
    if steps == 0 {
        return Err(FlowError::Shape(
            "integration needs at least one step".into(),
        ));
    }
    let dt = 1.0 / steps as f64;
    let mut v = vec![0.0; x.len()];
    for i in 0..steps {
        model.velocity(x, i as f64 * dt, cond, &mut v)?;
        euler_step_batch(x, &v, dt);
    }
    Ok(())
}

/// Draws `k` trajectories: source samples `exp(ξ0)` with the model's
/// [`FlowModel::source_std`], integrated with [`integrate`]. Returns flat `[k, T, 3]`.
pub fn sample<M: FlowModel + ?Sized, R: Rng + ?Sized>(
    model: &M,
    cond: &FlowCondition,
    k: usize,
    steps: usize,
    rng: &mut R,
) -> Result<Vec<f64>, FlowError> {
    let mut x = sample_source(k, model.horizon(), model.source_std(), rng);
    integrate(model, &mut x, cond, steps)?;
    Ok(x)
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;
    use human2nav_core::se2::{Pose2, Twist2};

    /// The exact flow-matching field towards one fixed trajectory `x1`: at `x_t` on the
    /// geodesic from `x0`, the velocity is `log(x_t⁻¹x1)/(1 − t)`.
    struct ToTarget {
        x1: Vec<Pose2>,
    }

    impl FlowModel for ToTarget {
        fn horizon(&self) -> usize {
            self.x1.len()
        }
        fn velocity(
            &self,
            x: &[f64],
            t: f64,
            _: &FlowCondition,
            out: &mut [f64],
        ) -> Result<(), FlowError> {
            let n = self.x1.len();
            for (i, (p, o)) in x.chunks_exact(3).zip(out.chunks_exact_mut(3)).enumerate() {
                let v = Pose2::from_slice(p)
                    .between(self.x1[i % n])
                    .log()
                    .scale(1.0 / (1.0 - t));
                o.copy_from_slice(&v.to_array());
            }
            Ok(())
        }
        fn velocity_vjp(
            &self,
            _: &[f64],
            _: f64,
            _: &FlowCondition,
            _: &[f64],
            _: &mut [f64],
            _: &mut [f64],
        ) -> Result<(), FlowError> {
            Err(FlowError::Backend("not needed".into()))
        }
    }

    #[test]
    fn exact_field_transports_every_source_sample_to_the_target() {
        use rand::SeedableRng;
        let x1 = vec![
            Pose2::new(1.0, 0.2, 0.3),
            Pose2::new(2.0, 0.5, -0.4),
            Pose2::new(3.0, 1.5, 1.2),
        ];
        let model = ToTarget { x1: x1.clone() };
        let cond = FlowCondition {
            bev: vec![],
            goal: [0.0; 2],
            velocity: [0.0; 2],
        };
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        let x = sample(&model, &cond, 5, 4, &mut rng).unwrap();
        for (i, p) in x.chunks_exact(3).enumerate() {
            let target = x1[i % 3];
            assert_relative_eq!(p[0], target.x, epsilon = 1e-9);
            assert_relative_eq!(p[1], target.y, epsilon = 1e-9);
            assert_relative_eq!(p[2], target.theta, epsilon = 1e-9);
        }
        let _ = Twist2::ZERO;
        assert!(integrate(&model, &mut [0.0; 9], &cond, 0).is_err());
    }
}
