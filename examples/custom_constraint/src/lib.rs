//! `proximity_speed`: slow down near people. The example of `examples/custom_constraint`.
//!
//! Near a pedestrian the robot should not go faster than `v_near`; far from everyone the
//! robot's own limits (the built-in terms) apply. For segment `k` of a trajectory (poses `k`
//! and `k + 1`, `T − 1` segments, time `(k + ½)·dt`):
//!
//! ```text
//! Δ_k = p_{k+1} − p_k,   v_k = sqrt(|Δ_k|² + ε²) / dt              (speed, ε = 1e-9 m)
//! m_k = (p_k + p_{k+1}) / 2                                         (segment midpoint)
//! w_kj = exp(−|m_k − q_j|² / (2ℓ²))                                 (closeness to agent j,
//!                                                                    predicted at constant velocity)
//! h_k = softplus(γ·(v_k / v_near − 1 + δ)) / γ                      (Eq. 8 margin on the speed)
//! cost = (1 / (T − 1)) · Σ_k (Σ_j w_kj) · h_k
//! ```
//!
//! The gradient is analytic (product rule over `W_k = Σ_j w_kj` and `h_k`):
//! `∂h_k/∂Δ_k = σ(u_k)·Δ_k / (v_near·dt²·v_k)` and `∂W_k/∂m_k = −Σ_j w_kj·(m_k − q_j)/ℓ²`,
//! with `Δ_k` pulling on `p_{k+1}` (+) and `p_k` (−) and `m_k` on both by ½.
//!
//! Configuration (TOML, unknown fields rejected):
//!
//! ```toml
//! v_near = 0.5        # m/s, speed allowed next to a person
//! length_scale = 1.0  # m, ℓ: how far "near" reaches (w = 0.61 at ℓ, 0.011 at 3ℓ)
//! gamma = 10.0        # softplus sharpness γ
//! delta = 0.05        # margin δ
//! predict = true      # constant-velocity prediction of the pedestrians
//! ```

use human2nav::core::constraint::{ConstraintContext, ConstraintError, ConstraintTerm, TrajBatch};
use human2nav::plugin::{InitError, PluginInit};
use serde::Deserialize;

/// Options of the term.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ProximitySpeedConfig {
    /// Speed allowed next to a person (m/s). Default 0.5.
    pub v_near: f64,
    /// How far "near" reaches, `ℓ` (m). Default 1.0.
    pub length_scale: f64,
    /// Softplus sharpness `γ`. Default 10.
    pub gamma: f64,
    /// Margin `δ` in `[0, 1)`. Default 0.05.
    pub delta: f64,
    /// Predict pedestrians at constant velocity. Default true.
    pub predict: bool,
}

impl Default for ProximitySpeedConfig {
    fn default() -> Self {
        Self {
            v_near: 0.5,
            length_scale: 1.0,
            gamma: 10.0,
            delta: 0.05,
            predict: true,
        }
    }
}

impl ProximitySpeedConfig {
    /// Checks every value; errors name the field.
    pub fn validate(&self) -> Result<(), InitError> {
        let positive = |v: f64| v.is_finite() && v > 0.0;
        if !positive(self.v_near) {
            return Err(InitError::invalid("v_near", "must be finite and > 0"));
        }
        if !positive(self.length_scale) {
            return Err(InitError::invalid("length_scale", "must be finite and > 0"));
        }
        if !positive(self.gamma) {
            return Err(InitError::invalid("gamma", "must be finite and > 0"));
        }
        if !(self.delta.is_finite() && (0.0..1.0).contains(&self.delta)) {
            return Err(InitError::invalid("delta", "must be in [0, 1)"));
        }
        Ok(())
    }
}

/// The constraint term.
#[derive(Clone, Debug, PartialEq)]
pub struct ProximitySpeed {
    config: ProximitySpeedConfig,
}

impl ProximitySpeed {
    /// A term with validated options.
    pub fn new(config: ProximitySpeedConfig) -> Result<Self, InitError> {
        config.validate()?;
        Ok(Self { config })
    }

    /// The plugin factory: parses the TOML configuration.
    pub fn from_init(init: &PluginInit<'_>) -> Result<Self, InitError> {
        Self::new(init.config()?)
    }
}

fn softplus(x: f64) -> f64 {
    if x > 0.0 {
        x + (-x).exp().ln_1p()
    } else {
        x.exp().ln_1p()
    }
}

fn sigmoid(x: f64) -> f64 {
    if x >= 0.0 {
        1.0 / (1.0 + (-x).exp())
    } else {
        let e = x.exp();
        e / (1.0 + e)
    }
}

impl ConstraintTerm for ProximitySpeed {
    fn name(&self) -> &str {
        "proximity_speed"
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
        if !(ctx.dt.is_finite() && ctx.dt > 0.0) {
            return Err(ConstraintError::Failed {
                term: self.name().into(),
                message: format!("dt = {} must be finite and positive", ctx.dt),
            });
        }
        if batch.horizon < 2 || ctx.agents.is_empty() {
            return Ok(());
        }
        let c = &self.config;
        let (dt, inv_l2) = (ctx.dt, 1.0 / (c.length_scale * c.length_scale));
        let scale = 1.0 / (batch.horizon - 1) as f64;
        for b in 0..batch.batch {
            let p = batch.trajectory(b);
            let g = &mut grad[b * batch.horizon * 3..(b + 1) * batch.horizon * 3];
            let mut total = 0.0;
            for k in 0..batch.horizon - 1 {
                let (x0, y0, x1, y1) = (p[3 * k], p[3 * k + 1], p[3 * k + 3], p[3 * k + 4]);
                let (dx, dy) = (x1 - x0, y1 - y0);
                let len = (dx * dx + dy * dy + 1e-18).sqrt();
                let v = len / dt;
                let u = c.gamma * (v / c.v_near - 1.0 + c.delta);
                let h = softplus(u) / c.gamma;
                // W_k and ∂W_k/∂m_k.
                let (mx, my) = (0.5 * (x0 + x1), 0.5 * (y0 + y1));
                let t = if c.predict {
                    (k as f64 + 0.5) * dt
                } else {
                    0.0
                };
                let (mut w, mut dwx, mut dwy) = (0.0, 0.0, 0.0);
                for a in ctx.agents {
                    let rx = mx - (a.position[0] + a.velocity[0] * t);
                    let ry = my - (a.position[1] + a.velocity[1] * t);
                    let wj = (-0.5 * (rx * rx + ry * ry) * inv_l2).exp();
                    w += wj;
                    dwx -= wj * rx * inv_l2;
                    dwy -= wj * ry * inv_l2;
                }
                total += w * h;
                // ∂(W·h)/∂Δ = W·σ(u)/(v_near·dt)·Δ/len; ∂(W·h)/∂m = h·∂W/∂m.
                let dh = w * sigmoid(u) / (c.v_near * dt * len);
                let (gdx, gdy) = (dh * dx, dh * dy);
                let (gmx, gmy) = (0.5 * h * dwx, 0.5 * h * dwy);
                g[3 * k] += scale * (gmx - gdx);
                g[3 * k + 1] += scale * (gmy - gdy);
                g[3 * k + 3] += scale * (gmx + gdx);
                g[3 * k + 4] += scale * (gmy + gdy);
            }
            cost[b] += scale * total;
        }
        Ok(())
    }
}

human2nav::plugin::export_plugin! {
    name: "proximity_speed",
    version: env!("CARGO_PKG_VERSION"),
    factories: [
        constraint("proximity_speed", "speed limit v_near close to pedestrians (Gaussian proximity)")
            => ProximitySpeed::from_init,
    ],
}

#[cfg(test)]
mod tests {
    use super::*;
    use human2nav::core::{AgentState, Limits, Twist2};

    fn eval(term: &ProximitySpeed, data: &[f64], b: usize, t: usize) -> (Vec<f64>, Vec<f64>) {
        let limits = Limits {
            v_max: 1.5,
            v_reverse_max: 0.5,
            a_max: 1.0,
            omega_max: 2.0,
            kappa_max: None,
            lateral_speed_max: 0.05,
            coupled: None,
        };
        let agents = [
            AgentState {
                id: 1,
                position: [1.0, 0.4],
                velocity: [-0.5, 0.0],
                radius: 0.3,
                history: vec![],
            },
            AgentState {
                id: 2,
                position: [0.2, -1.0],
                velocity: [0.0, 0.6],
                radius: 0.3,
                history: vec![],
            },
        ];
        let ctx = ConstraintContext {
            dt: 0.1,
            limits: &limits,
            initial_velocity: Twist2::ZERO,
            agents: &agents,
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

    /// Two trajectories of 6 poses at about 1 m/s (above v_near) passing the agents.
    fn data() -> Vec<f64> {
        (0..2)
            .flat_map(|b| {
                (0..6).flat_map(move |k| {
                    let s = k as f64 * 0.1;
                    [
                        s * (1.0 + 0.1 * b as f64),
                        0.2 * s * s - 0.1 * b as f64,
                        0.0,
                    ]
                })
            })
            .collect()
    }

    #[test]
    fn fast_near_people_costs_slow_does_not() {
        let term = ProximitySpeed::new(ProximitySpeedConfig::default()).unwrap();
        let (fast, _) = eval(&term, &data(), 2, 6);
        assert!(fast.iter().all(|c| *c > 0.05), "{fast:?}");
        let slow: Vec<f64> = data().iter().map(|v| v * 0.2).collect();
        let (slow_cost, _) = eval(&term, &slow, 2, 6);
        assert!(
            slow_cost.iter().zip(&fast).all(|(s, f)| *s < 0.01 * f),
            "{slow_cost:?} vs {fast:?}"
        );
    }

    #[test]
    fn gradient_matches_central_differences() {
        let term = ProximitySpeed::new(ProximitySpeedConfig::default()).unwrap();
        let x = data();
        let (_, grad) = eval(&term, &x, 2, 6);
        let h = 1e-6;
        for i in 0..x.len() {
            let mut p = x.clone();
            p[i] += h;
            let (cp, _) = eval(&term, &p, 2, 6);
            p[i] -= 2.0 * h;
            let (cm, _) = eval(&term, &p, 2, 6);
            let fd = (cp[i / 18] - cm[i / 18]) / (2.0 * h);
            assert!(
                (fd - grad[i]).abs() <= 1e-6 * (1.0 + grad[i].abs()),
                "x[{i}]: fd {fd} vs {}",
                grad[i]
            );
        }
    }

    #[test]
    fn config_is_checked() {
        let err = ProximitySpeed::from_init(&PluginInit::new("v_near = 0", None)).unwrap_err();
        assert_eq!(err, InitError::invalid("v_near", "must be finite and > 0"));
        let err = ProximitySpeed::from_init(&PluginInit::new("speed = 1", None)).unwrap_err();
        assert!(err.is_config(), "{err}");
    }
}

// The Rust snippets of the plugin guides are doctests of this crate: they are written against
// the same dependencies (`human2nav` without its default features, and `serde`) as the plugin
// crates the guides build. `cargo test -p human2nav-example-proximity-speed --doc` compiles
// them and runs their unit tests; `tests/tests/guides.rs` checks that every guide page with
// Rust code is listed here.
#[cfg(doctest)]
#[doc = include_str!("../../../docs/guide/constraint-plugin.md")]
mod guide_constraint_plugin {}

#[cfg(doctest)]
#[doc = include_str!("../../../docs/guide/planner-plugin.md")]
mod guide_planner_plugin {}

#[cfg(doctest)]
#[doc = include_str!("../../../docs/guide/embodiment-plugin.md")]
mod guide_embodiment_plugin {}
