//! The planner's configuration file (`sdk/configs/planner.toml`): [`PlannerConfig`] and its
//! `[prediction]` table.

use super::{Backend, PlannerError};
use human2nav_core::forecast::FlowPredictorSettings;
use human2nav_core::human2nav::Human2NavSettings;
use human2nav_core::input::{MAX_CONFIG_BYTES, read_user_file};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// The shipped model's folder, relative to the workspace root.
pub const DEFAULT_MODEL_DIR: &str = "models/human2nav-cfm";

/// Largest `threads` accepted (libtorch intra-op threads; a planner is meant to use one).
pub const MAX_THREADS: usize = 256;

/// Contents of `sdk/configs/planner.toml` (every key optional).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PlannerConfig {
    /// Model folder (`model.toml` + weights); relative paths are resolved against the workspace
    /// root. Default [`DEFAULT_MODEL_DIR`].
    pub model: PathBuf,
    /// libtorch intra-op threads for planning with the `torch` backend. Default 1 (one core
    /// per robot; the latency targets are stated for one thread). The native backend always
    /// runs on the calling thread.
    pub threads: usize,
    /// What runs the network: `native` (Rust kernels on the CPU, the default) or `torch`
    /// (libtorch: the reference, and the way to a GPU).
    pub backend: Backend,
    /// The planner's settings (sampling, guidance, selection).
    pub human2nav: Human2NavSettings,
    /// Where the selection expects people to go (the `[prediction]` table). Without a model
    /// (the default): constant velocity.
    pub prediction: PredictionConfig,
}

/// The `[prediction]` table of a planner file: a goal-free flow model of people
/// ([`Normalisation::goal_conditioned`](crate::config::Normalisation::goal_conditioned) false,
/// `train.goal = false`) and how the [`FlowPredictor`] samples it.
///
/// [`FlowPredictor`]: human2nav_core::forecast::FlowPredictor
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PredictionConfig {
    /// The predictor's model folder, resolved like [`PlannerConfig::model`]; `None` (the
    /// default): constant velocity. It runs on the planner's backend.
    pub model: Option<PathBuf>,
    /// How it is sampled (`[prediction.flow]`).
    pub flow: FlowPredictorSettings,
}

impl Default for PlannerConfig {
    fn default() -> Self {
        Self {
            model: PathBuf::from(DEFAULT_MODEL_DIR),
            threads: 1,
            backend: Backend::default(),
            human2nav: Human2NavSettings::default(),
            prediction: PredictionConfig::default(),
        }
    }
}

impl PlannerConfig {
    /// Checks every field; the error names the first offending one.
    pub fn validate(&self) -> Result<(), PlannerError> {
        if !(1..=MAX_THREADS).contains(&self.threads) {
            return Err(PlannerError::Setting {
                field: "threads".into(),
                message: format!("{} is not in 1..={MAX_THREADS}", self.threads),
            });
        }
        if self.model.as_os_str().is_empty() {
            return Err(PlannerError::Setting {
                field: "model".into(),
                message: "must name a model folder".into(),
            });
        }
        self.backend.check_available()?;
        self.human2nav.validate()?;
        // Checked with or without a model: a bad value is an error before it is used.
        self.prediction.flow.validate().map_err(|e| {
            let (key, message) = e.split_once(": ").unwrap_or(("", &e));
            PlannerError::Setting {
                field: format!("prediction.flow.{key}"),
                message: message.to_owned(),
            }
        })?;
        Ok(())
    }

    /// Parses and validates the TOML text of a planner configuration; `path` is only used in
    /// error messages.
    pub fn from_toml_str(text: &str, path: &Path) -> Result<Self, PlannerError> {
        let cfg: Self = toml::from_str(text).map_err(|e| PlannerError::Config {
            path: path.to_path_buf(),
            message: e.to_string(),
        })?;
        cfg.validate()?;
        Ok(cfg)
    }

    /// Reads, parses and validates a planner configuration file.
    pub fn load(path: &Path) -> Result<Self, PlannerError> {
        let text =
            read_user_file(path, "planner configuration", MAX_CONFIG_BYTES).map_err(|e| {
                PlannerError::Config {
                    path: path.to_path_buf(),
                    message: e.to_string(),
                }
            })?;
        Self::from_toml_str(&text, path)
    }

    /// The model folder, resolved against `workspace` when relative.
    pub fn model_dir(&self, workspace: &Path) -> PathBuf {
        resolve(&self.model, workspace)
    }
}

pub(super) fn resolve(path: &Path, workspace: &Path) -> PathBuf {
    if path.is_absolute() {
        path.to_path_buf()
    } else {
        workspace.join(path)
    }
}
