//! human2nav: crowd-navigation planning that learns from human trajectories and adapts to the
//! robot at hand. This crate is the one to depend on: it re-exports the SDK's crates under
//! short module names and gathers what a first program needs in [`prelude`].
//!
//! | module | crate | what it holds |
//! |---|---|---|
//! | [`core`] | `human2nav-core` | SE(2), robot profiles and limits, constraint terms, guidance, the `Planner` trait, the reference planner |
//! | [`data`] | `human2nav-data` | dataset loaders, training tuples, benchmark episodes, the synthetic crowd |
//! | [`plugin`] | `human2nav-plugin` | the plugin C ABI, [`plugin::export_plugin!`] for authors, the host that loads libraries |
//! | [`flow`] | `human2nav-flow` | the flow-matching model and a planner built from a robot profile and a model folder (feature `flow`; training and the libtorch backend with feature `torch`) |
//! | [`sim`] | `human2nav-sim` | the closed-loop simulator, the benchmark, its report and figures (feature `sim`) |
//!
//! `flow` and `sim` are on by default and need no libtorch: the planner runs its network on
//! the SDK's own kernels. The `torch` feature adds libtorch (training, the reference network,
//! the `torch` planner backend). A plugin library needs none of them: depend on this crate with
//! `default-features = false`.
//!
//! # libtorch at run time
//!
//! With the `torch` feature (or when another package of the same build turns on
//! `human2nav-flow/torch`, as the workspace's CLI does), programs link libtorch. This crate's
//! build script passes
//! libtorch's directory to the build scripts of its direct dependents as
//! `DEP_HUMAN2NAV_LIBTORCH_LIB`; a program bakes it in as an rpath with a three-line
//! `build.rs` (as `examples/quickstart` does):
//!
//! ```text
//! fn main() {
//!     if let Ok(dir) = std::env::var("DEP_HUMAN2NAV_LIBTORCH_LIB") {
//!         println!("cargo::rustc-link-arg=-Wl,-rpath,{dir}");
//!     }
//! }
//! ```

#![warn(missing_docs)]

pub use human2nav_core as core;
pub use human2nav_data as data;
#[cfg(feature = "flow")]
pub use human2nav_flow as flow;
pub use human2nav_plugin as plugin;
#[cfg(feature = "sim")]
pub use human2nav_sim as sim;

/// What a first program needs, in one `use human2nav::prelude::*;`.
///
/// * describing the robot and the scene: [`RobotProfile`](prelude::RobotProfile),
///   [`Limits`](prelude::Limits), [`Pose2`](prelude::Pose2), [`Twist2`](prelude::Twist2),
///   [`Observation`](prelude::Observation), [`AgentState`](prelude::AgentState),
///   [`Obstacle`](prelude::Obstacle);
/// * planning: the [`Planner`](prelude::Planner) trait, [`Plan`](prelude::Plan), and with the
///   `flow` feature [`PlannerConfig`](prelude::PlannerConfig) (`sdk/configs/planner.toml`) and
///   [`RobotPlanner`](prelude::RobotPlanner), the reference planner built from a robot profile
///   and the shipped model;
/// * scoring a plan: [`feasibility_mask`](prelude::feasibility_mask),
///   [`tfs_plan`](prelude::tfs_plan);
/// * episodes: [`Episode`](prelude::Episode), [`ScenarioClass`](prelude::ScenarioClass),
///   [`synthetic_episodes`](prelude::synthetic_episodes) (no dataset needed),
///   [`find_workspace_root`](prelude::find_workspace_root);
/// * with the `sim` feature, a closed loop ([`run_episode`](prelude::run_episode),
///   [`SimConfig`](prelude::SimConfig), [`RobotSetup`](prelude::RobotSetup)) and one planning
///   step drawn like the paper's Fig. 4 ([`draw_plan_figure`](prelude::draw_plan_figure));
/// * writing a plugin: [`ConstraintTerm`](prelude::ConstraintTerm),
///   [`Embodiment`](prelude::Embodiment), [`PluginInit`](prelude::PluginInit) and
///   [`export_plugin!`](prelude::export_plugin).
pub mod prelude {
    pub use human2nav_core::constraint::{
        ConstraintContext, ConstraintError, ConstraintTerm, TrajBatch,
    };
    pub use human2nav_core::embodiment::Embodiment;
    pub use human2nav_core::feasibility::{feasibility_mask, tfs_plan};
    pub use human2nav_core::human2nav::{GuidanceTerms, Human2Nav, Human2NavSettings};
    pub use human2nav_core::obstacle::Obstacle;
    pub use human2nav_core::robot::RobotProfile;
    pub use human2nav_core::{
        AgentState, Deadline, FlowModel, Limits, Observation, Plan, PlanError, PlanInfo, Planner,
        Pose2, Twist2,
    };
    pub use human2nav_data::paths::find_workspace_root;
    pub use human2nav_data::synthetic::episodes as synthetic_episodes;
    pub use human2nav_data::{Episode, EpisodeSuite, ScenarioClass};
    pub use human2nav_plugin::{InitError, PluginHost, PluginInit, export_plugin};

    #[cfg(feature = "flow")]
    pub use human2nav_flow::planner::{Backend, PlannerConfig, PlannerError, RobotPlanner};

    #[cfg(feature = "sim")]
    pub use human2nav_sim::episode::load_episode_file;
    #[cfg(feature = "sim")]
    pub use human2nav_sim::plan_figure::{
        PlanFigure, PlanFigureNumbers, StepOptions, draw_plan_figure, observation_at,
    };
    #[cfg(feature = "sim")]
    pub use human2nav_sim::{EpisodeRun, Outcome, RobotSetup, SimConfig, run_episode};
}
