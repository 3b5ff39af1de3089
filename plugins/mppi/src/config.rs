//! The MPPI settings: names and defaults after ROS 2 Nav2's MPPI controller where a setting
//! has a counterpart there (see the crate's README for each default against Nav2's).

use crate::kinematics::LimitOverrides;
use human2nav_plugin::InitError;
use serde::{Deserialize, Serialize};

/// Largest `batch_size` (samples per iteration): far above Nav2's 1000 to 2000, low enough
/// that one call cannot allocate without bound.
pub const MAX_BATCH_SIZE: usize = 100_000;

/// Largest `time_steps`.
pub const MAX_TIME_STEPS: usize = 1000;

/// Largest `iteration_count`.
pub const MAX_ITERATIONS: usize = 100;

/// Nav2's `vx_std` over its `vx_max` (0.2 / 0.5); also `vy_std / vy_max`.
pub const NAV2_VX_STD_RATIO: f64 = 0.2 / 0.5;

/// Nav2's `wz_std` over its `wz_max` (0.4 / 1.9).
pub const NAV2_WZ_STD_RATIO: f64 = 0.4 / 1.9;

/// Largest `batch_size × time_steps` (the sampled controls held at once: 24 bytes each).
pub const MAX_SAMPLED_CONTROLS: usize = 10_000_000;

/// MPPI settings. Every field has a default; robot-dependent ones (`radius` and the velocity
/// limits) take the robot's values unless the configuration sets them.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct MppiConfig {
    /// Sampled control sequences per iteration. Default 1000 (Nav2).
    pub batch_size: usize,
    /// Controls (and poses after the current one) per sequence. Default 28 (2.8 s, Nav2's
    /// horizon of 56 steps of 0.05 s).
    pub time_steps: usize,
    /// Time between two controls and between two plan poses (s). Default 0.1 (Nav2: 0.05;
    /// Nav2 asks for the control period, the benchmark replans every 0.1 s).
    pub model_dt: f64,
    /// Sample–weight–update rounds per planning call. Default 1 (Nav2).
    pub iteration_count: usize,
    /// Softmax temperature λ of the sample weights `exp(−(S − S_min)/λ)`. Default 0.3 (Nav2).
    pub temperature: f64,
    /// Weight of the control-cost term `γ·Σ_t u_tᵀ Σ⁻¹ ε_t` of each sample. Default 0.015
    /// (Nav2).
    pub gamma: f64,
    /// Standard deviation of the noise on `v_x` (m/s). Default: `0.4·vx_max`, Nav2's ratio
    /// (0.2 for its 0.5 m/s); 0.2 without a robot.
    pub vx_std: Option<f64>,
    /// Standard deviation of the noise on `v_y` (m/s, omnidirectional bases). Default:
    /// `0.4·vy_max`, Nav2's ratio (0.2 for its 0.5 m/s).
    pub vy_std: Option<f64>,
    /// Standard deviation of the noise on `ω` (rad/s). Default: `(0.4/1.9)·wz_max`, Nav2's
    /// ratio (0.4 for its 1.9 rad/s).
    pub wz_std: Option<f64>,
    /// Largest forward speed (m/s). Default: the robot's `v_max` (Nav2: 0.5).
    pub vx_max: Option<f64>,
    /// Smallest longitudinal speed, `<= 0` (m/s). Default: minus the robot's `v_reverse_max`
    /// (Nav2: −0.35).
    pub vx_min: Option<f64>,
    /// Largest lateral speed (m/s). Default: the robot's `lateral_speed_max` (Nav2: 0.5).
    pub vy_max: Option<f64>,
    /// Largest yaw rate (rad/s). Default: the robot's `omega_max` (Nav2: 1.9).
    pub wz_max: Option<f64>,
    /// Largest linear acceleration (m/s²). Default: the robot's `a_max` (Nav2: 3.0).
    pub ax_max: Option<f64>,
    /// Largest curvature (1/m); set, it makes the model Ackermann. Default: the robot's
    /// `kappa_max` (Nav2: `1 / min_turning_r`).
    pub kappa_max: Option<f64>,
    /// Largest yaw acceleration (rad/s²). Default: none (the robot profiles declare none).
    pub wz_accel_max: Option<f64>,
    /// The robot's disc radius (m). Default: the robot's footprint radius (0.3 without one).
    pub radius: Option<f64>,
    /// Seed of the noise generator, re-seeded at every `reset` (episode). Default 0.
    pub seed: u64,
    /// Goal critic weight: `w · mean_t |p_t − goal|`. Default 5 (Nav2's GoalCritic).
    pub goal_weight: f64,
    /// Prefer-forward critic weight: `w · Σ_t max(−v_x, 0)·dt`. Default 5 (Nav2).
    pub prefer_forward_weight: f64,
    /// The prefer-forward critic is off within this distance of the goal (m). Default 0.5.
    pub prefer_forward_threshold: f64,
    /// Cost of a sample that touches an obstacle or a pedestrian. Default 10000 (Nav2).
    pub collision_cost: f64,
    /// Clearance below which the critical term applies (m). Default 0.1 (Nav2).
    pub collision_margin_distance: f64,
    /// Weight of the critical term `Σ_t (margin − clearance)`. Default 20 (Nav2).
    pub critical_weight: f64,
    /// Weight of the repulsion term `Σ_t (inflation − clearance) / T`. Default 1.5 (Nav2).
    pub repulsion_weight: f64,
    /// Clearance from a static obstacle below which repulsion applies (m). Default 0.55 (Nav2).
    pub inflation_radius: f64,
    /// Static-obstacle repulsion is off within this distance of the goal (m). Default 0.5
    /// (Nav2).
    pub near_goal_distance: f64,
    /// Factor on the pedestrian critic (the obstacle critic's form, against pedestrians
    /// walking on at constant velocity). Default 1.
    pub pedestrian_weight: f64,
    /// Clearance from a pedestrian below which repulsion applies (m). Default 0.55.
    pub pedestrian_inflation_radius: f64,
}

impl Default for MppiConfig {
    fn default() -> Self {
        Self {
            batch_size: 1000,
            time_steps: 28,
            model_dt: 0.1,
            iteration_count: 1,
            temperature: 0.3,
            gamma: 0.015,
            vx_std: None,
            vy_std: None,
            wz_std: None,
            vx_max: None,
            vx_min: None,
            vy_max: None,
            wz_max: None,
            ax_max: None,
            kappa_max: None,
            wz_accel_max: None,
            radius: None,
            seed: 0,
            goal_weight: 5.0,
            prefer_forward_weight: 5.0,
            prefer_forward_threshold: 0.5,
            collision_cost: 10_000.0,
            collision_margin_distance: 0.1,
            critical_weight: 20.0,
            repulsion_weight: 1.5,
            inflation_radius: 0.55,
            near_goal_distance: 0.5,
            pedestrian_weight: 1.0,
            pedestrian_inflation_radius: 0.55,
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

fn count(key: &str, v: usize, max: usize) -> Result<(), InitError> {
    if (1..=max).contains(&v) {
        Ok(())
    } else {
        Err(InitError::invalid(
            key,
            format!("must be positive and at most {max}, got {v}"),
        ))
    }
}

impl MppiConfig {
    /// The limits the configuration sets in place of the robot's.
    pub fn overrides(&self) -> LimitOverrides {
        LimitOverrides {
            vx_max: self.vx_max,
            vx_min: self.vx_min,
            vy_max: self.vy_max,
            wz_max: self.wz_max,
            ax_max: self.ax_max,
            kappa_max: self.kappa_max,
        }
    }

    /// The noise standard deviations `[v_x, v_y, ω]` for these bounds: the configured ones,
    /// else Nav2's ratios to the speed limits.
    pub fn noise_std(&self, bounds: &crate::kinematics::Bounds) -> [f64; 3] {
        [
            self.vx_std
                .unwrap_or(NAV2_VX_STD_RATIO * bounds.vx_max.max(-bounds.vx_min)),
            self.vy_std.unwrap_or(NAV2_VX_STD_RATIO * bounds.vy_max),
            self.wz_std.unwrap_or(NAV2_WZ_STD_RATIO * bounds.wz_max),
        ]
    }

    /// Checks every value; the error names the first offending key.
    pub fn validate(&self) -> Result<(), InitError> {
        count("batch_size", self.batch_size, MAX_BATCH_SIZE)?;
        count("time_steps", self.time_steps, MAX_TIME_STEPS)?;
        count("iteration_count", self.iteration_count, MAX_ITERATIONS)?;
        if self.batch_size * self.time_steps > MAX_SAMPLED_CONTROLS {
            return Err(InitError::invalid(
                "batch_size",
                format!(
                    "batch_size × time_steps must be at most {MAX_SAMPLED_CONTROLS}, got {} × {}",
                    self.batch_size, self.time_steps
                ),
            ));
        }
        finite("model_dt", self.model_dt, self.model_dt > 0.0, "> 0")?;
        finite(
            "temperature",
            self.temperature,
            self.temperature > 0.0,
            "> 0",
        )?;
        finite("gamma", self.gamma, self.gamma >= 0.0, ">= 0")?;
        for (key, v) in [
            ("vx_std", self.vx_std),
            ("vy_std", self.vy_std),
            ("wz_std", self.wz_std),
        ] {
            if let Some(v) = v {
                finite(key, v, v >= 0.0, ">= 0")?;
            }
        }
        self.overrides().validate()?;
        if let Some(a) = self.wz_accel_max {
            finite("wz_accel_max", a, a > 0.0, "> 0")?;
        }
        if let Some(r) = self.radius {
            finite("radius", r, r > 0.0, "> 0")?;
        }
        for (key, v) in [
            ("goal_weight", self.goal_weight),
            ("prefer_forward_weight", self.prefer_forward_weight),
            ("prefer_forward_threshold", self.prefer_forward_threshold),
            ("collision_cost", self.collision_cost),
            ("collision_margin_distance", self.collision_margin_distance),
            ("critical_weight", self.critical_weight),
            ("repulsion_weight", self.repulsion_weight),
            ("inflation_radius", self.inflation_radius),
            ("near_goal_distance", self.near_goal_distance),
            ("pedestrian_weight", self.pedestrian_weight),
            (
                "pedestrian_inflation_radius",
                self.pedestrian_inflation_radius,
            ),
        ] {
            finite(key, v, v >= 0.0, ">= 0")?;
        }
        Ok(())
    }
}
