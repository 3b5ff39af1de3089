//! Closed-loop crowd-navigation benchmark (paper §IV–V): a SocNavBench-like simulator that
//! replays real (or synthetic) pedestrians non-reactively around a robot driven by any
//! [`human2nav_core::Planner`] through its embodiment's tracking controller, the per-episode
//! metrics (SR, TFS, ...), the benchmark runner over suites × robots × methods, and the report
//! (`results.csv`, `report.md`, PNG figures). No libtorch: planners come in as trait objects.
//!
//! * [`episode`]: the episode types (from the data crate).
//! * [`replay`]: pedestrians interpolated to the simulation step.
//! * [`crowd`]: the crowd during a run, replayed or reactive (social force toward the robot).
//! * [`runner`]: the closed loop, collision/goal/budget rules ([`runner::SimConfig`]).
//! * [`metrics`]: per-episode metrics.
//! * [`straight`]: the straight-to-goal sanity baseline.
//! * [`oracle`]: the clairvoyant yardstick (reads the recorded crowd's future).
//! * [`foresight`]: a yardstick predictor for a planner under test, between constant velocity
//!   and the recorded future.
//! * [`bench`](mod@bench): methods as planner factories, suites, the parallel deterministic runner.
//! * [`config`]: the benchmark TOML and suite building.
//! * [`report`], [`figures`]: `results.csv`, `report.md` and the PNGs; [`stats`]: the paired
//!   tests, intervals and density bins the report uses.
//! * [`plan_figure`]: one planning step from an episode, drawn like the paper's Fig. 4.
//! * [`compare`]: a method of one run against a method of another, paired run by run.
//! * [`record`]: runs and planning calls as MCAP logs for Foxglove.
//! * [`rosbag`]: ROS 2 bags in MCAP storage, read (CDR decoded with the bag's definitions) and
//!   written (`human2nav replay`).
//! * [`shard`]: a benchmark spread over machines (`bench --shard K/N`, `bench --merge`).

#![warn(missing_docs)]

pub mod bench;
pub mod compare;
pub mod config;
pub mod crowd;
pub mod driver;
pub mod episode;
pub mod error;
pub mod figures;
pub mod foresight;
mod human_likeness;
pub mod metrics;
pub mod oracle;
pub mod plan_figure;
pub mod record;
pub mod replay;
pub mod report;
pub mod rosbag;
pub mod runner;
pub mod shard;
pub mod stats;
pub mod straight;

pub use bench::{MethodSpec, PlannerContext, ResultRow, Suite, SuiteKind, run_bench};
pub use crowd::{CrowdModel, SocialForce};
pub use error::SimError;
/// The progress bar type the benchmark reports to (re-exported so callers need no direct
/// dependency; `ProgressBar::hidden()` for silence).
pub use indicatif::ProgressBar;
pub use metrics::EpisodeMetrics;
pub use runner::{
    Contact, EpisodeRun, Outcome, RobotSetup, SimConfig, run_episode, run_episode_with,
};
