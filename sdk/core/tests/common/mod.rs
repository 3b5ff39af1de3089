//! The robot and scenes shared by the planner tests (each test crate uses part of them).
#![allow(dead_code)]

use human2nav_core::constraint::Phi;
use human2nav_core::human2nav::RobotModel;
use human2nav_core::robot::footprint::FootprintShape;
use human2nav_core::{AgentState, GuidanceWeights, Limits, Observation, Pose2, Twist2};

/// The test robot's limits.
pub fn limits() -> Limits {
    Limits {
        v_max: 1.0,
        v_reverse_max: 0.3,
        a_max: 1.0,
        omega_max: 1.0,
        kappa_max: None,
        lateral_speed_max: 0.05,
        coupled: None,
    }
}

/// The test robot's footprint: a disc about its reference point (m).
pub const ROBOT_RADIUS: f64 = 0.3;

/// The test robot: [`limits`], a disc of [`ROBOT_RADIUS`], Φ of the default weights.
pub fn robot() -> RobotModel {
    let limits = limits();
    RobotModel {
        limits,
        footprint: vec![FootprintShape::Disc {
            center: [0.0, 0.0],
            radius: ROBOT_RADIUS,
        }],
        phi: Phi::from_weights(&GuidanceWeights::default(), &limits),
    }
}

/// The robot at the origin at 0.5 m/s towards a goal `goal_x` m straight ahead, and somebody
/// standing 2 m ahead, where every sample of a model walking straight goes.
pub fn someone_ahead(goal_x: f64) -> Observation {
    Observation {
        time: 0.0,
        ego: Pose2::IDENTITY,
        ego_velocity: Twist2::new(0.5, 0.0, 0.0),
        goal: [goal_x, 0.0],
        agents: vec![AgentState {
            id: 1,
            position: [2.0, 0.0],
            velocity: [0.0, 0.0],
            radius: 0.3,
            history: vec![],
        }],
        ..Default::default()
    }
}
