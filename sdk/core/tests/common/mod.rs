//! Scenes shared by the planner tests.

use human2nav_core::{AgentState, Observation, Pose2, Twist2};

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
