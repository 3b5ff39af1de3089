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
/// lateral-speed and reverse-speed terms, and the softplus sharpness `γ` and margin `δ` of Eq. 8.
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
            gamma: 10.0,
            delta: 0.05,
        }
    }
}
