//! Embodiments: how a robot moves. A kinematic model step, command saturation to the robot's
//! limits, and a PD tracking controller that turns a planned trajectory into commands.
//!
//! Commands are body-frame twists `(v_x, v_y, ω)` for every embodiment; a differential-drive or
//! Ackermann robot simply cannot realise `v_y ≠ 0`, and an Ackermann robot's steering angle is
//! implied by the curvature `ω / v_x`.

use crate::planner::Plan;
use crate::se2::{Pose2, Twist2};

/// The robot's state as the simulator and controllers see it.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct RobotState {
    pub pose: Pose2,
    /// Body-frame velocity actually executed during the last step.
    pub velocity: Twist2,
}

/// A way of moving.
pub trait Embodiment: Send + Sync {
    /// A short, stable name (`differential_drive`, `ackermann`, `omnidirectional`, ...).
    fn name(&self) -> &str;

    /// Whether the robot can move sideways (`v_y ≠ 0`).
    fn holonomic(&self) -> bool;

    /// Clips a commanded twist to what the robot can do from `state` within `dt`
    /// (speed, reverse speed, yaw rate, curvature, lateral speed and acceleration limits).
    fn saturate(&self, state: &RobotState, cmd: Twist2, dt: f64) -> Twist2;

    /// Advances the kinematic model by `dt` under an already saturated command.
    fn step(&self, state: &RobotState, cmd: Twist2, dt: f64) -> RobotState;

    /// The tracking controller: the (unsaturated) command that follows `plan` at time `t`.
    fn track(&self, state: &RobotState, plan: &Plan, t: f64) -> Twist2;
}
