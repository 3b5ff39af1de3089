//! `personal_space`: an example third-party constraint term, shipped as a plugin.
//!
//! It keeps planned poses out of the personal space of pedestrians, predicted at constant
//! velocity along the plan. For pose `k` of a trajectory (time `k·dt` after the planning
//! instant) and agent `j` predicted at `q_j(k) = p_j + v_j·k·dt`:
//!
//! ```text
//! d      = sqrt(|x_k − q_j(k)|² + ε²)                (ε = 1e-6 m keeps d differentiable)
//! d_safe = robot_radius + r_j + personal_space
//! s      = 1 − d / d_safe                              (normalised intrusion; > 0 inside)
//! cost_b = (1/T) Σ_k Σ_j (1/γ) · softplus(γ·(s + δ))
//! ```
//!
//! This is the soft margin of the paper's Eq. 8 applied to the intrusion `s` instead of
//! `|x|/limit − 1`: the penalty starts rising when a pose comes within `(1 + δ)·d_safe` of a
//! pedestrian and grows linearly (slope `1/d_safe` per metre) inside. The gradient is analytic:
//!
//! ```text
//! ∂cost_b/∂x_k = −(1/T) Σ_j σ(γ·(s + δ)) · (x_k − q_j(k)) / (d · d_safe),   ∂cost_b/∂θ_k = 0
//! ```
//!
//! Pairs with `γ·(s + δ) < −36` are skipped: their softplus is below `2.4e-16` (under one ulp of
//! a cost of order one).
//!
//! Configuration (TOML, every field optional, unknown fields rejected):
//!
//! ```toml
//! personal_space = 0.5   # m, beyond the two bodies' radii
//! robot_radius = 0.3     # m; default: the robot's footprint radius, else 0.3
//! gamma = 10.0           # softplus sharpness γ
//! delta = 0.05           # margin δ
//! predict = true         # constant-velocity prediction of the agents (false: frozen)
//! ```

use human2nav_core::constraint::{
    ConstraintContext, ConstraintError, ConstraintTerm, TrajBatch, sigmoid, softplus,
};
use human2nav_plugin::{InitError, PluginInit};
use serde::Deserialize;

/// Smoothing of the distance, `d = sqrt(|Δ|² + ε²)`.
pub const EPSILON: f64 = 1e-6;

/// Pairs whose softplus argument is below this are skipped (their cost is < 2.4e-16).
pub const SKIP_BELOW: f64 = -36.0;

/// Robot radius used when neither the config nor the robot context gives one (m).
pub const DEFAULT_ROBOT_RADIUS: f64 = 0.3;

/// Options of the term, as written in the TOML config.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PersonalSpaceConfig {
    /// Personal space beyond the two bodies' radii (m). Default 0.5.
    pub personal_space: f64,
    /// The robot's radius (m). Default: the robot's footprint radius, else 0.3.
    pub robot_radius: Option<f64>,
    /// Softplus sharpness `γ`. Default 10.
    pub gamma: f64,
    /// Margin `δ` in `[0, 1)`. Default 0.05.
    pub delta: f64,
    /// Predict agents at constant velocity along the plan. Default true.
    pub predict: bool,
}

impl Default for PersonalSpaceConfig {
    fn default() -> Self {
        Self {
            personal_space: 0.5,
            robot_radius: None,
            gamma: 10.0,
            delta: 0.05,
            predict: true,
        }
    }
}

impl PersonalSpaceConfig {
    /// Checks every value; errors name the field.
    pub fn validate(&self) -> Result<(), InitError> {
        if !(self.personal_space.is_finite() && self.personal_space >= 0.0) {
            return Err(InitError::invalid(
                "personal_space",
                "must be finite and >= 0",
            ));
        }
        if let Some(r) = self.robot_radius {
            if !(r.is_finite() && r >= 0.0) {
                return Err(InitError::invalid(
                    "robot_radius",
                    "must be finite and >= 0",
                ));
            }
        }
        if !(self.gamma.is_finite() && self.gamma > 0.0) {
            return Err(InitError::invalid("gamma", "must be finite and > 0"));
        }
        if !(self.delta.is_finite() && (0.0..1.0).contains(&self.delta)) {
            return Err(InitError::invalid("delta", "must be in [0, 1)"));
        }
        Ok(())
    }
}

/// The personal-space clearance term.
#[derive(Clone, Debug, PartialEq)]
pub struct PersonalSpace {
    /// Personal space beyond the radii (m).
    pub personal_space: f64,
    /// The robot's radius (m).
    pub robot_radius: f64,
    /// Softplus sharpness `γ`.
    pub gamma: f64,
    /// Margin `δ`.
    pub delta: f64,
    /// Constant-velocity prediction of agents.
    pub predict: bool,
}

impl PersonalSpace {
    /// The term from a validated config and the robot's footprint radius (if known).
    pub fn new(
        config: &PersonalSpaceConfig,
        footprint_radius: Option<f64>,
    ) -> Result<Self, InitError> {
        config.validate()?;
        Ok(Self {
            personal_space: config.personal_space,
            robot_radius: config
                .robot_radius
                .or(footprint_radius)
                .unwrap_or(DEFAULT_ROBOT_RADIUS),
            gamma: config.gamma,
            delta: config.delta,
            predict: config.predict,
        })
    }

    /// The plugin factory: parses the TOML config.
    pub fn from_init(init: &PluginInit<'_>) -> Result<Self, InitError> {
        let config: PersonalSpaceConfig = init.config()?;
        Self::new(&config, init.robot().map(|r| r.footprint_radius))
    }
}

impl ConstraintTerm for PersonalSpace {
    fn name(&self) -> &str {
        "personal_space"
    }

    /// A sum of softplus terms per trajectory (γ > 0): never negative, finite for finite
    /// poses, and each trajectory's cost is computed from it alone.
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
        if cost.len() != batch.batch || grad.len() != batch.data.len() {
            return Err(ConstraintError::Shape(format!(
                "cost {} / gradient {} entries for {} trajectories of {} poses",
                cost.len(),
                grad.len(),
                batch.batch,
                batch.horizon
            )));
        }
        if self.predict && !(ctx.dt.is_finite() && ctx.dt > 0.0) {
            return Err(ConstraintError::Failed {
                term: self.name().into(),
                message: format!("dt = {} must be finite and positive", ctx.dt),
            });
        }
        if batch.horizon == 0 || ctx.agents.is_empty() {
            return Ok(());
        }
        let inv_t = 1.0 / batch.horizon as f64;
        let inv_gamma = 1.0 / self.gamma;
        let dt = if self.predict { ctx.dt } else { 0.0 };
        for b in 0..batch.batch {
            let traj = batch.trajectory(b);
            let g = &mut grad[b * batch.horizon * 3..(b + 1) * batch.horizon * 3];
            let mut c = 0.0;
            for k in 0..batch.horizon {
                let (x, y) = (traj[3 * k], traj[3 * k + 1]);
                let t = k as f64 * dt;
                for a in ctx.agents {
                    let d_safe = self.robot_radius + a.radius + self.personal_space;
                    if d_safe <= 0.0 {
                        continue;
                    }
                    let dx = x - (a.position[0] + a.velocity[0] * t);
                    let dy = y - (a.position[1] + a.velocity[1] * t);
                    let d = (dx * dx + dy * dy + EPSILON * EPSILON).sqrt();
                    let z = self.gamma * (1.0 - d / d_safe + self.delta);
                    if z < SKIP_BELOW {
                        continue;
                    }
                    c += inv_gamma * softplus(z);
                    let w = -inv_t * sigmoid(z) / (d * d_safe);
                    g[3 * k] += w * dx;
                    g[3 * k + 1] += w * dy;
                }
            }
            cost[b] += c * inv_t;
        }
        Ok(())
    }
}

human2nav_plugin::export_plugin! {
    name: "personal_space",
    version: env!("CARGO_PKG_VERSION"),
    factories: [
        constraint(
            "personal_space",
            "soft personal-space clearance around constant-velocity pedestrians (Eq. 8 margin)"
        ) => PersonalSpace::from_init,
    ],
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;
    use human2nav_core::{AgentState, Limits, Twist2};
    use proptest::prelude::*;

    fn limits() -> Limits {
        Limits {
            v_max: 1.2,
            v_reverse_max: 0.3,
            a_max: 1.0,
            omega_max: 1.5,
            kappa_max: None,
            lateral_speed_max: 0.05,
            coupled: None,
        }
    }

    fn agent(id: u64, p: [f64; 2], v: [f64; 2], r: f64) -> AgentState {
        AgentState {
            id,
            position: p,
            velocity: v,
            radius: r,
            history: vec![],
        }
    }

    fn eval(
        term: &PersonalSpace,
        data: &[f64],
        b: usize,
        t: usize,
        agents: &[AgentState],
    ) -> (Vec<f64>, Vec<f64>) {
        let l = limits();
        let ctx = ConstraintContext {
            dt: 0.1,
            limits: &l,
            initial_velocity: Twist2::ZERO,
            agents,
            scene: Default::default(),
        };
        let mut cost = vec![0.0; b];
        let mut grad = vec![0.0; data.len()];
        term.evaluate(
            TrajBatch::new(data, b, t).unwrap(),
            &ctx,
            &mut cost,
            &mut grad,
        )
        .unwrap();
        (cost, grad)
    }

    fn term() -> PersonalSpace {
        PersonalSpace::new(
            &PersonalSpaceConfig {
                robot_radius: Some(0.3),
                ..Default::default()
            },
            None,
        )
        .unwrap()
    }

    #[test]
    fn single_pose_closed_form() {
        // One pose at the origin, one static agent at (1, 0) of radius 0.2:
        // d_safe = 0.3 + 0.2 + 0.5 = 1.0, d = 1, s = 0, z = γδ = 0.5. ε shifts d by 5e-13,
        // hence the 1e-10 tolerance.
        let t = term();
        let a = [agent(1, [1.0, 0.0], [0.0, 0.0], 0.2)];
        let (cost, grad) = eval(&t, &[0.0, 0.0, 0.3], 1, 1, &a);
        let z: f64 = 0.5;
        assert_relative_eq!(cost[0], (1.0 + z.exp()).ln() / 10.0, max_relative = 1e-10);
        let sig = 1.0 / (1.0 + (-z).exp());
        // ∂/∂x = −σ(z)·(x − q)/(d·d_safe) = −σ·(−1)/1.
        assert_relative_eq!(grad[0], sig, max_relative = 1e-9);
        assert_relative_eq!(grad[1], 0.0, epsilon = 1e-15);
        assert_eq!(grad[2], 0.0);
    }

    #[test]
    fn agents_are_predicted_at_constant_velocity() {
        // Agent starts 100 m away moving at 100 m/s toward the poses (all at the origin), so
        // at index 9 (t = 0.9 s) it is still 10 m away (skipped) and at index 10 (t = 1 s) it is
        // on the pose.
        let t = term();
        let a = [agent(1, [100.0, 0.0], [-100.0, 0.0], 0.2)];
        let mut data = vec![0.0; 11 * 3];
        data[3 * 10 + 1] = 1e-3;
        let (cost, _) = eval(&t, &data, 1, 11, &a);
        // Only pose 10 is inside (d ≈ 1e-3, s ≈ 1): cost ≈ softplus(10·1.05)/10/11.
        let z: f64 = 10.0 * (1.0 - 1e-3 + 0.05);
        assert_relative_eq!(
            cost[0],
            (z + (-z).exp().ln_1p()) / 10.0 / 11.0,
            max_relative = 1e-6
        );
        let frozen = PersonalSpace {
            predict: false,
            ..t
        };
        let (cost_frozen, _) = eval(&frozen, &data, 1, 11, &a);
        assert_eq!(cost_frozen[0], 0.0);
    }

    #[test]
    fn no_agents_adds_nothing() {
        let (cost, grad) = eval(&term(), &[0.1, 0.2, 0.3, 0.4, 0.5, 0.6], 1, 2, &[]);
        assert_eq!(cost, vec![0.0]);
        assert!(grad.iter().all(|g| *g == 0.0));
    }

    #[test]
    fn config_defaults_and_validation() {
        let t = PersonalSpace::from_init(&PluginInit::new("", None)).unwrap();
        assert_eq!(t.robot_radius, DEFAULT_ROBOT_RADIUS);
        let err = PersonalSpace::from_init(&PluginInit::new("gamma = -1.0", None)).unwrap_err();
        assert_eq!(err, InitError::invalid("gamma", "must be finite and > 0"));
        let err = PersonalSpace::from_init(&PluginInit::new("radius = 1.0", None)).unwrap_err();
        assert!(err.is_config(), "{err}");
    }

    proptest! {
        #[test]
        fn gradient_matches_central_differences(
            poses in prop::collection::vec(-1.5f64..1.5, 2 * 5 * 3),
            ax in -1.0f64..1.0, ay in -1.0f64..1.0, vx in -1.0f64..1.0, vy in -1.0f64..1.0,
        ) {
            let t = term();
            let agents = [agent(1, [ax, ay], [vx, vy], 0.25), agent(2, [0.5, -0.5], [0.0, 0.3], 0.3)];
            let (_, grad) = eval(&t, &poses, 2, 5, &agents);
            let h = 1e-6;
            for i in 0..poses.len() {
                let mut p = poses.clone();
                p[i] += h;
                let (cp, _) = eval(&t, &p, 2, 5, &agents);
                p[i] -= 2.0 * h;
                let (cm, _) = eval(&t, &p, 2, 5, &agents);
                let b = i / 15;
                let fd = (cp[b] - cm[b]) / (2.0 * h);
                prop_assert!((fd - grad[i]).abs() <= 1e-6 * (1.0 + grad[i].abs()), "i={} fd={} an={}", i, fd, grad[i]);
            }
        }
    }
}
