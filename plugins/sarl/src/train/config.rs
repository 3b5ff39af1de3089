//! The training settings: [`TrainConfig`] and its sections.

use super::MAX_THREADS;
use crate::env::EnvConfig;
use crate::error::SarlError;
use crate::net::NetConfig;
use crate::policy::LookAhead;
use human2nav_core::input::{MAX_CONFIG_BYTES, read_user_file};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// Optimisation settings shared by both stages.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct OptimConfig {
    /// Discount γ per unit of `Δt·v_pref`. Default 0.9.
    pub gamma: f64,
    /// Minibatch size. Default 100.
    pub batch_size: usize,
    /// SGD momentum. Default 0.9.
    pub momentum: f64,
    /// Replay memory capacity (states). Default 100,000.
    pub capacity: usize,
}

impl Default for OptimConfig {
    fn default() -> Self {
        Self {
            gamma: 0.9,
            batch_size: 100,
            momentum: 0.9,
            capacity: 100_000,
        }
    }
}

/// Imitation stage.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct IlConfig {
    /// ORCA demonstrations. Default 5,000 (the paper's count).
    pub episodes: usize,
    /// Passes over the memory. Default 50.
    pub epochs: usize,
    /// Learning rate. Default 0.01.
    pub learning_rate: f64,
    /// Added to the demonstrator's radius (m). Default 0.15.
    pub safety_space: f64,
}

impl Default for IlConfig {
    fn default() -> Self {
        Self {
            episodes: 5000,
            epochs: 50,
            learning_rate: 0.01,
            safety_space: 0.15,
        }
    }
}

/// TD-learning stage.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RlConfig {
    /// Training episodes. Default 20,000 (the paper's count).
    pub episodes: usize,
    /// Learning rate. Default 0.001.
    pub learning_rate: f64,
    /// Minibatch updates after each episode. Default 100 (CrowdNav `train_batches`).
    pub batches_per_episode: usize,
    /// ε at the first episode. Default 0.5.
    pub epsilon_start: f64,
    /// ε after the decay. Default 0.1.
    pub epsilon_end: f64,
    /// Episodes over which ε decays linearly. Default 4,000.
    pub epsilon_decay_episodes: usize,
    /// Episodes between target-network updates. Default 50.
    pub target_update_every: usize,
}

impl Default for RlConfig {
    fn default() -> Self {
        Self {
            episodes: 20_000,
            learning_rate: 0.001,
            batches_per_episode: 100,
            epsilon_start: 0.5,
            epsilon_end: 0.1,
            epsilon_decay_episodes: 4000,
            target_update_every: 50,
        }
    }
}

impl RlConfig {
    /// ε at episode `e` (0-based).
    pub fn epsilon(&self, e: usize) -> f64 {
        if e >= self.epsilon_decay_episodes {
            self.epsilon_end
        } else {
            self.epsilon_start
                + (self.epsilon_end - self.epsilon_start) * e as f64
                    / self.epsilon_decay_episodes as f64
        }
    }
}

/// Bookkeeping of a run.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RunConfig {
    /// Model name in the card. Default `sarl`.
    pub name: String,
    /// Checkpoints and logs; relative paths start at the workspace root. Default `out/sarl`.
    pub out_dir: PathBuf,
    /// Where the trained model is exported. Default `models/sarl`.
    pub model_dir: PathBuf,
    /// RL episodes between checkpoints. Default 250.
    pub checkpoint_every: usize,
    /// RL episodes between validation runs. Default 500.
    pub eval_every: usize,
    /// Greedy validation episodes per run. Default 100.
    pub eval_episodes: usize,
    /// Held-out test episodes evaluated at the end (model card). Default 500.
    pub test_episodes: usize,
    /// Why the counts differ from the paper's (copied into the model card).
    pub notes: String,
}

impl Default for RunConfig {
    fn default() -> Self {
        Self {
            name: "sarl".into(),
            out_dir: PathBuf::from("out/sarl"),
            model_dir: PathBuf::from("models/sarl"),
            checkpoint_every: 250,
            eval_every: 500,
            eval_episodes: 100,
            test_episodes: 500,
            notes: String::new(),
        }
    }
}

/// The whole training configuration (`sdk/configs/sarl.toml`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TrainConfig {
    /// Master seed. Default 7.
    pub seed: u64,
    /// libtorch intra-op threads. Default 1.
    pub threads: usize,
    pub env: EnvConfig,
    pub net: NetConfig,
    pub optim: OptimConfig,
    pub il: IlConfig,
    pub rl: RlConfig,
    pub run: RunConfig,
}

impl Default for TrainConfig {
    fn default() -> Self {
        Self {
            seed: 7,
            threads: 1,
            env: EnvConfig::default(),
            net: NetConfig::default(),
            optim: OptimConfig::default(),
            il: IlConfig::default(),
            rl: RlConfig::default(),
            run: RunConfig::default(),
        }
    }
}

impl TrainConfig {
    /// Reads and validates a configuration file.
    pub fn load(path: &Path) -> Result<Self, SarlError> {
        let text = read_user_file(path, "SARL training configuration", MAX_CONFIG_BYTES)
            .map_err(|e| SarlError::io(path, e))?;
        let cfg: TrainConfig = toml::from_str(&text).map_err(|e| SarlError::Parse {
            path: path.to_path_buf(),
            message: e.to_string(),
        })?;
        cfg.validate()?;
        Ok(cfg)
    }

    /// Checks every section; names the first offending field.
    pub fn validate(&self) -> Result<(), SarlError> {
        self.env.validate()?;
        self.net.validate()?;
        if !(1..=MAX_THREADS).contains(&self.threads) {
            return Err(SarlError::config(
                "threads",
                format!("{} is not in 1..={MAX_THREADS}", self.threads),
            ));
        }
        let o = &self.optim;
        if !(o.gamma > 0.0 && o.gamma <= 1.0) {
            return Err(SarlError::config(
                "optim.gamma",
                format!("must lie in (0, 1], got {}", o.gamma),
            ));
        }
        if o.batch_size == 0 || o.capacity < o.batch_size {
            return Err(SarlError::config(
                "optim.capacity",
                "batch_size must be ≥ 1 and capacity ≥ batch_size",
            ));
        }
        if !(0.0..1.0).contains(&o.momentum) {
            return Err(SarlError::config(
                "optim.momentum",
                format!("must lie in [0, 1), got {}", o.momentum),
            ));
        }
        for (field, lr) in [
            ("il.learning_rate", self.il.learning_rate),
            ("rl.learning_rate", self.rl.learning_rate),
        ] {
            if !(lr.is_finite() && lr > 0.0) {
                return Err(SarlError::config(
                    field,
                    format!("must be finite and > 0, got {lr}"),
                ));
            }
        }
        if !(self.il.safety_space.is_finite() && self.il.safety_space >= 0.0) {
            return Err(SarlError::config(
                "il.safety_space",
                "must be finite and ≥ 0",
            ));
        }
        if self.il.episodes == 0 && self.il.epochs > 0 {
            return Err(SarlError::config(
                "il.episodes",
                "imitation epochs need demonstrations",
            ));
        }
        let r = &self.rl;
        for (field, e) in [
            ("rl.epsilon_start", r.epsilon_start),
            ("rl.epsilon_end", r.epsilon_end),
        ] {
            if !(0.0..=1.0).contains(&e) {
                return Err(SarlError::config(
                    field,
                    format!("must lie in [0, 1], got {e}"),
                ));
            }
        }
        if r.target_update_every == 0 {
            return Err(SarlError::config("rl.target_update_every", "must be ≥ 1"));
        }
        if self.run.checkpoint_every == 0 || self.run.eval_every == 0 {
            return Err(SarlError::config(
                "run.checkpoint_every",
                "checkpoint_every and eval_every must be ≥ 1",
            ));
        }
        Ok(())
    }

    /// The look-ahead implied by the settings.
    pub fn lookahead(&self) -> LookAhead {
        LookAhead {
            gamma: self.optim.gamma,
            time_step: self.env.time_step,
            reward: self.env.reward(),
        }
    }

    /// `γ̄ = γ^{Δt·v_pref}`.
    pub fn gamma_bar(&self) -> f64 {
        self.lookahead().gamma_bar(self.env.robot_v_pref)
    }

    /// The settings a checkpoint must agree with to be resumed (everything but `run` and the
    /// number of RL episodes).
    pub(super) fn resume_key(&self) -> Result<String, SarlError> {
        let mut c = self.clone();
        c.run = RunConfig::default();
        c.rl.episodes = 0;
        toml::to_string(&c).map_err(|e| SarlError::config("config", e.to_string()))
    }
}
