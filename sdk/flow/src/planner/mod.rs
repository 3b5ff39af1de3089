//! The reference planner with the trained flow model: a [`Human2Nav<PlannerModel>`] built from a
//! robot profile (`robot.toml` + URDF + plugin constraint terms) and a model folder
//! (`model.toml` card + weights), and two measurements of it:
//!
//! * the guidance ablation (raw, Algorithm 1, QP, both) lives in
//!   [`human2nav_core::ablation`]; `human2nav plan --eval` runs it with this planner;
//! * [`measure_latency`] / [`LatencyStats`]: p50/p95 wall time of one planning call, and
//!   [`TimedModel`], which splits that time into flow-network calls and everything else.
//!
//! # Configuration
//! [`PlannerConfig`] is the TOML of `sdk/configs/planner.toml`: the model folder, the number of
//! libtorch threads and the [`Human2NavSettings`] table (`[human2nav]`, with
//! `[human2nav.guidance]` and `[human2nav.selection]`). Unknown keys are rejected.
//!
//! # The BEV raster
//! The planner must rasterise the crowd exactly as the training tuples were rasterised
//! ([`bev_spec`]): the number of cells is the network's input size (`net.bev_cells` of the
//! card) and the cell size comes from the card's training record.
//!
//! [`Human2Nav<PlannerModel>`]: human2nav_core::human2nav::Human2Nav
//! [`Human2NavSettings`]: human2nav_core::human2nav::Human2NavSettings

use crate::error::CfmError;
use human2nav_core::PlanError;
use std::path::PathBuf;

mod card;
mod config;
mod latency;
mod model;
mod robot;
#[cfg(test)]
mod tests;

pub use card::{BevOrigin, TRAINING_DT, bev_spec, check_dt, trained_dt};
pub use config::{DEFAULT_MODEL_DIR, MAX_THREADS, PlannerConfig, PredictionConfig};
pub use latency::{FlowCallStats, LatencyStats, TimedModel, measure_latency};
pub use model::{Backend, PlannerModel, PredictionModel, TORCH_MISSING, load_model};
pub use robot::{RobotPlanner, load_profile, robot_model, robot_phi};

/// Why a planner could not be built or measured.
#[derive(Debug, thiserror::Error)]
pub enum PlannerError {
    /// A planner configuration file could not be read or parsed.
    #[error("{path}: {message}")]
    Config {
        /// The file or folder.
        path: PathBuf,
        /// What went wrong, in one line.
        message: String,
    },
    /// A configuration value is out of range; `field` is its TOML path.
    #[error("invalid planner setting `{field}`: {message}")]
    Setting {
        /// The setting's TOML path.
        field: String,
        /// What went wrong, in one line.
        message: String,
    },
    /// The robot profile could not be loaded.
    #[error("robot profile {path}: {message}")]
    Profile {
        /// The file or folder.
        path: PathBuf,
        /// What went wrong, in one line.
        message: String,
    },
    /// A plugin constraint term of the profile could not be instantiated.
    #[error("robot profile {path}: plugin constraint: {message}")]
    Plugin {
        /// The file or folder.
        path: PathBuf,
        /// What went wrong, in one line.
        message: String,
    },
    /// The model folder could not be loaded.
    #[error("model {path}: {source}")]
    Model {
        /// The file or folder.
        path: PathBuf,
        /// Why the model could not be loaded.
        #[source]
        source: CfmError,
    },
    /// The planner rejected its settings or an observation.
    #[error(transparent)]
    Plan(#[from] PlanError),
}
