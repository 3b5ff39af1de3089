//! Pedestrian datasets to training tuples and benchmark episodes (paper §III-A), and a
//! synthetic social-force crowd for machines without the datasets. No libtorch.
//!
//! Pipeline: [`loaders`] (ETH, UCY, sgan benchmark, SDD raw and TrajNet) → [`track::RawScene`]
//! in metres → [`resample`] to 0.1 s with velocity and heading → [`tuples`] (BEV raster, goal,
//! velocity, 32 future SE(2) poses) in a versioned binary [`cache`] split by scene, and
//! [`scenario`] mining of benchmark [`Episode`]s from held-out scenes, with [`episode_mining`]
//! mining interaction-rich ones (the robot's path and the crowd from different times).
//! [`association`] builds tracks from identity-free detections with the Hungarian algorithm,
//! [`homography`] maps image to world (Eq. 1), [`synthetic`] generates crowds of the four flow
//! classes. [`config`] is the `data.toml` schema, [`pipeline`] the parallel,
//! thread-count-independent jobs behind `human2nav data build | episodes | associate`, and
//! [`paths`] locates datasets and outputs. [`input_limits`] lists the bounds on what is read.
//! [`prediction`] scores simple pedestrian predictors on the recorded crowds of an episode
//! file (`human2nav data predict`).

#![warn(missing_docs)]

pub mod association;
pub mod cache;
pub mod config;
pub mod corridor;
pub mod episode_mining;
pub mod error;
pub mod homography;
pub mod input_limits;
/// The former name of [`input_limits`].
pub use input_limits as limits;
pub mod loaders;
pub mod paths;
pub mod pipeline;
pub mod prediction;
pub mod resample;
pub mod scenario;
pub mod synthetic;
pub(crate) mod text;
pub mod track;
pub mod tuples;

/// The former name of [`episode_mining`], kept so that existing paths resolve.
pub use episode_mining as interaction;

pub use cache::{Manifest, SceneInfo, TupleCache};
pub use episode_mining::{InteractionOptions, InteractionStats, SuiteSummary};
pub use error::DataError;
pub use homography::Homography;
pub use resample::{ResampleOptions, Scene, Track};
pub use scenario::{AgentTrack, Episode, EpisodeSuite, ScenarioClass};
pub use track::{AgentClass, RawScene, RawTrack, Sample};
pub use tuples::{CompactTuple, Split, TrainingTuple};
