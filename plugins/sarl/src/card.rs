//! The model card (`model.toml`) shipped beside `model.safetensors` in `models/sarl`: what the
//! planner needs to rebuild the network and its look-ahead, plus provenance and evaluation.

use crate::env::{EnvConfig, RewardConfig};
use crate::error::SarlError;
use crate::net::NetConfig;
use human2nav_core::input::{MAX_CONFIG_BYTES, read_user_file};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// File name of the card in a model directory.
pub const CARD_FILE: &str = "model.toml";
/// File name of the weights in a model directory.
pub const WEIGHTS_FILE: &str = "model.safetensors";
/// File name of the training-curve figure in a model directory.
pub const CURVE_FILE: &str = "training_curve.png";

/// The look-ahead's constants as trained.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LookAheadCard {
    /// Discount per unit of `Δt·v_pref`.
    pub gamma: f64,
    /// Look-ahead step Δt (s).
    pub time_step: f64,
    /// Speeds per heading.
    pub speed_samples: usize,
    /// Headings.
    pub rotation_samples: usize,
    /// The robot's preferred speed in training (m/s).
    pub v_pref: f64,
}

/// Outcome rates of greedy episodes on held-out circle-crossing seeds.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct EvalCard {
    pub episodes: usize,
    /// Seeds used: `held-out test stream of seed S, episodes 0..n`.
    pub seeds: String,
    pub success_rate: f64,
    pub collision_rate: f64,
    pub timeout_rate: f64,
    /// Mean time to the goal of the successful episodes (s).
    pub mean_success_time: f64,
    /// The same seeds with the straight-to-goal policy (at `v_pref`), for reference.
    pub straight_success_rate: f64,
    pub straight_collision_rate: f64,
    /// The same seeds with the ORCA demonstrator controlling the robot.
    pub orca_success_rate: f64,
    pub orca_collision_rate: f64,
}

/// Provenance of the weights.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TrainingCard {
    pub seed: u64,
    pub threads: usize,
    pub il_episodes: usize,
    pub il_transitions: usize,
    pub il_epochs: usize,
    pub il_learning_rate: f64,
    pub rl_episodes: usize,
    pub rl_learning_rate: f64,
    pub batches_per_episode: usize,
    pub batch_size: usize,
    pub momentum: f64,
    pub capacity: usize,
    pub epsilon: String,
    pub target_update_every: usize,
    /// Total wall time of training (s), over every resumed invocation.
    pub wall_seconds: f64,
    /// Why the counts differ from the paper's, if they do.
    pub notes: String,
}

/// The whole card.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ModelCard {
    pub format_version: u32,
    pub name: String,
    pub description: String,
    pub weights: String,
    pub parameters: usize,
    pub net: NetConfig,
    pub lookahead: LookAheadCard,
    pub reward: RewardConfig,
    pub env: EnvConfig,
    #[serde(default)]
    pub training: TrainingCard,
    #[serde(default)]
    pub evaluation: EvalCard,
}

impl ModelCard {
    /// Reads and checks a card.
    pub fn load(path: &Path) -> Result<Self, SarlError> {
        let text = read_user_file(path, "SARL model card", MAX_CONFIG_BYTES)
            .map_err(|e| SarlError::io(path, e))?;
        let card: ModelCard = toml::from_str(&text).map_err(|e| SarlError::Parse {
            path: path.to_path_buf(),
            message: e.to_string(),
        })?;
        card.net.validate()?;
        let la = &card.lookahead;
        let ok = la.gamma > 0.0 && la.gamma <= 1.0 && la.time_step > 0.0 && la.v_pref > 0.0;
        if !ok {
            return Err(SarlError::Parse {
                path: path.to_path_buf(),
                message: "lookahead: gamma must lie in (0, 1], time_step and v_pref be > 0".into(),
            });
        }
        if la.speed_samples == 0 || la.rotation_samples == 0 {
            return Err(SarlError::Parse {
                path: path.to_path_buf(),
                message: "lookahead: speed_samples and rotation_samples must be ≥ 1".into(),
            });
        }
        Ok(card)
    }

    /// Writes the card with a header comment.
    pub fn save(&self, path: &Path) -> Result<(), SarlError> {
        let body = toml::to_string_pretty(self).map_err(|e| SarlError::Parse {
            path: path.to_path_buf(),
            message: e.to_string(),
        })?;
        let text = format!(
            "# SARL model card: architecture, look-ahead, training provenance, circle-crossing evaluation.\n{body}"
        );
        std::fs::write(path, text).map_err(|e| SarlError::io(path, e))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn card() -> ModelCard {
        ModelCard {
            format_version: 1,
            name: "sarl".into(),
            description: "test".into(),
            weights: WEIGHTS_FILE.into(),
            parameters: NetConfig::default().parameter_count(),
            net: NetConfig::default(),
            lookahead: LookAheadCard {
                gamma: 0.9,
                time_step: 0.25,
                speed_samples: 5,
                rotation_samples: 16,
                v_pref: 1.0,
            },
            reward: RewardConfig::default(),
            env: EnvConfig::default(),
            training: TrainingCard::default(),
            evaluation: EvalCard::default(),
        }
    }

    #[test]
    fn round_trip_and_checks() {
        let dir = std::env::temp_dir().join(format!("sarl-card-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join(CARD_FILE);
        let c = card();
        c.save(&path).unwrap();
        assert_eq!(ModelCard::load(&path).unwrap(), c);
        let mut bad = card();
        bad.lookahead.gamma = 1.5;
        bad.save(&path).unwrap();
        let err = ModelCard::load(&path).unwrap_err();
        assert!(err.to_string().contains("gamma"), "{err}");
        let err = ModelCard::load(&dir.join("missing.toml")).unwrap_err();
        assert!(err.to_string().contains("missing.toml"), "{err}");
        let _ = std::fs::remove_dir_all(&dir);
    }
}
