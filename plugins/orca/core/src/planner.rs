//! ORCA as a [`Planner`]: the robot is one ORCA agent among the observed pedestrians.
//!
//! * The robot's own velocity is its current world-frame velocity (the body twist of the
//!   observation rotated by its heading); pedestrians contribute their observed position,
//!   velocity and radius; the observation's static obstacles contribute RVO2 obstacle lines
//!   ([`crate::obstacle`]; its occupancy grid is ignored).
//! * The preferred velocity points at the goal with speed `min(pref_speed, d / arrival_time)`,
//!   `d` the distance to the goal (RVO2's examples use the goal vector clipped to unit length,
//!   which is this rule with `pref_speed = 1 m/s`, `arrival_time = 1 s`).
//! * Holonomic → embodiment conversion: the chosen velocity `v` becomes a constant-velocity
//!   plan `poses[k] = (p + k·dt·v, atan2(v))` for `k ≥ 1`, `poses[0]` the current pose. The
//!   embodiment's tracking controller then follows this plan like any other, so a differential
//!   drive turns toward `v`, an Ackermann robot turns within its curvature limit and an
//!   omnidirectional robot can move along `v` directly. Below `min_heading_speed` the plan keeps
//!   the current heading (no spinning on the spot to face a zero velocity).

use crate::lp::Vec2;
use crate::obstacle::Obstacles;
use crate::orca::{Neighbor, OrcaParams, compute_new_velocity_with_obstacles};
use human2nav_core::{Observation, Plan, PlanError, PlanInfo, Planner, Pose2};
use human2nav_plugin::{InitError, PluginInit};
use serde::{Deserialize, Serialize};

/// Why an ORCA configuration was rejected.
#[derive(Debug, thiserror::Error)]
pub enum OrcaError {
    #[error("invalid ORCA configuration: field `{field}` {message}")]
    Config {
        field: &'static str,
        message: String,
    },
    #[error("cannot parse ORCA configuration TOML: {0}")]
    Parse(#[from] toml::de::Error),
}

/// ORCA settings (RVO2 names). Every field has a documented default.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct OrcaConfig {
    /// The robot's disc radius `r` (m). Default 0.3; the benchmark sets the robot's footprint
    /// radius.
    pub radius: f64,
    /// Extra clearance added to `radius` (m). Default 0.0 (plain RVO2).
    pub safety_margin: f64,
    /// Largest speed ORCA may choose (m/s). Default 1.0; the benchmark sets the robot's `v_max`.
    pub max_speed: f64,
    /// Preferred cruising speed toward the goal (m/s); `None` means `max_speed`.
    pub pref_speed: Option<f64>,
    /// Neighbours beyond this centre distance are ignored (m). Default 10.
    pub neighbor_dist: f64,
    /// At most this many closest neighbours are used. Default 10.
    pub max_neighbors: usize,
    /// Time horizon `τ` of the velocity obstacles (s). Default 5.
    pub time_horizon: f64,
    /// Time horizon of the static obstacles' velocity obstacles (s, RVO2's
    /// `timeHorizonObst`). Default 5.
    pub time_horizon_obst: f64,
    /// Time step for the overlap cut-off (s); the replanning period. Default 0.1.
    pub time_step: f64,
    /// Time constant of the approach: the preferred speed is `min(pref_speed, d / arrival_time)`
    /// (s). Default 1.
    pub arrival_time: f64,
    /// Spacing of the plan's poses (s). Default 0.1 (the dataset step).
    pub plan_dt: f64,
    /// Number of poses in the plan, including `poses[0]`. Default 32 (3.2 s as in the paper).
    pub horizon: usize,
    /// Below this speed (m/s) the plan keeps the current heading. Default 0.05.
    pub min_heading_speed: f64,
}

impl Default for OrcaConfig {
    fn default() -> Self {
        Self {
            radius: 0.3,
            safety_margin: 0.0,
            max_speed: 1.0,
            pref_speed: None,
            neighbor_dist: 10.0,
            max_neighbors: 10,
            time_horizon: 5.0,
            time_horizon_obst: 5.0,
            time_step: 0.1,
            arrival_time: 1.0,
            plan_dt: 0.1,
            horizon: 32,
            min_heading_speed: 0.05,
        }
    }
}

impl OrcaConfig {
    /// Parses a TOML table (the plugin configuration string) and validates it.
    pub fn from_toml_str(s: &str) -> Result<Self, OrcaError> {
        let cfg: OrcaConfig = toml::from_str(s)?;
        cfg.validate()?;
        Ok(cfg)
    }

    /// Checks every field is finite and in range; names the first offending field.
    pub fn validate(&self) -> Result<(), OrcaError> {
        fn positive(field: &'static str, v: f64) -> Result<(), OrcaError> {
            if v.is_finite() && v > 0.0 {
                Ok(())
            } else {
                Err(OrcaError::Config {
                    field,
                    message: format!("must be finite and > 0, got {v}"),
                })
            }
        }
        positive("radius", self.radius)?;
        if !(self.safety_margin.is_finite() && self.safety_margin >= 0.0) {
            return Err(OrcaError::Config {
                field: "safety_margin",
                message: format!("must be finite and ≥ 0, got {}", self.safety_margin),
            });
        }
        positive("max_speed", self.max_speed)?;
        if let Some(p) = self.pref_speed {
            positive("pref_speed", p)?;
        }
        positive("neighbor_dist", self.neighbor_dist)?;
        positive("time_horizon", self.time_horizon)?;
        positive("time_horizon_obst", self.time_horizon_obst)?;
        positive("time_step", self.time_step)?;
        positive("arrival_time", self.arrival_time)?;
        positive("plan_dt", self.plan_dt)?;
        if self.horizon < 2 {
            return Err(OrcaError::Config {
                field: "horizon",
                message: format!("must be ≥ 2, got {}", self.horizon),
            });
        }
        if !(self.min_heading_speed.is_finite() && self.min_heading_speed >= 0.0) {
            return Err(OrcaError::Config {
                field: "min_heading_speed",
                message: format!("must be finite and ≥ 0, got {}", self.min_heading_speed),
            });
        }
        Ok(())
    }

    /// The per-agent ORCA parameters this configuration implies.
    pub fn params(&self) -> OrcaParams {
        OrcaParams {
            neighbor_dist: self.neighbor_dist,
            max_neighbors: self.max_neighbors,
            time_horizon: self.time_horizon,
            time_step: self.time_step,
            radius: self.radius + self.safety_margin,
            max_speed: self.max_speed,
        }
    }

    /// The preferred velocity from `position` toward `goal`.
    pub fn preferred_velocity(&self, position: Vec2, goal: Vec2) -> Vec2 {
        let to_goal = goal - position;
        let d = to_goal.norm();
        if d <= 0.0 {
            return Vec2::ZERO;
        }
        let speed = self
            .pref_speed
            .unwrap_or(self.max_speed)
            .min(self.max_speed)
            .min(d / self.arrival_time);
        to_goal * (speed / d)
    }
}

/// The ORCA planner (name `orca`).
#[derive(Clone, Debug)]
pub struct OrcaPlanner {
    config: OrcaConfig,
}

impl OrcaPlanner {
    /// A planner with a validated configuration.
    pub fn new(config: OrcaConfig) -> Result<Self, OrcaError> {
        config.validate()?;
        Ok(Self { config })
    }

    pub fn config(&self) -> &OrcaConfig {
        &self.config
    }

    /// The ORCA velocity (world frame) for this observation.
    pub fn velocity(&self, obs: &Observation) -> Vec2 {
        let position = Vec2::new(obs.ego.x, obs.ego.y);
        let velocity = Vec2::from_array(obs.ego.rotate([obs.ego_velocity.vx, obs.ego_velocity.vy]));
        let pref = self
            .config
            .preferred_velocity(position, Vec2::from_array(obs.goal));
        let others: Vec<Neighbor> = obs
            .agents
            .iter()
            .map(|a| Neighbor {
                position: Vec2::from_array(a.position),
                velocity: Vec2::from_array(a.velocity),
                radius: a.radius,
            })
            .collect();
        compute_new_velocity_with_obstacles(
            position,
            velocity,
            pref,
            &others,
            &Obstacles::from_observation(&obs.obstacles),
            self.config.time_horizon_obst,
            &self.config.params(),
        )
    }

    /// The constant-velocity rollout of `v` from the observation's pose (see the module docs).
    pub fn rollout(&self, obs: &Observation, v: Vec2) -> Plan {
        let c = &self.config;
        let heading = if v.norm() >= c.min_heading_speed && v.norm() > 0.0 {
            v.y.atan2(v.x)
        } else {
            obs.ego.theta
        };
        let mut poses = Vec::with_capacity(c.horizon);
        poses.push(obs.ego);
        for k in 1..c.horizon {
            let t = k as f64 * c.plan_dt;
            poses.push(Pose2::new(
                obs.ego.x + t * v.x,
                obs.ego.y + t * v.y,
                heading,
            ));
        }
        Plan {
            t0: obs.time,
            dt: c.plan_dt,
            poses,
            info: PlanInfo::default(),
        }
    }
}

impl OrcaPlanner {
    /// The plugin factory. With a robot context, `radius` defaults to the robot's footprint
    /// radius and `max_speed` to its `v_max` (values written in the configuration win).
    pub fn from_init(init: &PluginInit<'_>) -> Result<Self, InitError> {
        let mut cfg: OrcaConfig = init.config()?;
        if let Some(robot) = init.robot() {
            if !init.sets("radius") {
                cfg.radius = robot.footprint_radius;
            }
            if !init.sets("max_speed") {
                cfg.max_speed = robot.limits.v_max;
            }
        }
        Self::new(cfg).map_err(|e| match e {
            OrcaError::Config { field, message } => InitError::invalid(field, message),
            OrcaError::Parse(p) => InitError::Parse {
                message: p.to_string(),
            },
        })
    }
}

impl Planner for OrcaPlanner {
    fn name(&self) -> &str {
        "orca"
    }

    fn plan(&mut self, obs: &Observation) -> Result<Plan, PlanError> {
        obs.validate()?;
        let v = self.velocity(obs);
        if !(v.x.is_finite() && v.y.is_finite()) {
            return Err(PlanError::Failed {
                planner: "orca".into(),
                message: "non-finite velocity".into(),
            });
        }
        Ok(self.rollout(obs, v))
    }
}
