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
//! exploration from its own RNG ([`episode_rng`]), and minibatches from an RNG of the episode
//! or epoch index, so a run is deterministic given the seed (with one libtorch thread) and a
//! resumed run continues exactly: a checkpoint holds the network, the target network, the
//! momentum buffers, the memory and the progress (`progress.toml`).
//!
//! A checkpoint is one set (`human2nav_core::fileset`): its five files go into
//! `checkpoint.partial/`, `manifest.toml` (size and checksum of each) last, then the folder
//! replaces `checkpoint/`. [`Trainer::resume`] continues from the newest complete set and
//! refuses a partial one, naming the missing or altered file; it never starts over silently.

use crate::action::ActionSpace;
use crate::card::{
    CARD_FILE, CURVE_FILE, EvalCard, LookAheadCard, ModelCard, TrainingCard, WEIGHTS_FILE,
};
use crate::env::{EnvConfig, Outcome};
use crate::error::SarlError;
use crate::eval::{EvalStats, Policy, SeedStream, episode_rng, evaluate, run_episode};
use crate::net::{NetConfig, SarlNet};
use crate::policy::LookAhead;
use crate::state::JOINT_DIM;
use human2nav_core::fileset::{self, SetError};
use human2nav_core::input::{MAX_CONFIG_BYTES, read_user_file};
use rand::seq::SliceRandom;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Instant;
use tch::{Device, Kind, Tensor};

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
    fn resume_key(&self) -> Result<String, SarlError> {
        let mut c = self.clone();
        c.run = RunConfig::default();
        c.rl.episodes = 0;
        toml::to_string(&c).map_err(|e| SarlError::config("config", e.to_string()))
    }
}

/// A ring buffer of (joint states, value target) pairs, all with the same number of humans.
#[derive(Clone, Debug, PartialEq)]
pub struct Memory {
    capacity: usize,
    stride: usize,
    states: Vec<f32>,
    values: Vec<f32>,
    next: usize,
}

impl Memory {
    /// An empty memory for states of `humans` humans.
    pub fn new(capacity: usize, humans: usize) -> Self {
        Self {
            capacity,
            stride: humans * JOINT_DIM,
            states: Vec::new(),
            values: Vec::new(),
            next: 0,
        }
    }

    /// Stored pairs.
    pub fn len(&self) -> usize {
        self.values.len()
    }

    /// True when nothing is stored.
    pub fn is_empty(&self) -> bool {
        self.values.is_empty()
    }

    /// Adds a pair, overwriting the oldest when full.
    pub fn push(&mut self, state: &[f32], value: f32) {
        debug_assert_eq!(state.len(), self.stride);
        if self.values.len() < self.capacity {
            self.states.extend_from_slice(state);
            self.values.push(value);
        } else {
            let i = self.next;
            self.states[i * self.stride..(i + 1) * self.stride].copy_from_slice(state);
            self.values[i] = value;
        }
        self.next = (self.next + 1) % self.capacity;
    }

    /// The batch at `indices`: states `[B, N, 13]` and values `[B, 1]`.
    fn batch(&self, indices: &[usize]) -> (Tensor, Tensor) {
        let mut s = Vec::with_capacity(indices.len() * self.stride);
        let mut v = Vec::with_capacity(indices.len());
        for &i in indices {
            s.extend_from_slice(&self.states[i * self.stride..(i + 1) * self.stride]);
            v.push(self.values[i]);
        }
        let b = indices.len() as i64;
        (
            Tensor::from_slice(&s).reshape([b, (self.stride / JOINT_DIM) as i64, JOINT_DIM as i64]),
            Tensor::from_slice(&v).reshape([b, 1]),
        )
    }
}

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

/// Names of the checkpoint files inside the run directory.
const CKPT_DIR: &str = "checkpoint";
const CKPT_MODEL: &str = "model.safetensors";
const CKPT_TARGET: &str = "target.safetensors";
const CKPT_MOMENTUM: &str = "momentum.safetensors";
const CKPT_MEMORY: &str = "memory.safetensors";
const CKPT_PROGRESS: &str = "progress.toml";
/// Every file of a checkpoint set, all listed in its manifest.
const CKPT_FILES: [&str; 5] = [
    CKPT_MODEL,
    CKPT_TARGET,
    CKPT_MOMENTUM,
    CKPT_MEMORY,
    CKPT_PROGRESS,
];

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

    /// Resumes from the newest complete checkpoint set under `out_dir` (`checkpoint/`, or
    /// `checkpoint.old/` when a save was cut between its renames); `None` when there is no
    /// checkpoint at all. A partial set (a file missing, or not the size and checksum its
    /// manifest records) is an error naming the file.
    pub fn resume(cfg: TrainConfig, out_dir: PathBuf) -> Result<Option<Self>, SarlError> {
        let ckpt = out_dir.join(CKPT_DIR);
        let dir = match fileset::find_complete(&ckpt, &CKPT_FILES) {
            Ok(Some(dir)) => dir,
            Ok(None) => return Ok(None),
            Err(SetError::Incomplete { path, reason }) => {
                return Err(SarlError::Resume {
                    path,
                    message: format!(
                        "{reason}; the checkpoint set is incomplete (restore it, or start \
                         afresh without --resume)"
                    ),
                });
            }
            Err(e) => return Err(e.into()),
        };
        let progress_path = dir.join(CKPT_PROGRESS);
        let mut t = Self::new(cfg, out_dir)?;
        let text = read_user_file(&progress_path, "SARL training progress", MAX_CONFIG_BYTES)
            .map_err(|e| SarlError::io(&progress_path, e))?;
        let progress: Progress = toml::from_str(&text).map_err(|e| SarlError::Parse {
            path: progress_path.clone(),
            message: e.to_string(),
        })?;
        if progress.config_key != t.progress.config_key {
            return Err(SarlError::Resume {
                path: progress_path,
                message: "the checkpoint was written under different settings (only `run` and \
                          `rl.episodes` may change); start afresh without --resume or restore \
                          the old settings"
                    .into(),
            });
        }
        t.model.load(&dir.join(CKPT_MODEL))?;
        t.target.load(&dir.join(CKPT_TARGET))?;
        let named = read_tensors(&dir.join(CKPT_MOMENTUM))?;
        for (k, buf) in t.momentum.iter_mut() {
            let Some(saved) = named.get(k) else {
                return Err(SarlError::Resume {
                    path: dir.join(CKPT_MOMENTUM),
                    message: format!("no momentum buffer `{k}`"),
                });
            };
            *buf = saved.shallow_clone();
        }
        let mem = read_tensors(&dir.join(CKPT_MEMORY))?;
        let (Some(states), Some(values)) = (mem.get("states"), mem.get("values")) else {
            return Err(SarlError::Resume {
                path: dir.join(CKPT_MEMORY),
                message: "needs tensors `states` and `values`".into(),
            });
        };
        t.memory.states = Vec::<f32>::try_from(&states.reshape([-1]))?;
        t.memory.values = Vec::<f32>::try_from(&values.reshape([-1]))?;
        t.memory.next = progress.memory_next;
        if t.memory.states.len() != t.memory.values.len() * t.memory.stride
            || t.memory.values.len() > t.memory.capacity
        {
            return Err(SarlError::Resume {
                path: dir.join(CKPT_MEMORY),
                message: "memory shape does not fit the settings".into(),
            });
        }
        t.progress = progress;
        Ok(Some(t))
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

    /// Runs (or continues) both stages to the end, checkpointing on the way.
    pub fn run(&mut self, obs: &mut dyn Observer) -> Result<(), SarlError> {
        let start = Instant::now();
        let wall0 = self.progress.wall_seconds;
        let clock = || wall0 + start.elapsed().as_secs_f64();
        if !self.progress.demos_done {
            self.generate_demonstrations(obs)?;
            self.progress.wall_seconds = clock();
            obs.note(&format!(
                "demonstrations done (wall {:.0} s)",
                self.progress.wall_seconds
            ));
            self.checkpoint()?;
        }
        if self.progress.il_epochs_done < self.cfg.il.epochs {
            obs.stage(
                "imitation epochs",
                self.cfg.il.epochs as u64,
                self.progress.il_epochs_done as u64,
            );
            while self.progress.il_epochs_done < self.cfg.il.epochs {
                let loss = self.il_epoch(self.progress.il_epochs_done)?;
                self.progress.il_epochs_done += 1;
                let e = self.progress.il_epochs_done;
                self.progress.il_log.push(LogPoint {
                    step: e,
                    loss,
                    success_rate: 0.0,
                });
                obs.tick(e as u64, &format!("loss {loss:.5}"));
                if e % 10 == 0 || e == self.cfg.il.epochs {
                    self.progress.wall_seconds = clock();
                    self.checkpoint()?;
                }
            }
            self.target.copy_from(&self.model)?;
            obs.note(&format!("imitation done (wall {:.0} s)", clock()));
        }
        if self.progress.validation.is_empty() && self.cfg.run.eval_episodes > 0 {
            let s = self.validate(obs)?;
            obs.note(&format!(
                "after imitation: validation success {:.3}, collision {:.3}, timeout {:.3}",
                s.success_rate, s.collision_rate, s.timeout_rate
            ));
        }
        let total = self.cfg.rl.episodes;
        if self.progress.rl_episodes_done < total {
            obs.stage(
                "TD episodes",
                total as u64,
                self.progress.rl_episodes_done as u64,
            );
        }
        let mut block_loss = Vec::new();
        let mut block_outcomes = Vec::new();
        let mut recent: std::collections::VecDeque<bool> = std::collections::VecDeque::new();
        while self.progress.rl_episodes_done < total {
            let e = self.progress.rl_episodes_done;
            let (outcome, loss) = self.rl_episode(e)?;
            block_loss.push(loss);
            block_outcomes.push(outcome);
            recent.push_back(outcome == Outcome::Success);
            if recent.len() > 100 {
                recent.pop_front();
            }
            self.progress.rl_episodes_done += 1;
            let done = self.progress.rl_episodes_done;
            if done % self.cfg.rl.target_update_every == 0 {
                self.target.copy_from(&self.model)?;
            }
            let sr = recent.iter().filter(|s| **s).count() as f64 / recent.len() as f64;
            obs.tick(
                done as u64,
                &format!(
                    "ε {:.2}  train success (last {}) {:.2}  loss {:.5}",
                    self.cfg.rl.epsilon(e),
                    recent.len(),
                    sr,
                    loss
                ),
            );
            if done % self.cfg.run.eval_every == 0 && self.cfg.run.eval_episodes > 0 {
                let s = self.validate(obs)?;
                obs.note(&format!(
                    "episode {done}: validation success {:.3}, collision {:.3}, timeout {:.3}",
                    s.success_rate, s.collision_rate, s.timeout_rate
                ));
            }
            if done % self.cfg.run.checkpoint_every == 0 || done == total {
                let n = block_outcomes.len().max(1) as f64;
                self.progress.rl_log.push(LogPoint {
                    step: done,
                    loss: block_loss.iter().sum::<f64>() / n,
                    success_rate: block_outcomes
                        .iter()
                        .filter(|o| **o == Outcome::Success)
                        .count() as f64
                        / n,
                });
                block_loss.clear();
                block_outcomes.clear();
                self.progress.wall_seconds = clock();
                self.checkpoint()?;
                obs.note(&format!(
                    "episode {done}: checkpoint written (wall {:.0} s)",
                    self.progress.wall_seconds
                ));
            }
        }
        self.progress.wall_seconds = clock();
        Ok(())
    }

    /// Stage 1a: the ORCA demonstrations into the memory.
    fn generate_demonstrations(&mut self, obs: &mut dyn Observer) -> Result<(), SarlError> {
        let n = self.cfg.il.episodes;
        obs.stage("ORCA demonstrations", n as u64, 0);
        let g = self.cfg.gamma_bar();
        let policy = Policy::Orca {
            safety_space: self.cfg.il.safety_space,
        };
        let mut kept = 0usize;
        for d in 0..n {
            let mut rng = episode_rng(self.cfg.seed, SeedStream::Demo, d as u64);
            let ep = run_episode(&self.cfg.env, &policy, &mut rng)?;
            if ep.outcome != Outcome::Timeout {
                let stride = ep.humans * JOINT_DIM;
                let mut ret = 0.0;
                let mut values = vec![0.0; ep.steps()];
                for i in (0..ep.steps()).rev() {
                    ret = ep.rewards[i] + g * ret;
                    values[i] = ret;
                }
                for (i, v) in values.iter().enumerate() {
                    self.memory
                        .push(&ep.states[i * stride..(i + 1) * stride], *v as f32);
                }
                kept += ep.steps();
            }
            if (d + 1) % 50 == 0 || d + 1 == n {
                obs.tick((d + 1) as u64, &format!("{kept} transitions"));
            }
        }
        self.progress.demos_done = true;
        self.progress.demo_transitions = kept;
        obs.note(&format!("{n} ORCA demonstrations: {kept} transitions kept"));
        Ok(())
    }

    /// One imitation epoch over the memory in shuffled minibatches; mean MSE.
    fn il_epoch(&mut self, epoch: usize) -> Result<f64, SarlError> {
        let mut order: Vec<usize> = (0..self.memory.len()).collect();
        let mut rng = ChaCha8Rng::seed_from_u64(self.cfg.seed ^ (0x11 << 48) ^ epoch as u64);
        order.shuffle(&mut rng);
        let lr = self.cfg.il.learning_rate;
        let mut sum = 0.0;
        let mut k = 0usize;
        for chunk in order.chunks(self.cfg.optim.batch_size) {
            sum += self.update(chunk, lr)?;
            k += 1;
        }
        Ok(if k > 0 { sum / k as f64 } else { 0.0 })
    }

    /// One TD episode (exploration, memory update, minibatch updates): its outcome and the
    /// mean minibatch loss.
    fn rl_episode(&mut self, e: usize) -> Result<(Outcome, f64), SarlError> {
        let mut rng = episode_rng(self.cfg.seed, SeedStream::Train, e as u64);
        let policy = Policy::Sarl {
            net: &self.model,
            actions: &self.actions,
            lookahead: self.cfg.lookahead(),
            epsilon: self.cfg.rl.epsilon(e),
        };
        let ep = run_episode(&self.cfg.env, &policy, &mut rng)?;
        if ep.outcome != Outcome::Timeout {
            let stride = ep.humans * JOINT_DIM;
            let steps = ep.steps();
            let next_values = if steps > 1 {
                self.target
                    .values(&ep.states[stride..], steps - 1, ep.humans)?
            } else {
                Vec::new()
            };
            let g = self.cfg.gamma_bar();
            for i in 0..steps {
                let v = if i + 1 == steps {
                    ep.rewards[i]
                } else {
                    ep.rewards[i] + g * f64::from(next_values[i])
                };
                self.memory
                    .push(&ep.states[i * stride..(i + 1) * stride], v as f32);
            }
        }
        let mut sum = 0.0;
        let n = self.cfg.rl.batches_per_episode;
        let len = self.memory.len();
        if len >= self.cfg.optim.batch_size {
            for _ in 0..n {
                let idx: Vec<usize> = (0..self.cfg.optim.batch_size)
                    .map(|_| rng.random_range(0..len))
                    .collect();
                sum += self.update(&idx, self.cfg.rl.learning_rate)?;
            }
        }
        Ok((ep.outcome, if n > 0 { sum / n as f64 } else { 0.0 }))
    }

    /// One SGD-with-momentum step on the memory rows `indices` (PyTorch's rule:
    /// `b ← μ·b + g`, `θ ← θ − lr·b`); the minibatch MSE before the step.
    fn update(&mut self, indices: &[usize], lr: f64) -> Result<f64, SarlError> {
        let (x, y) = self.memory.batch(indices);
        let vars = self.model.var_store().variables();
        for v in vars.values() {
            v.shallow_clone().zero_grad();
        }
        let pred = self.model.forward(&x);
        let loss = pred.mse_loss(&y, tch::Reduction::Mean);
        loss.backward();
        let mu = self.cfg.optim.momentum;
        tch::no_grad(|| {
            for (name, v) in &vars {
                let g = v.grad();
                if let Some(b) = self.momentum.get_mut(name) {
                    *b *= mu;
                    *b += &g;
                    let mut p = v.shallow_clone();
                    p -= &*b * lr;
                }
            }
        });
        Ok(loss.double_value(&[]))
    }

    /// Greedy validation on the validation stream; appends to the log.
    fn validate(&mut self, obs: &mut dyn Observer) -> Result<EvalStats, SarlError> {
        let policy = Policy::Sarl {
            net: &self.model,
            actions: &self.actions,
            lookahead: self.cfg.lookahead(),
            epsilon: 0.0,
        };
        let s = evaluate(
            &self.cfg.env,
            &policy,
            self.cfg.seed,
            SeedStream::Validation,
            self.cfg.run.eval_episodes,
            &mut |_| {},
        )?;
        self.progress.validation.push(ValPoint {
            episode: self.progress.rl_episodes_done,
            success_rate: s.success_rate,
            collision_rate: s.collision_rate,
            timeout_rate: s.timeout_rate,
        });
        let _ = obs;
        Ok(s)
    }

    /// Writes the checkpoint as one set (module docs): a crash at any point leaves a complete
    /// set behind, the new one or the previous one.
    pub fn checkpoint(&mut self) -> Result<(), SarlError> {
        self.progress.memory_next = self.memory.next;
        let step = (self.progress.il_epochs_done + self.progress.rl_episodes_done) as u64;
        let ckpt = self.out_dir.join(CKPT_DIR);
        fileset::commit(&ckpt, &CKPT_FILES, step, |dir| self.write_checkpoint(dir))
    }

    /// Writes the checkpoint's files into `dir` (no manifest).
    fn write_checkpoint(&self, dir: &Path) -> Result<(), SarlError> {
        self.model.save(&dir.join(CKPT_MODEL))?;
        self.target.save(&dir.join(CKPT_TARGET))?;
        let named: Vec<(String, Tensor)> = self
            .momentum
            .iter()
            .map(|(k, v)| (k.clone(), v.shallow_clone()))
            .collect();
        write_tensors(&dir.join(CKPT_MOMENTUM), &named)?;
        let m = &self.memory;
        let rows = m.values.len() as i64;
        let states = Tensor::from_slice(&m.states).reshape([
            rows,
            (m.stride / JOINT_DIM) as i64,
            JOINT_DIM as i64,
        ]);
        let values = Tensor::from_slice(&m.values);
        write_tensors(
            &dir.join(CKPT_MEMORY),
            &[
                ("states".to_string(), states),
                ("values".to_string(), values),
            ],
        )?;
        let path = dir.join(CKPT_PROGRESS);
        let text = toml::to_string(&self.progress).map_err(|e| SarlError::Parse {
            path: path.clone(),
            message: e.to_string(),
        })?;
        let tmp = path.with_extension("toml.tmp");
        std::fs::write(&tmp, text).map_err(|e| SarlError::io(&tmp, e))?;
        std::fs::rename(&tmp, &path).map_err(|e| SarlError::io(&path, e))
    }

    /// Evaluates the trained network on the held-out test stream (and the straight and ORCA
    /// policies on the same episodes), then writes `model.safetensors`, `model.toml` and the
    /// training-curve PNG into `model_dir`.
    pub fn export(
        &self,
        model_dir: &Path,
        progress: &mut dyn FnMut(&str, usize),
    ) -> Result<ModelCard, SarlError> {
        std::fs::create_dir_all(model_dir).map_err(|e| SarlError::io(model_dir, e))?;
        let n = self.cfg.run.test_episodes;
        let env = &self.cfg.env;
        let seed = self.cfg.seed;
        let sarl = Policy::Sarl {
            net: &self.model,
            actions: &self.actions,
            lookahead: self.cfg.lookahead(),
            epsilon: 0.0,
        };
        let s = evaluate(env, &sarl, seed, SeedStream::Test, n, &mut |i| {
            progress("sarl", i)
        })?;
        let st = evaluate(
            env,
            &Policy::Straight,
            seed,
            SeedStream::Test,
            n,
            &mut |i| progress("straight", i),
        )?;
        let orca = Policy::Orca {
            safety_space: self.cfg.il.safety_space,
        };
        let o = evaluate(env, &orca, seed, SeedStream::Test, n, &mut |i| {
            progress("orca", i)
        })?;
        self.model.save(&model_dir.join(WEIGHTS_FILE))?;
        let c = &self.cfg;
        let card = ModelCard {
            format_version: 1,
            name: c.run.name.clone(),
            description: "SARL value network (Chen et al. 2019, CrowdNav defaults): pairwise \
                          human-robot embedding mlp1, feature mlp2, attention over [e_i, mean e] \
                          with softmax pooling, value head mlp3 on [self state, pooled feature]; \
                          holonomic one-step look-ahead over 81 actions. Trained by imitation of \
                          ORCA, then TD learning in circle crossing."
                .into(),
            weights: WEIGHTS_FILE.into(),
            parameters: c.net.parameter_count(),
            net: c.net.clone(),
            lookahead: LookAheadCard {
                gamma: c.optim.gamma,
                time_step: c.env.time_step,
                speed_samples: crate::action::SPEED_SAMPLES,
                rotation_samples: crate::action::ROTATION_SAMPLES,
                v_pref: c.env.robot_v_pref,
            },
            reward: c.env.reward(),
            env: c.env.clone(),
            training: TrainingCard {
                seed: c.seed,
                threads: c.threads,
                il_episodes: c.il.episodes,
                il_transitions: self.progress.demo_transitions,
                il_epochs: c.il.epochs,
                il_learning_rate: c.il.learning_rate,
                rl_episodes: self.progress.rl_episodes_done,
                rl_learning_rate: c.rl.learning_rate,
                batches_per_episode: c.rl.batches_per_episode,
                batch_size: c.optim.batch_size,
                momentum: c.optim.momentum,
                capacity: c.optim.capacity,
                epsilon: format!(
                    "{} → {} linearly over {} episodes",
                    c.rl.epsilon_start, c.rl.epsilon_end, c.rl.epsilon_decay_episodes
                ),
                target_update_every: c.rl.target_update_every,
                wall_seconds: self.progress.wall_seconds,
                notes: c.run.notes.clone(),
            },
            evaluation: EvalCard {
                episodes: n,
                seeds: format!("held-out test stream of seed {seed}, episodes 0..{n}"),
                success_rate: s.success_rate,
                collision_rate: s.collision_rate,
                timeout_rate: s.timeout_rate,
                mean_success_time: s.mean_success_time,
                straight_success_rate: st.success_rate,
                straight_collision_rate: st.collision_rate,
                orca_success_rate: o.success_rate,
                orca_collision_rate: o.collision_rate,
            },
        };
        card.save(&model_dir.join(CARD_FILE))?;
        crate::plot::training_curve(&self.progress, &model_dir.join(CURVE_FILE))?;
        Ok(card)
    }
}

/// Reads every tensor of a safetensors file by name.
fn read_tensors(path: &Path) -> Result<BTreeMap<String, Tensor>, SarlError> {
    if !path.is_file() {
        return Err(SarlError::Resume {
            path: path.to_path_buf(),
            message: "file missing".into(),
        });
    }
    let list = Tensor::read_safetensors(path).map_err(|e| SarlError::Weights {
        path: path.to_path_buf(),
        message: e.to_string(),
    })?;
    Ok(list.into_iter().collect())
}

/// Writes named tensors as safetensors (temporary file, then rename).
fn write_tensors(path: &Path, tensors: &[(String, Tensor)]) -> Result<(), SarlError> {
    let tmp = path.with_extension("tmp.safetensors");
    let contiguous: Vec<(String, Tensor)> = tensors
        .iter()
        .map(|(k, t)| (k.clone(), t.to_kind(Kind::Float).contiguous()))
        .collect();
    Tensor::write_safetensors(&contiguous, &tmp).map_err(|e| SarlError::Weights {
        path: tmp.clone(),
        message: e.to_string(),
    })?;
    std::fs::rename(&tmp, path).map_err(|e| SarlError::io(path, e))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn small(dir: &str) -> (TrainConfig, PathBuf) {
        let mut c = TrainConfig::default();
        c.il.episodes = 30;
        c.il.epochs = 4;
        c.rl.episodes = 6;
        c.rl.batches_per_episode = 3;
        c.rl.target_update_every = 2;
        c.run.checkpoint_every = 3;
        c.run.eval_every = 3;
        c.run.eval_episodes = 2;
        let out = std::env::temp_dir().join(format!("human2nav-sarl-{dir}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&out);
        (c, out)
    }

    fn weights(t: &Trainer) -> Vec<(String, Vec<f32>)> {
        let mut v: Vec<(String, Vec<f32>)> = t
            .model
            .var_store()
            .variables()
            .into_iter()
            .map(|(k, x)| (k, Vec::<f32>::try_from(&x.reshape([-1])).unwrap()))
            .collect();
        v.sort_by(|a, b| a.0.cmp(&b.0));
        v
    }

    #[test]
    fn imitation_lowers_the_value_loss() {
        let (cfg, out) = small("il");
        let mut t = Trainer::new(cfg, out.clone()).unwrap();
        t.run(&mut Silent).unwrap();
        let log = &t.progress().il_log;
        assert_eq!(log.len(), 4);
        let (first, last) = (log[0].loss, log[3].loss);
        assert!(first.is_finite() && last.is_finite());
        assert!(last < 0.8 * first, "imitation loss {first} → {last}");
        // The demonstrations that did not time out, then the TD episodes, filled the memory.
        assert!(t.progress().demo_transitions > 0);
        assert!(t.memory().len() > t.progress().demo_transitions);
        // The TD stage ran and logged at every checkpoint.
        assert_eq!(t.progress().rl_episodes_done, 6);
        assert_eq!(t.progress().rl_log.len(), 2);
        assert!(t.progress().rl_log.iter().all(|p| p.loss.is_finite()));
        // Validation after imitation and at episodes 3 and 6.
        assert_eq!(
            t.progress()
                .validation
                .iter()
                .map(|v| v.episode)
                .collect::<Vec<_>>(),
            vec![0, 3, 6]
        );
        let _ = std::fs::remove_dir_all(&out);
    }

    #[test]
    fn runs_are_deterministic_and_resume_exactly() {
        let (cfg, out_a) = small("det-a");
        let mut a = Trainer::new(cfg.clone(), out_a.clone()).unwrap();
        a.run(&mut Silent).unwrap();

        // The same run interrupted after three TD episodes (a checkpoint), then resumed.
        let (_, out_b) = small("det-b");
        let mut first = cfg.clone();
        first.rl.episodes = 3;
        let mut b = Trainer::new(first, out_b.clone()).unwrap();
        b.run(&mut Silent).unwrap();
        drop(b);
        let mut b = Trainer::resume(cfg.clone(), out_b.clone())
            .unwrap()
            .unwrap();
        assert_eq!(b.progress().rl_episodes_done, 3);
        b.run(&mut Silent).unwrap();

        assert_eq!(a.progress().il_log, b.progress().il_log);
        assert_eq!(a.progress().rl_log, b.progress().rl_log);
        assert_eq!(a.progress().validation, b.progress().validation);
        assert_eq!(a.memory(), b.memory());
        assert_eq!(weights(&a), weights(&b));
        let _ = std::fs::remove_dir_all(&out_a);
        let _ = std::fs::remove_dir_all(&out_b);
    }

    #[test]
    fn resume_refuses_other_settings() {
        let (cfg, out) = small("refuse");
        let mut c = cfg.clone();
        c.rl.episodes = 0;
        c.run.eval_episodes = 0;
        let mut t = Trainer::new(c.clone(), out.clone()).unwrap();
        t.run(&mut Silent).unwrap();
        let mut other = c.clone();
        other.optim.gamma = 0.8;
        let err = Trainer::resume(other, out.clone()).unwrap_err();
        assert!(matches!(err, SarlError::Resume { .. }), "{err}");
        // No checkpoint: nothing to resume.
        assert!(Trainer::resume(c, out.join("nowhere")).unwrap().is_none());
        let _ = std::fs::remove_dir_all(&out);
    }

    /// A run stopped after imitation (no TD episodes): its checkpoint is a complete set.
    fn stopped_run(name: &str) -> (TrainConfig, PathBuf) {
        let (mut c, out) = small(name);
        c.rl.episodes = 0;
        c.run.eval_episodes = 0;
        Trainer::new(c.clone(), out.clone())
            .unwrap()
            .run(&mut Silent)
            .unwrap();
        (c, out)
    }

    #[test]
    fn checkpoints_are_sets_with_a_manifest() {
        let (c, out) = stopped_run("set");
        let ckpt = out.join(CKPT_DIR);
        let manifest = std::fs::read_to_string(ckpt.join(fileset::MANIFEST_FILE)).unwrap();
        for f in CKPT_FILES {
            assert!(manifest.contains(&format!("[files.\"{f}\"]")), "{manifest}");
        }
        assert!(!fileset::sibling(&ckpt, "partial").exists());
        let t = Trainer::resume(c.clone(), out.clone()).unwrap().unwrap();
        assert_eq!(t.progress().il_epochs_done, 4);
        // Killed between the two renames of a later save: `checkpoint.old` is the last complete
        // set, and the half-filled `checkpoint` beside it is ignored.
        let old = fileset::sibling(&ckpt, "old");
        std::fs::rename(&ckpt, &old).unwrap();
        std::fs::create_dir_all(&ckpt).unwrap();
        std::fs::copy(old.join(CKPT_MODEL), ckpt.join(CKPT_MODEL)).unwrap();
        let t = Trainer::resume(c, out.clone()).unwrap().unwrap();
        assert_eq!(t.progress().il_epochs_done, 4);
        let _ = std::fs::remove_dir_all(&out);
    }

    #[test]
    fn a_partial_checkpoint_is_refused_naming_the_file() {
        let (c, out) = stopped_run("partial");
        let ckpt = out.join(CKPT_DIR);
        // The progress file gone: this resumed as "no checkpoint" (a silent restart) before.
        std::fs::remove_file(ckpt.join(CKPT_PROGRESS)).unwrap();
        let err = Trainer::resume(c.clone(), out.clone()).unwrap_err();
        assert!(
            matches!(&err, SarlError::Resume { .. })
                && err.to_string().contains("progress.toml is missing")
                && err.to_string().contains("without --resume"),
            "{err}"
        );
        // An altered memory file: named with its size and the manifest's.
        let (c2, out2) = stopped_run("altered");
        let mem = out2.join(CKPT_DIR).join(CKPT_MEMORY);
        let mut bytes = std::fs::read(&mem).unwrap();
        bytes.truncate(bytes.len() / 2);
        std::fs::write(&mem, &bytes).unwrap();
        let err = Trainer::resume(c2, out2.clone()).unwrap_err().to_string();
        assert!(
            err.contains("memory.safetensors has") && err.contains("the manifest says"),
            "{err}"
        );
        // Without a manifest, the files of an older checkpoint: missing ones are named too.
        std::fs::remove_file(ckpt.join(fileset::MANIFEST_FILE)).unwrap();
        let err = Trainer::resume(c, out.clone()).unwrap_err().to_string();
        assert!(err.contains("progress.toml is missing"), "{err}");
        let _ = std::fs::remove_dir_all(&out);
        let _ = std::fs::remove_dir_all(&out2);
    }

    #[test]
    fn epsilon_schedule() {
        let r = RlConfig::default();
        assert_eq!(r.epsilon(0), 0.5);
        approx::assert_relative_eq!(r.epsilon(2000), 0.3, epsilon = 1e-12);
        assert_eq!(r.epsilon(4000), 0.1);
        assert_eq!(r.epsilon(15000), 0.1);
    }

    #[test]
    fn memory_is_a_ring() {
        let mut m = Memory::new(3, 1);
        for k in 0..5 {
            m.push(&[k as f32; JOINT_DIM], k as f32);
        }
        assert_eq!(m.len(), 3);
        // Pushes 3 and 4 overwrote slots 0 and 1.
        assert_eq!(m.values, vec![3.0, 4.0, 2.0]);
        assert_eq!(m.states[0], 3.0);
        assert_eq!(m.next, 2);
    }

    #[test]
    fn the_shipped_config_parses() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../sdk/configs/sarl.toml");
        let cfg = TrainConfig::load(&path).unwrap();
        assert_eq!(cfg.il.episodes, 5000);
        assert_eq!(cfg.net, NetConfig::default());
        let err = toml::from_str::<TrainConfig>("[rl]\nepisodez = 3").unwrap_err();
        assert!(err.to_string().contains("episodez"), "{err}");
        // Thread counts are bounded (libtorch would start them all).
        for threads in [0, MAX_THREADS + 1, 100_000] {
            let c = TrainConfig {
                threads,
                ..cfg.clone()
            };
            let err = c.validate().unwrap_err().to_string();
            assert!(err.contains("threads") && err.contains("1..=256"), "{err}");
        }
    }
}
