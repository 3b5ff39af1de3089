//! SARL's two training stages (CrowdNav `train.py` with `sarl` and `train.config`):
//!
//! 1. **Imitation.** `il.episodes` circle-crossing episodes with ORCA controlling the robot
//!    (its radius enlarged by `il.safety_space`, as CrowdNav does); every state of an episode
//!    that ended in success or collision enters the replay memory with its discounted return
//!    `Σ_{t≥i} γ̄^{t−i} r_t` as the value target, `γ̄ = γ^{Δt·v_pref}`. Then `il.epochs`
//!    passes over the memory in shuffled minibatches (MSE, SGD with momentum).
//! 2. **TD learning.** `rl.episodes` episodes of the SARL look-ahead policy with ε-greedy
//!    exploration (ε falls linearly from `epsilon_start` to `epsilon_end` over
//!    `epsilon_decay_episodes`, then stays). After each episode that did not time out its
//!    states enter the memory with targets `r_i + γ̄·V_target(s_{i+1})` (the last state: its
//!    reward), computed once with the target network; then `batches_per_episode` random
//!    minibatches update the value network. The target network copies it every
//!    `target_update_every` episodes.
//!
//! The replay memory is a ring buffer of `capacity` states. Every episode draws its layout and
//! exploration from its own RNG ([`episode_rng`](crate::eval::episode_rng)), and minibatches
//! from an RNG of the episode or epoch index, so a run is deterministic given the seed (with
//! one libtorch thread) and a resumed run continues exactly: a checkpoint holds the network, the target network, the
//! momentum buffers, the memory and the progress (`progress.toml`).
//!
//! A checkpoint is one set (`human2nav_core::fileset`): its five files go into
//! `checkpoint.partial/`, `manifest.toml` (size and checksum of each) last, then the folder
//! replaces `checkpoint/`. [`Trainer::resume`] continues from the newest complete set and
//! refuses a partial one, naming the missing or altered file; it never starts over silently.
//!
//! The files: [`TrainConfig`] and its sections (`config.rs`), the replay [`Memory`]
//! (`memory.rs`), the two stages (`stages.rs`), checkpoints and resume (`checkpoint.rs`), and
//! the export of a trained model with its card (`export.rs`).

use crate::action::ActionSpace;
use crate::error::SarlError;
use crate::net::SarlNet;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::PathBuf;
use tch::{Device, Tensor};

mod checkpoint;
mod config;
mod export;
mod memory;
mod stages;
#[cfg(test)]
mod tests;

pub use config::{IlConfig, OptimConfig, RlConfig, RunConfig, TrainConfig};
pub use memory::Memory;

/// One point of the training log.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LogPoint {
    /// Imitation epoch (1-based) or RL episode count at the end of the block.
    pub step: usize,
    /// Mean minibatch MSE of the epoch or block.
    pub loss: f64,
    /// Training success rate over the block (RL only; exploration included).
    pub success_rate: f64,
}

/// One validation run.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ValPoint {
    /// RL episodes done when it ran (0: right after imitation).
    pub episode: usize,
    pub success_rate: f64,
    pub collision_rate: f64,
    pub timeout_rate: f64,
}

/// How far a run got (`progress.toml` in a checkpoint).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Progress {
    /// The settings the run was started with (see `TrainConfig::resume_key`).
    pub config_key: String,
    pub demos_done: bool,
    pub demo_transitions: usize,
    pub il_epochs_done: usize,
    pub rl_episodes_done: usize,
    pub memory_next: usize,
    pub il_log: Vec<LogPoint>,
    pub rl_log: Vec<LogPoint>,
    pub validation: Vec<ValPoint>,
    /// Wall time spent so far, over every invocation (s).
    pub wall_seconds: f64,
}

/// What a trainer reports while it runs (the CLI draws progress bars from these).
pub trait Observer {
    /// A stage starts (or resumes at `done` of `total` units).
    fn stage(&mut self, name: &str, total: u64, done: u64);
    /// `done` units of the current stage are finished; `message` summarises the state.
    fn tick(&mut self, done: u64, message: &str);
    /// A line worth keeping (validation results, checkpoints).
    fn note(&mut self, line: &str);
}

/// An observer that ignores everything (tests).
#[derive(Debug, Default)]
pub struct Silent;

impl Observer for Silent {
    fn stage(&mut self, _: &str, _: u64, _: u64) {}
    fn tick(&mut self, _: u64, _: &str) {}
    fn note(&mut self, _: &str) {}
}

/// Largest `threads` accepted: libtorch starts that many intra-op threads, each with its own
/// stack (`threads = 100000` overflowed before this bound); the flow trainer has the same.
pub const MAX_THREADS: usize = 256;

/// The two-stage SARL trainer.
#[derive(Debug)]
pub struct Trainer {
    cfg: TrainConfig,
    out_dir: PathBuf,
    model: SarlNet,
    target: SarlNet,
    /// Momentum buffers by variable name.
    momentum: BTreeMap<String, Tensor>,
    memory: Memory,
    actions: ActionSpace,
    progress: Progress,
}

impl Trainer {
    /// A fresh run writing its checkpoints under `out_dir` (already resolved). Sets libtorch's
    /// thread count; the initial weights depend on the seed alone ([`SarlNet::seeded`]).
    pub fn new(cfg: TrainConfig, out_dir: PathBuf) -> Result<Self, SarlError> {
        cfg.validate()?;
        tch::set_num_threads(cfg.threads as i32);
        let model = SarlNet::seeded(&cfg.net, cfg.seed, Device::Cpu)?;
        let mut target = SarlNet::new(&cfg.net, Device::Cpu)?;
        target.copy_from(&model)?;
        let momentum = model
            .var_store()
            .variables()
            .into_iter()
            .map(|(k, v)| (k, v.zeros_like()))
            .collect();
        let memory = Memory::new(cfg.optim.capacity, cfg.env.human_num);
        let actions = ActionSpace::crowdnav(cfg.env.robot_v_pref);
        let progress = Progress {
            config_key: cfg.resume_key()?,
            ..Progress::default()
        };
        Ok(Self {
            cfg,
            out_dir,
            model,
            target,
            momentum,
            memory,
            actions,
            progress,
        })
    }

    /// The value network.
    pub fn model(&self) -> &SarlNet {
        &self.model
    }

    /// The progress so far.
    pub fn progress(&self) -> &Progress {
        &self.progress
    }

    /// The replay memory.
    pub fn memory(&self) -> &Memory {
        &self.memory
    }

    /// The settings.
    pub fn config(&self) -> &TrainConfig {
        &self.cfg
    }
}
