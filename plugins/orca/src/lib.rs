//! ORCA (optimal reciprocal collision avoidance, van den Berg et al. 2011) as a human2nav
//! planner, with the semantics of the RVO2 library.
//!
//! * [`lp`]: RVO2's incremental 2-D linear programs, solved exactly.
//! * [`orca`]: neighbour selection, ORCA half-planes and the new velocity of one agent.
//! * [`planner`]: [`OrcaPlanner`], the [`human2nav_core::Planner`] that turns the ORCA velocity
//!   into a plan the robot's tracking controller follows (the documented holonomic → embodiment
//!   conversion).
//!
//! The crate builds both as a Rust library (tests and direct use) and as a `cdylib` plugin.

pub mod lp;
pub mod orca;
pub mod planner;

pub use planner::{OrcaConfig, OrcaError, OrcaPlanner};

human2nav_plugin::export_plugin! {
    name: "orca",
    version: env!("CARGO_PKG_VERSION"),
    factories: [
        planner(
            "orca",
            "ORCA reciprocal collision avoidance (RVO2 semantics), constant-velocity plan"
        ) => OrcaPlanner::from_init,
    ],
}
