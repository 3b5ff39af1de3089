//! The model card: a TOML file shipped beside the weights that fully describes how to rebuild
//! the network and how to use it (architecture, normalisation, source distribution), and
//! records where it came from (training data, split, time) and how good it is.

use crate::config::{NetConfig, Normalisation};
use crate::error::CfmError;
use human2nav_core::input::{MAX_CONFIG_BYTES, fnv1a64, read_user_file};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Version of the card and weight-naming scheme; bumped on incompatible changes.
pub const FORMAT_VERSION: u32 = 1;

/// Everything needed to rebuild and use a trained model, plus its provenance.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ModelCard {
    /// Card format version ([`FORMAT_VERSION`]).
    pub format_version: u32,
    /// Model name, e.g. `human2nav-cfm`.
    pub name: String,
    /// One-paragraph description.
    #[serde(default)]
    pub description: String,
    /// File name of the weights beside the card.
    pub weights: String,
    /// FNV-1a 64 checksum (hex) of the weights file, written with the weights; a file that
    /// does not match is refused. Absent in cards written before checksums were recorded.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub weights_fnv64: Option<String>,
    /// Architecture hyper-parameters.
    pub net: NetConfig,
    /// Metric ↔ network normalisation.
    pub normalisation: Normalisation,
    /// The source distribution samplers must draw from.
    pub source: SourceInfo,
    /// The BEV raster the model was trained on (`cells = net.bev_cells`); planners must
    /// rasterise with the same spec. Absent for untrained models.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub bev: Option<human2nav_core::bev::BevSpec>,
    /// Size and cost.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub complexity: Option<ComplexityInfo>,
    /// How the model was trained.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub training: Option<TrainingInfo>,
    /// Held-out evaluation.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub evaluation: Option<EvaluationInfo>,
    /// Measured latencies.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub performance: Option<PerformanceInfo>,
}

/// The source distribution `x0 = exp(ξ0)`, `ξ0 ~ N(0, diag(std²))` per waypoint.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SourceInfo {
    /// `[σ_x, σ_y, σ_θ]` in metres and radians (`[s, s, 1]`: `N(0, I)` in normalised units).
    pub std: [f64; 3],
    /// Integration steps `N` the evaluation used (uniform grid `t_i = i/N`).
    pub steps: usize,
}

impl SourceInfo {
    /// Every `std` finite and > 0, `steps` in 1 to
    /// [`MAX_STEPS_N`](human2nav_core::guidance::MAX_STEPS_N); the error names the field.
    pub fn validate(&self) -> Result<(), String> {
        if let Some(k) = self.std.iter().position(|s| !(s.is_finite() && *s > 0.0)) {
            return Err(format!("std[{k}] = {} must be finite and > 0", self.std[k]));
        }
        let most = human2nav_core::guidance::MAX_STEPS_N;
        if !(1..=most).contains(&self.steps) {
            return Err(format!("steps = {} must lie in 1 to {most}", self.steps));
        }
        Ok(())
    }
}

/// Parameter count and cost of one forward pass.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ComplexityInfo {
    /// Trainable scalar parameters.
    pub parameters: usize,
    /// FLOPs (2 × multiply-accumulates) of the U-Net per trajectory and flow step.
    pub unet_flops_per_trajectory: u64,
    /// FLOPs of the BEV and goal encoders, once per planning condition.
    pub condition_flops: u64,
    /// Size of the weights file in bytes.
    pub weights_bytes: u64,
}

/// Provenance of a trained model.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TrainingInfo {
    /// Data sets and cache the tuples came from.
    pub data: String,
    /// How the scenes were split into train / validation / test.
    pub split: String,
    /// Number of training tuples.
    pub train_tuples: usize,
    /// Number of validation tuples.
    pub val_tuples: usize,
    /// Optimiser steps.
    pub steps: u64,
    /// Examples per optimiser step.
    pub batch_size: usize,
    /// Passes over the training tuples (fractional).
    pub epochs: f64,
    /// Random seed.
    pub seed: u64,
    /// Flow-time distribution during training (see [`crate::cfm::TimeDistribution`]).
    pub time_distribution: String,
    /// `σ` of Eq. 3's probability path, normalised units (0: the deterministic geodesic; cards
    /// written before the option existed are 0).
    #[serde(default)]
    pub path_sigma: f64,
    /// Whether each training example was also used as its left-right mirror image (with
    /// probability 1/2; cards written before the field existed were trained without).
    #[serde(default)]
    pub mirror: bool,
    /// The counterfactual walkers the windows were augmented with
    /// ([`crate::train::Counterfactual`]); absent: none.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub counterfactual: Option<crate::train::Counterfactual>,
    /// The clearance term of the loss ([`crate::train::ClearanceLoss`]); absent: Eq. 3 alone.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub clearance: Option<crate::train::ClearanceLoss>,
    /// Optimiser and schedule, in words.
    pub optimiser: String,
    /// Wall time of training in seconds.
    pub wall_time_s: f64,
    /// Threads training ran on.
    pub threads: usize,
    /// Mean training throughput.
    pub samples_per_s: f64,
    /// Loss (Eq. 3, standardised units) of the EMA weights on the validation split at the end.
    pub final_val_loss: f64,
    /// The lowest validation loss seen during training.
    pub best_val_loss: f64,
    /// Training loss averaged over the last validation interval.
    pub final_train_loss: f64,
}

/// Best-of-K displacement errors on held-out windows and the proximity rate.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct EvaluationInfo {
    /// What was evaluated, in words (split, number of windows, sampler settings).
    pub protocol: String,
    /// Held-out windows evaluated.
    pub windows: usize,
    /// Trajectories sampled per window (the `K` of best-of-K).
    pub samples_per_window: usize,
    /// Integration steps of the sampler.
    pub steps: usize,
    /// Best-of-K average displacement error of the model, metres.
    pub min_ade: f64,
    /// Best-of-K final displacement error of the model, metres.
    pub min_fde: f64,
    /// Mean over samples (not the best) of ADE, metres.
    pub mean_ade: f64,
    /// Average displacement error of the constant-velocity baseline on the same windows, metres.
    pub cv_ade: f64,
    /// Final displacement error of the constant-velocity baseline, metres.
    pub cv_fde: f64,
    /// `1 − min_ade / cv_ade`.
    pub ade_improvement: f64,
    /// ADE of the samples' mean, taken as one point forecast, metres (absent from cards
    /// evaluated before it was measured).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub centroid_ade: Option<f64>,
    /// ADE over the first second: mean over samples, the samples' mean and constant
    /// velocity, metres (absent from cards evaluated before it was measured).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub early_ade: Option<EarlyAde>,
    /// The distance (m) to another agent's position that counts as "close" in the proximity
    /// rates below.
    pub proximity_radius: f64,
    /// Fraction of sampled trajectories within `proximity_radius` of another agent.
    pub proximity_model: f64,
    /// Fraction of ground-truth futures within `proximity_radius` of another agent.
    pub proximity_truth: f64,
    /// How the other agents' positions were obtained for the proximity metric.
    pub proximity_note: String,
    /// Whether the samples react to the crowd in the model's input (absent from cards
    /// evaluated before it was measured).
    /// One entry per crowd-guidance weight probed.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub crowd_probe: Vec<CrowdProbeInfo>,
}

/// The crowd-awareness probe of a model card ([`crate::eval::CrowdProbe`]): the same source
/// samples drawn with the crowd in the BEV raster and with the raster emptied.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CrowdProbeInfo {
    /// The crowd-guidance weight the samples were drawn with (1: the model as it is).
    pub crowd_weight: f64,
    /// Distance between centres (m) at which a sample meets someone.
    pub contact: f64,
    /// Share of samples meeting someone on their recorded future: crowd observed, hidden.
    pub recorded: [f64; 2],
    /// Share of samples meeting someone walking on at constant velocity: observed, hidden.
    pub constant_velocity: [f64; 2],
    /// The recorded human's own share at the same windows: recorded futures, constant velocity.
    pub human: [f64; 2],
    /// Mean distance (m) between a sample and its twin drawn with the crowd hidden.
    pub displacement: f64,
}

impl CrowdProbeInfo {
    /// The card's record of probe `p`, drawn with crowd-guidance weight `crowd_weight`.
    pub fn of(p: crate::eval::CrowdProbe, crowd_weight: f64) -> Self {
        Self {
            crowd_weight,
            contact: p.contact,
            recorded: [p.observed_recorded, p.hidden_recorded],
            constant_velocity: [p.observed_cv, p.hidden_cv],
            human: [p.human_recorded, p.human_cv],
            displacement: p.displacement,
        }
    }
}

/// ADEs over a plan's first waypoints (see [`EvaluationInfo::early_ade`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct EarlyAde {
    /// Seconds covered.
    pub seconds: f64,
    /// Mean over samples, metres.
    pub mean: f64,
    /// The samples' mean, metres.
    pub centroid: f64,
    /// Constant velocity, metres.
    pub constant_velocity: f64,
}

/// Measured latencies on the training machine.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PerformanceInfo {
    /// Machine and thread count the numbers were measured with.
    pub machine: String,
    /// Threads the numbers were measured with.
    pub threads: usize,
    /// Median milliseconds of a velocity call at batch 1.
    pub forward_b1_ms: f64,
    /// Median milliseconds of a velocity call at batch 16.
    pub forward_b16_ms: f64,
    /// Median milliseconds of a velocity + VJP call at batch 1.
    pub vjp_b1_ms: f64,
    /// Median milliseconds of a velocity + VJP call at batch 16.
    pub vjp_b16_ms: f64,
    /// Median milliseconds of encoding the condition once.
    pub encode_condition_ms: f64,
}

impl ModelCard {
    /// Reads and checks a card.
    pub fn load(path: &Path) -> Result<Self, CfmError> {
        let text = read_user_file(path, "model card", MAX_CONFIG_BYTES)
            .map_err(|e| CfmError::io(path, e))?;
        let card: ModelCard = toml::from_str(&text).map_err(|e| CfmError::Toml {
            path: path.to_path_buf(),
            message: e.to_string(),
        })?;
        if card.format_version != FORMAT_VERSION {
            return Err(CfmError::Toml {
                path: path.to_path_buf(),
                message: format!(
                    "format_version {} is not supported (expected {FORMAT_VERSION})",
                    card.format_version
                ),
            });
        }
        card.net.validate()?;
        card.normalisation.validate()?;
        card.source.validate().map_err(|message| CfmError::Toml {
            path: path.to_path_buf(),
            message: format!("[source]: {message}"),
        })?;
        if let Some(bev) = &card.bev {
            bev.validate().map_err(|e| CfmError::Toml {
                path: path.to_path_buf(),
                message: format!("[bev]: {e}"),
            })?;
            if bev.cells != card.net.bev_cells {
                return Err(CfmError::Toml {
                    path: path.to_path_buf(),
                    message: format!(
                        "[bev] cells = {} but the network takes net.bev_cells = {}: the card \
                         does not describe these weights",
                        bev.cells, card.net.bev_cells
                    ),
                });
            }
            if let Some(c) = &card.net.crowd {
                if (c.cell - bev.resolution).abs() > 1e-9 {
                    return Err(CfmError::Toml {
                        path: path.to_path_buf(),
                        message: format!(
                            "[bev] resolution = {} but net.crowd.cell = {}: the crowd pathway \
                             would place the raster's cells at the wrong distances",
                            bev.resolution, c.cell
                        ),
                    });
                }
            }
        }
        Ok(card)
    }

    /// The checksum a card records for `bytes` (see [`Self::weights_fnv64`]).
    pub fn checksum(bytes: &[u8]) -> String {
        format!("{:016x}", fnv1a64(bytes))
    }

    /// Checks the weights file's bytes against the card: its checksum, when the card has one,
    /// and the training settings the file records in its safetensors metadata
    /// ([`Self::trained_on`]), when it records them. A file written before weights carried
    /// that metadata passes the second check unverified.
    pub fn verify_weights(&self, path: &Path, bytes: &[u8]) -> Result<(), CfmError> {
        if let Some(want) = &self.weights_fnv64 {
            if *want != Self::checksum(bytes) {
                return Err(CfmError::WeightsChecksum {
                    path: path.to_path_buf(),
                    found: Self::checksum(bytes),
                    expected: want.clone(),
                    bytes: bytes.len(),
                });
            }
        }
        // A file whose header does not parse is reported by the weight loader, with the file
        // named; here only well-formed metadata is compared.
        let Ok((_, header)) = safetensors::SafeTensors::read_metadata(bytes) else {
            return Ok(());
        };
        let Some(recorded) = header.metadata() else {
            return Ok(());
        };
        for (key, card) in self.trained_on() {
            if let Some(weights) = recorded.get(key) {
                if *weights != card {
                    return Err(CfmError::WeightsTrainedOn {
                        path: path.to_path_buf(),
                        setting: format!("{key} = {weights}, the model card says {card}"),
                    });
                }
            }
        }
        Ok(())
    }

    /// The settings the weights depend on without their tensor shapes showing it, as the
    /// exporter records them in the weights file's safetensors metadata: the horizon, the BEV
    /// raster's cells per side and its resolution (the raster encoder is convolutional, so a
    /// card naming another raster would load and silently see a different world).
    pub fn trained_on(&self) -> Vec<(&'static str, String)> {
        let bev = self.bev.unwrap_or_default();
        vec![
            ("horizon", self.net.horizon.to_string()),
            ("bev_cells", self.net.bev_cells.to_string()),
            ("bev_resolution", bev.resolution.to_string()),
        ]
    }

    /// Writes the card as TOML.
    pub fn save(&self, path: &Path) -> Result<(), CfmError> {
        let text = toml::to_string_pretty(self).map_err(|e| CfmError::Toml {
            path: path.to_path_buf(),
            message: e.to_string(),
        })?;
        let header =
            "# human2nav flow-model card: architecture, normalisation, provenance, metrics.\n";
        std::fs::write(path, format!("{header}{text}")).map_err(|e| CfmError::io(path, e))
    }
}
