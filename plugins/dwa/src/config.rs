//! The DWA settings: the sampling after ROS 2 Nav2's DWB controller, the objective after Fox,
//! Burgard & Thrun (1997). See the crate's README for each default against theirs.

use crate::kinematics::LimitOverrides;
use human2nav_plugin::InitError;
use serde::{Deserialize, Serialize};

/// Largest number of samples per axis of the window.
pub const MAX_SAMPLES_PER_AXIS: usize = 1000;

/// Largest number of poses of one rollout (`sim_time / plan_dt`).
pub const MAX_ROLLOUT_STEPS: f64 = 1000.0;

/// DWA settings. Every field has a default; robot-dependent ones (`radius` and the velocity
/// limits) take the robot's values unless the configuration sets them.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct DwaConfig {
    /// How long each sample is rolled out at constant velocity (s). Default 1.7 (DWB).
    pub sim_time: f64,
    /// The interval the dynamic window is reachable in (s): the window is the current
    /// velocity ± acceleration × this. Default 0.1 (the benchmark's replanning period).
    pub control_period: f64,
    /// Time between two rollout poses and two plan poses (s). Default 0.1.
    pub plan_dt: f64,
    /// Samples of `v_x` across the window. Default 20 (DWB).
    pub vx_samples: usize,
    /// Samples of `v_y` across the window (omnidirectional bases only). Default 5 (DWB).
    pub vy_samples: usize,
    /// Samples of `ω` across the window. Default 20 (DWB).
    pub vtheta_samples: usize,
    /// α, weight of the heading term. Default 2.
    pub heading_weight: f64,
    /// β, weight of the clearance term. Default 0.2.
    pub clearance_weight: f64,
    /// γ, weight of the velocity term. Default 0.2.
    pub velocity_weight: f64,
    /// The clearance term's distance when nothing is met within `sim_time` (m); the term is
    /// `dist / clearance_max`. Default 3.
    pub clearance_max: f64,
    /// Growth of the robot's disc for the clearance term (m). Default 0.1.
    pub safety_margin: f64,
    /// Smallest `v_x` sampled (m/s). Default 0: forward only, as Fox et al. and DWB's
    /// `min_vel_x`; a negative value lets the robot back up, down to its reverse limit.
    pub min_vel_x: f64,
    /// Largest forward speed (m/s). Default: the robot's `v_max`.
    pub vx_max: Option<f64>,
    /// Largest lateral speed (m/s). Default: the robot's `lateral_speed_max`.
    pub vy_max: Option<f64>,
    /// Largest yaw rate (rad/s). Default: the robot's `omega_max`.
    pub wz_max: Option<f64>,
    /// Largest linear acceleration (m/s²). Default: the robot's `a_max`.
    pub ax_max: Option<f64>,
    /// Largest curvature (1/m); set, it makes the model Ackermann. Default: the robot's.
    pub kappa_max: Option<f64>,
    /// Largest yaw acceleration (rad/s²): narrows the window in `ω`. Default: none (the robot
    /// profiles declare none; the whole yaw-rate range is sampled).
    pub wz_accel_max: Option<f64>,
    /// The robot's disc radius (m). Default: the robot's footprint radius (0.3 without one).
    pub radius: Option<f64>,
}

impl Default for DwaConfig {
    fn default() -> Self {
        Self {
            sim_time: 1.7,
            control_period: 0.1,
            plan_dt: 0.1,
            vx_samples: 20,
            vy_samples: 5,
            vtheta_samples: 20,
            heading_weight: 2.0,
            clearance_weight: 0.2,
            velocity_weight: 0.2,
            clearance_max: 3.0,
            safety_margin: 0.1,
            min_vel_x: 0.0,
            vx_max: None,
            vy_max: None,
            wz_max: None,
            ax_max: None,
            kappa_max: None,
            wz_accel_max: None,
            radius: None,
        }
    }
}

fn finite(key: &str, v: f64, ok: bool, what: &str) -> Result<(), InitError> {
    if v.is_finite() && ok {
        Ok(())
    } else {
        Err(InitError::invalid(
            key,
            format!("must be finite and {what}, got {v}"),
        ))
    }
}

impl DwaConfig {
    /// The limits the configuration sets in place of the robot's (`min_vel_x` bounds the
    /// samples, not the robot: the reverse limit stays the robot's).
    pub fn overrides(&self) -> LimitOverrides {
        LimitOverrides {
            vx_max: self.vx_max,
            vx_min: None,
            vy_max: self.vy_max,
            wz_max: self.wz_max,
            ax_max: self.ax_max,
            kappa_max: self.kappa_max,
        }
    }

    /// Checks every value; the error names the first offending key.
    pub fn validate(&self) -> Result<(), InitError> {
        for (key, v) in [
            ("sim_time", self.sim_time),
            ("control_period", self.control_period),
            ("plan_dt", self.plan_dt),
            ("clearance_max", self.clearance_max),
        ] {
            finite(key, v, v > 0.0, "> 0")?;
        }
        let steps = self.sim_time / self.plan_dt;
        if steps > MAX_ROLLOUT_STEPS {
            return Err(InitError::invalid(
                "sim_time",
                format!("sim_time / plan_dt must be at most {MAX_ROLLOUT_STEPS}, got {steps}"),
            ));
        }
        for (key, n) in [
            ("vx_samples", self.vx_samples),
            ("vy_samples", self.vy_samples),
            ("vtheta_samples", self.vtheta_samples),
        ] {
            if !(1..=MAX_SAMPLES_PER_AXIS).contains(&n) {
                return Err(InitError::invalid(
                    key,
                    format!("must be positive and at most {MAX_SAMPLES_PER_AXIS}, got {n}"),
                ));
            }
        }
        for (key, v) in [
            ("heading_weight", self.heading_weight),
            ("clearance_weight", self.clearance_weight),
            ("velocity_weight", self.velocity_weight),
            ("safety_margin", self.safety_margin),
        ] {
            finite(key, v, v >= 0.0, ">= 0")?;
        }
        finite("min_vel_x", self.min_vel_x, self.min_vel_x <= 0.0, "<= 0")?;
        self.overrides().validate()?;
        if let Some(a) = self.wz_accel_max {
            finite("wz_accel_max", a, a > 0.0, "> 0")?;
        }
        if let Some(r) = self.radius {
            finite("radius", r, r > 0.0, "> 0")?;
        }
        Ok(())
    }
}
