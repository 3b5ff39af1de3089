//! SARL as a [`Planner`] (name `sarl`), and its holonomic → embodiment conversion.
//!
//! * The robot state is built from the observation: position, world-frame velocity (the body
//!   twist rotated by the heading), `radius`, the goal and `v_pref = max_speed`; the humans
//!   are the `max_humans` nearest observed agents (position, velocity, radius). SARL was
//!   trained with `v_pref = 1 m/s` and a 0.3 m robot; a robot with another `v_max` or footprint
//!   gets its own values in the state (CrowdNav's convention), which lies outside the training
//!   distribution — that is the baseline as published, not tuned for our robots.
//! * With no agent in view the network has nothing to attend to; the look-ahead's value is then
//!   known in closed form and so is its best velocity: straight at the goal at
//!   `min(v_pref, d/Δt)` (see [`crate::policy::empty_world_velocity`]).
//! * The action is chosen by the one-step look-ahead of [`crate::policy`] over the 81 holonomic
//!   actions of [`ActionSpace::crowdnav`] with the card's Δt and γ.
//! * Holonomic → embodiment conversion (ORCA's, reused from `human2nav-orca-core`): the chosen
//!   velocity `v` becomes a constant-velocity plan `poses[k] = (p + k·plan_dt·v, atan2(v))` for
//!   `k = 1..horizon−1`, `poses[0]` the current pose; below `min_heading_speed` (and for the
//!   stop action) the plan keeps the current heading. The embodiment's tracking controller then
//!   follows the plan like any other (a differential drive turns toward `v`, an Ackermann robot
//!   turns within its curvature limit).

use crate::action::ActionSpace;
use crate::card::{CARD_FILE, ModelCard, WEIGHTS_FILE};
use crate::error::SarlError;
use crate::net::SarlNet;
use crate::policy::{LookAhead, empty_world_velocity, select_action};
use crate::state::{HumanState, RobotState};
use human2nav_core::{Observation, Plan, PlanError, Planner};
use human2nav_orca_core::lp::Vec2;
use human2nav_orca_core::{OrcaConfig, OrcaPlanner};
use human2nav_plugin::{InitError, PluginInit};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use tch::Device;

/// SARL planner settings. Every field has a documented default.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SarlConfig {
    /// The trained model: a directory with `model.toml` and `model.safetensors` (or the
    /// `.safetensors` file itself, its card beside it). Relative paths are resolved against
    /// the workspace root above the current directory (else the current directory). Default
    /// `models/sarl`.
    pub weights: PathBuf,
    /// The robot's disc radius (m). Default 0.3; the benchmark sets the footprint radius.
    pub radius: f64,
    /// The robot's preferred speed `v_pref`, the fastest action (m/s). Default 1.0; the
    /// benchmark sets the robot's `v_max`.
    pub max_speed: f64,
    /// At most this many nearest agents enter the network. Default 10.
    pub max_humans: usize,
    /// Spacing of the plan's poses (s). Default 0.1.
    pub plan_dt: f64,
    /// Number of poses in the plan, including `poses[0]`. Default 32 (3.2 s).
    pub horizon: usize,
    /// Below this speed (m/s) the plan keeps the current heading. Default 0.05.
    pub min_heading_speed: f64,
}

impl Default for SarlConfig {
    fn default() -> Self {
        Self {
            weights: PathBuf::from("models/sarl"),
            radius: 0.3,
            max_speed: 1.0,
            max_humans: 10,
            plan_dt: 0.1,
            horizon: 32,
            min_heading_speed: 0.05,
        }
    }
}

impl SarlConfig {
    /// Checks every field; names the first offending one.
    pub fn validate(&self) -> Result<(), SarlError> {
        for (field, v) in [
            ("radius", self.radius),
            ("max_speed", self.max_speed),
            ("plan_dt", self.plan_dt),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(SarlError::config(
                    field,
                    format!("must be finite and > 0, got {v}"),
                ));
            }
        }
        if self.max_humans == 0 {
            return Err(SarlError::config("max_humans", "must be ≥ 1"));
        }
        if self.horizon < 2 {
            return Err(SarlError::config(
                "horizon",
                format!("must be ≥ 2, got {}", self.horizon),
            ));
        }
        if !(self.min_heading_speed.is_finite() && self.min_heading_speed >= 0.0) {
            return Err(SarlError::config(
                "min_heading_speed",
                "must be finite and ≥ 0",
            ));
        }
        if self.weights.as_os_str().is_empty() {
            return Err(SarlError::config(
                "weights",
                "must name the model directory",
            ));
        }
        Ok(())
    }

    /// The model directory and weights file `weights` names, resolved (see the field docs).
    pub fn model_paths(&self) -> (PathBuf, PathBuf) {
        let p = if self.weights.is_absolute() {
            self.weights.clone()
        } else {
            let cwd = std::env::current_dir().unwrap_or_else(|_| PathBuf::from("."));
            human2nav_data::paths::find_workspace_root(&cwd)
                .unwrap_or(cwd)
                .join(&self.weights)
        };
        if p.extension().is_some_and(|e| e == "safetensors") {
            let dir = p.parent().map(Path::to_path_buf).unwrap_or_default();
            (dir, p)
        } else {
            let w = p.join(WEIGHTS_FILE);
            (p, w)
        }
    }
}

/// A trained SARL network with its card.
#[derive(Debug)]
pub struct SarlModel {
    pub card: ModelCard,
    pub net: SarlNet,
}

impl SarlModel {
    /// Loads `model.toml` from `dir` and the weights from `weights` (on the CPU).
    pub fn load(dir: &Path, weights: &Path) -> Result<Self, SarlError> {
        let card = ModelCard::load(&dir.join(CARD_FILE))?;
        let mut net = SarlNet::new(&card.net, Device::Cpu)?;
        net.load(weights)?;
        Ok(Self { card, net })
    }

    /// Loads a model directory (`model.toml` + `model.safetensors`).
    pub fn load_dir(dir: &Path) -> Result<Self, SarlError> {
        Self::load(dir, &dir.join(WEIGHTS_FILE))
    }

    /// The look-ahead the model was trained with.
    pub fn lookahead(&self) -> LookAhead {
        LookAhead {
            gamma: self.card.lookahead.gamma,
            time_step: self.card.lookahead.time_step,
            reward: self.card.reward,
        }
    }
}

/// The SARL planner.
#[derive(Debug)]
pub struct SarlPlanner {
    config: SarlConfig,
    model: SarlModel,
    actions: ActionSpace,
    rollout: OrcaPlanner,
}

impl SarlPlanner {
    /// A planner from validated settings and a loaded model.
    pub fn new(config: SarlConfig, model: SarlModel) -> Result<Self, SarlError> {
        config.validate()?;
        // One libtorch intra-op thread (process-wide): the value network is tiny and the
        // benchmark already runs episodes in parallel, and with several threads the BLAS
        // reductions may split differently under load, which changed chosen actions between
        // two runs with the same seed.
        tch::set_num_threads(1);
        let la = &model.card.lookahead;
        let actions =
            ActionSpace::holonomic(config.max_speed, la.speed_samples, la.rotation_samples);
        let rollout = OrcaPlanner::new(OrcaConfig {
            radius: config.radius,
            max_speed: config.max_speed,
            plan_dt: config.plan_dt,
            horizon: config.horizon,
            min_heading_speed: config.min_heading_speed,
            ..OrcaConfig::default()
        })
        .map_err(|e| SarlError::config("plan", e.to_string()))?;
        Ok(Self {
            config,
            model,
            actions,
            rollout,
        })
    }

    /// Loads the model the settings name.
    pub fn from_config(config: SarlConfig) -> Result<Self, SarlError> {
        config.validate()?;
        let (dir, weights) = config.model_paths();
        let model = SarlModel::load(&dir, &weights)?;
        Self::new(config, model)
    }

    /// The settings.
    pub fn config(&self) -> &SarlConfig {
        &self.config
    }

    /// The action space (speeds scaled to `max_speed`).
    pub fn actions(&self) -> &ActionSpace {
        &self.actions
    }

    /// SARL's robot and human states for an observation (see the module docs).
    pub fn states(&self, obs: &Observation) -> (RobotState, Vec<HumanState>) {
        let v = obs.ego.rotate([obs.ego_velocity.vx, obs.ego_velocity.vy]);
        let robot = RobotState {
            px: obs.ego.x,
            py: obs.ego.y,
            vx: v[0],
            vy: v[1],
            radius: self.config.radius,
            gx: obs.goal[0],
            gy: obs.goal[1],
            v_pref: self.config.max_speed,
            theta: obs.ego.theta,
        };
        let mut agents: Vec<(f64, HumanState)> = obs
            .agents
            .iter()
            .map(|a| {
                let d = (a.position[0] - robot.px).hypot(a.position[1] - robot.py);
                (
                    d,
                    HumanState {
                        px: a.position[0],
                        py: a.position[1],
                        vx: a.velocity[0],
                        vy: a.velocity[1],
                        radius: a.radius,
                    },
                )
            })
            .collect();
        agents.sort_by(|a, b| a.0.total_cmp(&b.0));
        let humans: Vec<HumanState> = agents
            .into_iter()
            .take(self.config.max_humans)
            .map(|(_, h)| h)
            .collect();
        (robot, humans)
    }

    /// The velocity SARL chooses (world frame).
    pub fn velocity(&self, obs: &Observation) -> Result<[f64; 2], SarlError> {
        let (robot, humans) = self.states(obs);
        if humans.is_empty() {
            return Ok(empty_world_velocity(&robot, &self.model.lookahead()));
        }
        let d = select_action(
            &self.model.net,
            &self.actions,
            &robot,
            &humans,
            &self.model.lookahead(),
        )?;
        Ok(d.velocity)
    }

    /// The plugin factory. With a robot context, `radius` defaults to the robot's footprint
    /// radius and `max_speed` to its `v_max` (values written in the configuration win).
    pub fn from_init(init: &PluginInit<'_>) -> Result<Self, InitError> {
        let mut cfg: SarlConfig = init.config()?;
        if let Some(robot) = init.robot() {
            if !init.sets("radius") {
                cfg.radius = robot.footprint_radius;
            }
            if !init.sets("max_speed") {
                cfg.max_speed = robot.limits.v_max;
            }
        }
        Self::from_config(cfg).map_err(|e| match e {
            SarlError::Config { field, message } => InitError::invalid(field, message),
            other => InitError::Failed(other.to_string()),
        })
    }
}

impl Planner for SarlPlanner {
    fn name(&self) -> &str {
        "sarl"
    }

    fn plan(&mut self, obs: &Observation) -> Result<Plan, PlanError> {
        obs.validate()?;
        let v = self.velocity(obs).map_err(|e| PlanError::Failed {
            planner: "sarl".into(),
            message: e.to_string(),
        })?;
        if !(v[0].is_finite() && v[1].is_finite()) {
            return Err(PlanError::Failed {
                planner: "sarl".into(),
                message: "non-finite velocity".into(),
            });
        }
        Ok(self.rollout.rollout(obs, Vec2::from_array(v)))
    }
}
