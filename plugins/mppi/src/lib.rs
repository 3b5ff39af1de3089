//! MPPI (model predictive path integral control) as a human2nav planner plugin, after ROS 2
//! Nav2's MPPI controller: Gaussian-perturbed control sequences around the previous optimum,
//! rolled out through the robot's motion model, scored by critics and averaged with softmax
//! weights. See `README.md` for the parameters and how they compare with Nav2's.
//!
//! * [`kinematics`]: the motion model read off the robot's limits, and the velocity bounds;
//! * [`world`]: static obstacles and occupancy cells near the robot, pedestrians at constant
//!   velocity (both from `human2nav-local-core`, shared with the DWA plugin);
//! * [`config`]: the settings; [`planner`]: the algorithm.

pub mod config;
pub mod planner;

pub use human2nav_local_core::{kinematics, world};

pub use config::MppiConfig;
pub use kinematics::{Bounds, MotionModel, motion_model};
pub use planner::MppiPlanner;

human2nav_plugin::export_plugin! {
    name: "mppi",
    version: env!("CARGO_PKG_VERSION"),
    factories: [
        planner(
            "mppi",
            "MPPI after Nav2: sampled control sequences, critics, softmax-weighted update"
        ) => MppiPlanner::from_init,
    ],
}
