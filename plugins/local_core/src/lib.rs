//! What the sampling local planners of `plugins/` (MPPI, DWA) share, so that both read the
//! robot and the scene by one rule:
//!
//! * [`kinematics`]: the motion model read off the robot's limits (Ackermann, omnidirectional
//!   or differential drive) and the velocity bounds it implies;
//! * [`world`]: static obstacles and occupancy cells near the robot, and pedestrians walking on
//!   at constant velocity, as distances from the robot's disc;
//! * [`closed_loop`]: the small closed loop both planners' tests drive them in.
//!
//! Like `human2nav-orca-core`, it has no plugin entry point: a crate that exports a plugin
//! must not be linked into another plugin (both would define the entry symbol).

pub mod closed_loop;
pub mod kinematics;
pub mod world;

pub use kinematics::{Bounds, MotionModel, motion_model};
