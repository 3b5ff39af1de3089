//! Plain data shared by robot profiles, embodiments and constraint terms: the robot's hard
//! limits, its tracking-controller gains and the weights of the feasibility penalty Φ.
//!
//! Parsing and validation live in [`crate::robot`]; these structs carry no behaviour so that
//! constraint terms, embodiments and plugins can all depend on them.

use serde::{Deserialize, Serialize};

/// A robot's hard kinematic and dynamic limits, SI units, all finite and positive.
///
/// Feasibility (TFS) checks these; the soft-margin terms of Eq. 8 penalise approaching them.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Limits {
    /// Maximum forward speed `v_max` (m/s).
    pub v_max: f64,
    /// Maximum reverse speed (m/s, positive number).
    pub v_reverse_max: f64,
    /// Maximum longitudinal acceleration `a_max` (m/s², applies to braking too).
    pub a_max: f64,
    /// Maximum yaw rate `ω_max` (rad/s).
    pub omega_max: f64,
    /// Maximum curvature `κ_max = 1 / r_min` (1/m); `None` when the robot can turn in place.
    pub kappa_max: Option<f64>,
    /// Maximum body-frame lateral speed (m/s). For non-holonomic robots this is a small slip
    /// tolerance, for omnidirectional ones the real sideways limit.
    pub lateral_speed_max: f64,
    /// A limit on a weighted sum of the twist's magnitudes that the box limits above cannot
    /// express, declared by the embodiment ([`crate::embodiment::Embodiment::coupled_limit`]);
    /// `None` for the built-in embodiments.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub coupled: Option<CoupledLimit>,
}

/// A coupled twist limit `v·|v_x| + lateral·|v_y| + omega·|ω| ≤ max`: the wheel or track speed
/// of a base whose wheels share their speed between driving and turning. A skid-steered base
/// with track speed limit `s` and effective half track `χ·B/2` has
/// `|v| + (χ·B/2)·|ω| ≤ s` (the faster track's speed), so at full speed it cannot also turn.
///
/// TFS checks it (flag `coupled`), Φ has a soft-margin term on it (`λ_coupled`) and the
/// last-step correction keeps plans inside it.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CoupledLimit {
    /// Coefficient of `|v_x|` (dimensionless, `>= 0`).
    pub v: f64,
    /// Coefficient of `|v_y|` (dimensionless, `>= 0`).
    pub lateral: f64,
    /// Coefficient of `|ω|` (m/rad, `>= 0`).
    pub omega: f64,
    /// The bound (m/s, `> 0`).
    pub max: f64,
}

impl CoupledLimit {
    /// `v·|v_x| + lateral·|v_y| + omega·|ω|`, the quantity bounded by `max`.
    #[inline]
    pub fn value(&self, vx: f64, vy: f64, omega: f64) -> f64 {
        self.v * vx.abs() + self.lateral * vy.abs() + self.omega * omega.abs()
    }

    /// Checks the coefficients (finite, `>= 0`, at least one `> 0`) and the bound (finite,
    /// `> 0`); the error names the field.
    pub fn validate(&self) -> Result<(), (&'static str, String)> {
        for (field, c) in [
            ("v", self.v),
            ("lateral", self.lateral),
            ("omega", self.omega),
        ] {
            if !(c.is_finite() && c >= 0.0) {
                return Err((field, format!("{c} must be finite and >= 0")));
            }
        }
        if self.v == 0.0 && self.lateral == 0.0 && self.omega == 0.0 {
            return Err((
                "v",
                "every coefficient is 0: the limit bounds nothing".into(),
            ));
        }
        if !(self.max.is_finite() && self.max > 0.0) {
            return Err(("max", format!("{} must be finite and > 0", self.max)));
        }
        Ok(())
    }
}

/// Gains of the embodiment's PD tracking controller (see [`crate::embodiment`]).
///
/// Defaults: `k_x = 1.5`, `k_y = 4.0`, `k_theta = 3.0`, `k_d = 0.2`, `lookahead = 0.05`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ControllerGains {
    /// Proportional gain on the along-track position error (1/s).
    pub k_x: f64,
    /// Proportional gain on the cross-track position error (1/m², multiplied by the reference
    /// speed for non-holonomic embodiments; see [`crate::embodiment::BuiltinEmbodiment`]).
    pub k_y: f64,
    /// Proportional gain on the heading error (1/s).
    pub k_theta: f64,
    /// Derivative (velocity feed-forward error) gain, dimensionless.
    pub k_d: f64,
    /// Look-ahead time along the plan (s).
    pub lookahead: f64,
}

/// Weights and shape of the feasibility penalty: `λ_v, λ_a, λ_ω, λ_κ` of Eq. 9, the same for the
/// lateral-speed, reverse-speed and coupled-limit terms, and the softplus sharpness `γ` and
/// margin `δ` of Eq. 8.
///
/// Defaults: every `lambda_* = 1.0`, `gamma = 10.0`, `delta = 0.05`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct GuidanceWeights {
    /// Weight `λ_v` of the forward-speed term (against `v_max`); dimensionless, `>= 0`.
    pub lambda_v: f64,
    /// Weight `λ_a` of the longitudinal-acceleration term (against `a_max`).
    pub lambda_a: f64,
    /// Weight `λ_ω` of the yaw-rate term (against `omega_max`).
    pub lambda_omega: f64,
    /// Weight `λ_κ` of the curvature term (against `kappa_max`; no cost without one).
    pub lambda_kappa: f64,
    /// Weight of the body-frame lateral-speed term (against `lateral_speed_max`).
    pub lambda_lateral: f64,
    /// Weight of the reverse-speed term (against `v_reverse_max`).
    pub lambda_reverse: f64,
    /// Weight of the coupled-limit term (against the embodiment's [`CoupledLimit`]; no cost
    /// without one).
    pub lambda_coupled: f64,
    /// Softplus sharpness `γ` (Eq. 8).
    pub gamma: f64,
    /// Tolerance margin `δ` (Eq. 8): the penalty starts rising at `(1 − δ)·limit`.
    pub delta: f64,
}

impl Default for ControllerGains {
    fn default() -> Self {
        Self {
            k_x: 1.5,
            k_y: 4.0,
            k_theta: 3.0,
            k_d: 0.2,
            lookahead: 0.05,
        }
    }
}

impl Default for GuidanceWeights {
    fn default() -> Self {
        Self {
            lambda_v: 1.0,
            lambda_a: 1.0,
            lambda_omega: 1.0,
            lambda_kappa: 1.0,
            lambda_lateral: 1.0,
            lambda_reverse: 1.0,
            lambda_coupled: 1.0,
            gamma: 10.0,
            delta: 0.05,
        }
    }
}
