//! The dynamic window approach (Fox, Burgard & Thrun, 1997) as a human2nav planner plugin:
//! velocities reachable within one control period, each rolled out at constant velocity and
//! scored by heading, clearance and speed. See `README.md` for the parameters and how they
//! compare with the paper's and with Nav2's DWB controller.
//!
//! The motion model rule and the obstacle and pedestrian geometry are shared with the MPPI
//! plugin through `human2nav-local-core` (`plugins/local_core`).

pub mod config;
pub mod planner;

pub use human2nav_local_core::{kinematics, world};

pub use config::DwaConfig;
pub use kinematics::{Bounds, MotionModel, motion_model};
pub use planner::{Candidate, DwaPlanner};

human2nav_plugin::export_plugin! {
    name: "dwa",
    version: env!("CARGO_PKG_VERSION"),
    factories: [
        planner(
            "dwa",
            "dynamic window approach (Fox et al. 1997): heading, clearance and velocity"
        ) => DwaPlanner::from_init,
    ],
}
