//! The `train.toml` settings ([`TrainConfig`]): data, run bookkeeping and held-out evaluation
//! sections beside the network and the optimisation, and their checks.

use anyhow::{Context, bail};
use human2nav_core::input::{MAX_CONFIG_BYTES, read_user_file};
use human2nav_data::tuples::Split;
use human2nav_flow::NetConfig;
use human2nav_flow::train::TrainOptions;
use serde::Deserialize;
use std::path::{Path, PathBuf};

/// Where the data comes from.
#[derive(Clone, Debug, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct DataSection {
    /// Tuple cache directory (from `human2nav data build`); relative paths start at the
    /// workspace root.
    pub cache: PathBuf,
    /// Fraction of the training scenes to use (seeded choice). Default 1.
    pub train_fraction: f64,
    /// How many times each *interacting* training window is used per epoch (1 to
    /// [`MAX_INTERACTION_REPEAT`]): a window where the walker, going on at its velocity, would
    /// come within [`INTERACTION_CONTACT`] of someone going on at theirs, where what the
    /// crowd does matters to where the walker goes. Default 1: every window once.
    pub interaction_repeat: usize,
}

/// Largest [`DataSection::interaction_repeat`].
pub const MAX_INTERACTION_REPEAT: usize = 100;

/// Distance between centres (m) at which two constant-velocity paths meet, for
/// [`DataSection::interaction_repeat`]: two pedestrian discs of 0.3 m touching.
pub const INTERACTION_CONTACT: f64 = 0.6;

impl Default for DataSection {
    fn default() -> Self {
        Self {
            cache: PathBuf::from("out/data/cache"),
            train_fraction: 1.0,
            interaction_repeat: 1,
        }
    }
}

/// Run bookkeeping.
#[derive(Clone, Debug, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RunSection {
    /// Model name in the card.
    pub name: String,
    /// Checkpoints and logs. Default `out/train/<name>`.
    pub out_dir: Option<PathBuf>,
    /// Where the exported model goes. Default `models/<name>`.
    pub model_dir: Option<PathBuf>,
    /// Torch intra-op threads. Default 2.
    pub threads: usize,
    /// `auto` (CUDA when available), `cpu` or `cuda`.
    pub device: String,
    /// Steps between validation points. Default 250.
    pub validate_every: u64,
    /// Steps between checkpoints. Default 1000.
    pub checkpoint_every: u64,
    /// Stop (and checkpoint) after this many minutes of this invocation; 0 = no limit.
    pub max_minutes: f64,
}

impl Default for RunSection {
    fn default() -> Self {
        Self {
            name: "human2nav-cfm".into(),
            out_dir: None,
            model_dir: None,
            threads: 2,
            device: "auto".into(),
            validate_every: 250,
            checkpoint_every: 1000,
            max_minutes: 0.0,
        }
    }
}

/// Held-out evaluation.
#[derive(Clone, Debug, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct EvalSection {
    /// Sampled futures per window `K`. Default 20.
    pub samples: usize,
    /// Euler steps `N`. Default 10.
    pub steps: usize,
    /// Proximity radius, metres. Default 0.3.
    pub radius: f64,
    /// Distance between centres (m) at which a sample meets someone in the crowd-awareness
    /// probe ([`human2nav_flow::eval::CrowdProbe`]): two pedestrian discs of the raster's
    /// 0.3 m touching. Default 0.6.
    pub contact: f64,
    /// Crowd-guidance weights the probe runs ([`human2nav_core::flow::CrowdGuidance`]; 1:
    /// the model as it is). Default `[1]`.
    pub crowd_weights: Vec<f64>,
    /// Also run [`human2nav_flow::eval::counterfactual_probe`]: a standing person placed on
    /// each window's constant-velocity line where the recorded future avoided it, the samples
    /// with and without that person in the raster, once per crowd weight. Default
    /// false.
    pub counterfactual_probe: bool,
    /// Split whose windows are evaluated: `test` (the default, and what a model card
    /// reports), `val` (to study settings without looking at the test scenes) or `train`.
    pub split: Split,
    /// Windows evaluated at most (seeded subsample). Default 2000.
    pub max_windows: usize,
    /// Seed of the subsample and of the source noise. Default 0.
    pub seed: u64,
    /// Data config used to rebuild the test scenes for the other agents' true futures
    /// (proximity metric). When the datasets are unavailable, the neighbours stored in the
    /// cache are extrapolated at constant velocity instead (noted in the card).
    pub data_config: PathBuf,
}

impl Default for EvalSection {
    fn default() -> Self {
        Self {
            samples: 20,
            steps: 10,
            radius: 0.3,
            contact: 0.6,
            crowd_weights: vec![1.0],
            counterfactual_probe: false,
            split: Split::Test,
            max_windows: 2000,
            seed: 0,
            data_config: PathBuf::from("sdk/configs/data.toml"),
        }
    }
}

/// The whole `train.toml`; every section defaults to the values documented on its fields.
#[derive(Clone, Debug, Default, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TrainConfig {
    /// Where the data comes from.
    pub data: DataSection,
    /// The network.
    pub net: NetConfig,
    /// The optimisation.
    pub train: TrainOptions,
    /// Run bookkeeping.
    pub run: RunSection,
    /// Held-out evaluation.
    pub eval: EvalSection,
}

impl TrainConfig {
    /// Reads and parses a `train.toml` (not validated: callers apply their overrides, then
    /// call [`Self::validate`]).
    pub fn load(path: &Path) -> anyhow::Result<Self> {
        let text = read_user_file(path, "configuration", MAX_CONFIG_BYTES)
            .with_context(|| format!("reading {}", path.display()))?;
        toml::from_str(&text).with_context(|| format!("parsing {}", path.display()))
    }

    /// Checks every section; the error names the offending field.
    pub fn validate(&self) -> anyhow::Result<()> {
        self.net.validate()?;
        self.train.validate()?;
        self.train.check_batch_size(&self.net)?;
        if !(1..=MAX_INTERACTION_REPEAT).contains(&self.data.interaction_repeat) {
            bail!(
                "data.interaction_repeat: {} is not in 1..={MAX_INTERACTION_REPEAT}",
                self.data.interaction_repeat
            );
        }
        let f = self.data.train_fraction;
        if !(f > 0.0 && f <= 1.0) {
            bail!("data.train_fraction must lie in (0, 1], got {f}");
        }
        let max = human2nav_flow::planner::MAX_THREADS;
        if !(1..=max).contains(&self.run.threads) {
            bail!("run.threads: {} is not in 1..={max}", self.run.threads);
        }
        if self.run.validate_every == 0 || self.run.checkpoint_every == 0 {
            bail!("run.validate_every and run.checkpoint_every must be positive");
        }
        if !matches!(self.run.device.as_str(), "auto" | "cpu" | "cuda") {
            bail!(
                "run.device must be auto, cpu or cuda, got `{}`",
                self.run.device
            );
        }
        if self.run.max_minutes.is_nan() || self.run.max_minutes < 0.0 {
            bail!("run.max_minutes must be >= 0");
        }
        if self.eval.samples == 0
            || self.eval.steps == 0
            || self.eval.radius.is_nan()
            || self.eval.radius <= 0.0
            || !(self.eval.contact.is_finite() && self.eval.contact > 0.0)
        {
            bail!(
                "eval.samples, eval.steps, eval.radius and eval.contact must be positive and finite"
            );
        }
        if let Some(w) = self
            .eval
            .crowd_weights
            .iter()
            .find(|w| !(w.is_finite() && **w >= 0.0))
        {
            bail!("eval.crowd_weights: {w} must be finite and >= 0");
        }
        if self.eval.crowd_weights.len() > 16 {
            bail!("eval.crowd_weights: at most 16 weights (each is a pass over the windows)");
        }
        Ok(())
    }
}
