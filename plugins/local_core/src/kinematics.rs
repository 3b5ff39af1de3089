//! The robot's motion model and velocity bounds, derived from its [`Limits`].
//!
//! The plugin's [`RobotContext`](human2nav_plugin::RobotContext) carries limits but no
//! embodiment kind, so the kind is read off the limits by [`motion_model`]. The same rule and
//! the same clipping serve the MPPI and the DWA plugins (the DWA crate compiles this file as a
//! module of its own).

use human2nav_core::{CoupledLimit, Limits};
use human2nav_plugin::InitError;

/// A lateral speed limit above this (m/s) means the base really moves sideways; at or below
/// it the limit is a slip tolerance of a non-holonomic base (the shipped differential-drive and
/// Ackermann profiles declare 0.05 m/s).
pub const OMNI_LATERAL_THRESHOLD: f64 = 0.1;

/// How the base moves.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum MotionModel {
    /// `(v_x, ω)`, `v_y = 0`; turns in place.
    DiffDrive,
    /// `(v_x, v_y, ω)`, each within its own bound.
    Omni,
    /// `(v_x, ω)` with `|ω| ≤ κ_max·|v_x|`: no turning in place.
    Ackermann {
        /// Largest curvature `1 / r_min` (1/m).
        kappa_max: f64,
    },
}

impl MotionModel {
    /// A short name for notes and errors.
    pub fn name(&self) -> &'static str {
        match self {
            MotionModel::DiffDrive => "differential drive",
            MotionModel::Omni => "omnidirectional",
            MotionModel::Ackermann { .. } => "Ackermann",
        }
    }
}

/// The motion model of a robot with these limits:
///
/// 1. `kappa_max` set, finite and `> 0` → [`MotionModel::Ackermann`] with that curvature;
/// 2. else `lateral_speed_max > OMNI_LATERAL_THRESHOLD` → [`MotionModel::Omni`];
/// 3. else [`MotionModel::DiffDrive`].
///
/// Refused, with the reason: a non-finite or non-positive `v_max` or `a_max` (the robot cannot
/// move or accelerate), a negative or non-finite `v_reverse_max`, `omega_max` or
/// `lateral_speed_max`, a `kappa_max` that is set but not finite and `> 0`, and a
/// non-omnidirectional base with `omega_max = 0` (it could never turn toward a goal).
pub fn motion_model(limits: &Limits) -> Result<MotionModel, InitError> {
    let refuse = |why: String| Err(InitError::Failed(format!("cannot drive this robot: {why}")));
    let l = limits;
    if !(l.v_max.is_finite() && l.v_max > 0.0) {
        return refuse(format!("v_max is {} (must be finite and > 0)", l.v_max));
    }
    if !(l.a_max.is_finite() && l.a_max > 0.0) {
        return refuse(format!("a_max is {} (must be finite and > 0)", l.a_max));
    }
    for (name, v) in [
        ("v_reverse_max", l.v_reverse_max),
        ("omega_max", l.omega_max),
        ("lateral_speed_max", l.lateral_speed_max),
    ] {
        if !(v.is_finite() && v >= 0.0) {
            return refuse(format!("{name} is {v} (must be finite and >= 0)"));
        }
    }
    let model = match l.kappa_max {
        Some(k) if k.is_finite() && k > 0.0 => MotionModel::Ackermann { kappa_max: k },
        Some(k) => {
            return refuse(format!(
                "kappa_max is {k} (a car-like base needs a finite curvature > 0)"
            ));
        }
        None if l.lateral_speed_max > OMNI_LATERAL_THRESHOLD => MotionModel::Omni,
        None => MotionModel::DiffDrive,
    };
    if model != MotionModel::Omni && l.omega_max == 0.0 {
        return refuse(format!(
            "omega_max is 0 and the base is {}: it can never turn toward a goal",
            model.name()
        ));
    }
    Ok(model)
}

/// Limits a configuration may set in place of the robot's (`None`: the robot's value).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct LimitOverrides {
    /// Largest forward speed (m/s), `> 0`.
    pub vx_max: Option<f64>,
    /// Smallest (most negative) longitudinal speed (m/s), `<= 0`.
    pub vx_min: Option<f64>,
    /// Largest lateral speed either way (m/s), `>= 0`.
    pub vy_max: Option<f64>,
    /// Largest yaw rate either way (rad/s), `>= 0`.
    pub wz_max: Option<f64>,
    /// Largest linear acceleration (m/s²), `> 0`.
    pub ax_max: Option<f64>,
    /// Largest curvature (1/m), `> 0`: makes the model Ackermann.
    pub kappa_max: Option<f64>,
}

/// The limits used without a robot context (ROS 2 Nav2's MPPI defaults: `vx_max` 0.5 m/s,
/// `vx_min` −0.35 m/s, `wz_max` 1.9 rad/s, `ax_max` 3 m/s²; no lateral motion).
pub fn default_limits() -> Limits {
    Limits {
        v_max: 0.5,
        v_reverse_max: 0.35,
        a_max: 3.0,
        omega_max: 1.9,
        kappa_max: None,
        lateral_speed_max: 0.0,
        coupled: None,
    }
}

impl LimitOverrides {
    /// Checks each value that is set; the error names the key.
    pub fn validate(&self) -> Result<(), InitError> {
        let check = |key: &str, v: Option<f64>, ok: fn(f64) -> bool, what: &str| match v {
            Some(x) if !(x.is_finite() && ok(x)) => Err(InitError::invalid(
                key,
                format!("must be finite and {what}, got {x}"),
            )),
            _ => Ok(()),
        };
        check("vx_max", self.vx_max, |x| x > 0.0, "> 0")?;
        check("vx_min", self.vx_min, |x| x <= 0.0, "<= 0")?;
        check("vy_max", self.vy_max, |x| x >= 0.0, ">= 0")?;
        check("wz_max", self.wz_max, |x| x >= 0.0, ">= 0")?;
        check("ax_max", self.ax_max, |x| x > 0.0, "> 0")?;
        check("kappa_max", self.kappa_max, |x| x > 0.0, "> 0")
    }

    /// The robot's limits (or [`default_limits`] without a robot) with the set values in place.
    pub fn apply(&self, robot: Option<&Limits>) -> Result<Limits, InitError> {
        self.validate()?;
        let mut l = robot.copied().unwrap_or_else(default_limits);
        if let Some(v) = self.vx_max {
            l.v_max = v;
        }
        if let Some(v) = self.vx_min {
            l.v_reverse_max = -v;
        }
        if let Some(v) = self.vy_max {
            l.lateral_speed_max = v;
        }
        if let Some(v) = self.wz_max {
            l.omega_max = v;
        }
        if let Some(v) = self.ax_max {
            l.a_max = v;
        }
        if let Some(v) = self.kappa_max {
            l.kappa_max = Some(v);
        }
        Ok(l)
    }

    /// What a planner drives with: the velocity bounds of the robot's limits with the set
    /// values in place ([`Self::apply`], [`Bounds::new`]), and the disc radius (`radius` when
    /// the configuration sets it, else the robot's footprint radius, else
    /// [`DEFAULT_RADIUS`]). `robot` is the robot's limits and footprint radius, `None` without
    /// a robot. Errors name the key.
    pub fn resolve(
        &self,
        wz_accel_max: Option<f64>,
        radius: Option<f64>,
        robot: Option<(&Limits, f64)>,
    ) -> Result<(Bounds, f64), InitError> {
        let limits = self.apply(robot.map(|r| r.0))?;
        let bounds = Bounds::new(&limits, wz_accel_max)?;
        let radius = radius.or(robot.map(|r| r.1)).unwrap_or(DEFAULT_RADIUS);
        if !(radius.is_finite() && radius > 0.0) {
            return Err(InitError::invalid(
                "radius",
                format!("the robot's footprint radius {radius} must be finite and > 0"),
            ));
        }
        Ok((bounds, radius))
    }
}

/// The robot's disc radius (m) when neither the configuration nor a robot gives one.
pub const DEFAULT_RADIUS: f64 = 0.3;

/// The velocity bounds of one motion model: the speed box, the curvature and coupled limits,
/// and the acceleration.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Bounds {
    /// The motion model.
    pub model: MotionModel,
    /// Longitudinal speed range `[vx_min, vx_max]` (m/s).
    pub vx_min: f64,
    /// See `vx_min`.
    pub vx_max: f64,
    /// Lateral speed bound (m/s); 0 unless omnidirectional.
    pub vy_max: f64,
    /// Yaw-rate bound (rad/s).
    pub wz_max: f64,
    /// Linear acceleration bound (m/s²), on the norm of `(Δv_x, Δv_y)` as the embodiments apply
    /// it.
    pub ax_max: f64,
    /// Yaw acceleration bound (rad/s²); `None`: none (the robot profiles declare none).
    pub wz_accel_max: Option<f64>,
    /// A coupled limit declared by the robot's embodiment (a tracked base's track speed).
    pub coupled: Option<CoupledLimit>,
}

impl Bounds {
    /// The bounds of a robot with `limits` (checked by [`motion_model`]).
    pub fn new(limits: &Limits, wz_accel_max: Option<f64>) -> Result<Self, InitError> {
        let model = motion_model(limits)?;
        Ok(Self {
            model,
            vx_min: -limits.v_reverse_max,
            vx_max: limits.v_max,
            vy_max: if model == MotionModel::Omni {
                limits.lateral_speed_max
            } else {
                0.0
            },
            wz_max: limits.omega_max,
            ax_max: limits.a_max,
            wz_accel_max,
            coupled: limits.coupled,
        })
    }

    /// `u = [v_x, v_y, ω]` clipped into the speed box, the model's constraints (no lateral
    /// speed unless omnidirectional, `|ω| ≤ κ_max·|v_x|` for Ackermann) and the coupled limit
    /// (scaled down as a whole when it is exceeded).
    pub fn clip(&self, u: [f64; 3]) -> [f64; 3] {
        let vx = u[0].clamp(self.vx_min, self.vx_max);
        let vy = u[1].clamp(-self.vy_max, self.vy_max);
        let mut wz = u[2].clamp(-self.wz_max, self.wz_max);
        if let MotionModel::Ackermann { kappa_max } = self.model {
            let b = kappa_max * vx.abs();
            wz = wz.clamp(-b, b);
        }
        let mut out = [vx, vy, wz];
        if let Some(c) = &self.coupled {
            let value = c.value(vx, vy, wz);
            if value > c.max && value > 0.0 {
                let s = c.max / value;
                out = [vx * s, vy * s, wz * s];
            }
        }
        out
    }

    /// The velocity one step of `dt` after `v` when the base is commanded `u`: the change is
    /// limited by the accelerations, then the result clipped by [`Bounds::clip`].
    pub fn step_velocity(&self, v: [f64; 3], u: [f64; 3], dt: f64) -> [f64; 3] {
        let (mut dvx, mut dvy) = (u[0] - v[0], u[1] - v[1]);
        let dv = dvx.hypot(dvy);
        let max_dv = self.ax_max * dt;
        if dv > max_dv && dv > 0.0 {
            let s = max_dv / dv;
            dvx *= s;
            dvy *= s;
        }
        let mut dw = u[2] - v[2];
        if let Some(a) = self.wz_accel_max {
            dw = dw.clamp(-a * dt, a * dt);
        }
        self.clip([v[0] + dvx, v[1] + dvy, v[2] + dw])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn limits(kappa: Option<f64>, lateral: f64) -> Limits {
        Limits {
            kappa_max: kappa,
            lateral_speed_max: lateral,
            ..default_limits()
        }
    }

    #[test]
    fn the_model_follows_from_the_limits() {
        assert_eq!(
            motion_model(&limits(None, 0.05)).unwrap(),
            MotionModel::DiffDrive
        );
        assert_eq!(motion_model(&limits(None, 0.6)).unwrap(), MotionModel::Omni);
        assert_eq!(
            motion_model(&limits(Some(0.625), 0.6)).unwrap(),
            MotionModel::Ackermann { kappa_max: 0.625 }
        );
    }

    #[test]
    fn robots_that_cannot_drive_are_refused_with_the_reason() {
        let still = Limits {
            v_max: 0.0,
            ..default_limits()
        };
        let e = motion_model(&still).unwrap_err().to_string();
        assert!(e.contains("v_max") && e.contains("cannot drive"), "{e}");
        let e = motion_model(&limits(Some(0.0), 0.0))
            .unwrap_err()
            .to_string();
        assert!(e.contains("kappa_max"), "{e}");
        let stiff = Limits {
            omega_max: 0.0,
            ..default_limits()
        };
        assert!(
            motion_model(&stiff)
                .unwrap_err()
                .to_string()
                .contains("omega_max")
        );
        let nan = Limits {
            a_max: f64::NAN,
            ..default_limits()
        };
        assert!(
            motion_model(&nan)
                .unwrap_err()
                .to_string()
                .contains("a_max")
        );
    }

    #[test]
    fn clipping_keeps_the_curvature_and_the_acceleration() {
        let b = Bounds::new(&limits(Some(0.5), 0.0), None).unwrap();
        let u = b.clip([0.4, 0.3, 1.5]);
        assert_eq!(u[1], 0.0);
        assert!((u[2] - 0.2).abs() < 1e-12);
        let v = b.step_velocity([0.0, 0.0, 0.0], [0.5, 0.0, 0.0], 0.1);
        assert!((v[0] - 0.3).abs() < 1e-12, "{v:?}");
    }
}
