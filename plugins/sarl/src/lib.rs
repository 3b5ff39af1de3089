//! SARL (socially attentive reinforcement learning, Chen et al. 2019 — the paper's second
//! baseline) as a human2nav planner plugin, with its training.
//!
//! * [`state`]: robot and human states and the rotation into the robot-centric frame.
//! * [`net`]: the value network (pairwise embedding, attention pooling, value head) in tch.
//! * [`action`]: the 81 holonomic actions (5 exponentially spaced speeds × 16 headings + stop).
//! * [`env`](mod@env): the circle-crossing environment with ORCA humans, and the CrowdNav reward.
//! * [`policy`]: the one-step look-ahead action selection.
//! * [`eval`]: whole episodes with SARL, straight-to-goal or ORCA, and outcome rates.
//! * [`train`]: imitation on ORCA demonstrations, then TD learning; checkpoints and resume.
//! * [`card`], [`plot`]: the model card and the training-curve figure of `models/sarl`.
//! * [`planner`]: [`SarlPlanner`], the [`human2nav_core::Planner`] (holonomic velocity →
//!   constant-velocity plan, as ORCA's).
//!
//! Inference runs on the CPU; no tch type crosses the plugin boundary. The crate builds both as
//! a Rust library and as a `cdylib` plugin (libtorch found through an rpath baked in by
//! `build.rs`).

pub mod action;
pub mod card;
pub mod env;
pub mod error;
pub mod eval;
pub mod net;
pub mod planner;
pub mod plot;
pub mod policy;
pub mod state;
pub mod train;

pub use error::SarlError;
pub use planner::{SarlConfig, SarlModel, SarlPlanner};

human2nav_plugin::export_plugin! {
    name: "sarl",
    version: env!("CARGO_PKG_VERSION"),
    factories: [
        planner(
            "sarl",
            "SARL attention value network, one-step look-ahead over 81 holonomic actions, constant-velocity plan"
        ) => SarlPlanner::from_init,
    ],
}
