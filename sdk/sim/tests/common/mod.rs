//! Hand-made episodes and the workspace robots for the simulator tests.
#![allow(dead_code)]

use human2nav_core::Pose2;
use human2nav_sim::RobotSetup;
use human2nav_sim::episode::{AgentTrack, Episode, ScenarioClass};
use std::path::PathBuf;

/// `robots/<name>/robot.toml` of the workspace.
pub fn robot(name: &str) -> RobotSetup {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../robots")
        .join(name)
        .join("robot.toml");
    RobotSetup::load(&path).expect("workspace robot profile")
}

pub fn robots() -> Vec<RobotSetup> {
    ["diablo", "go2", "ackermann"]
        .iter()
        .map(|n| robot(n))
        .collect()
}

/// An episode from (0, 0) to (5, 0) (start heading `theta`), budget 12.5 s, at 0.1 s.
pub fn episode(id: &str, scenario: ScenarioClass, theta: f64, agents: Vec<AgentTrack>) -> Episode {
    Episode {
        id: id.into(),
        scene: "test".into(),
        source: "test".into(),
        scenario,
        dt: 0.1,
        start: Pose2::new(0.0, 0.0, theta),
        goal: [5.0, 0.0],
        time_budget: 12.5,
        density: agents.len(),
        agents,
        obstacles: Vec::new(),
        human_path: Vec::new(),
    }
}

/// A pedestrian standing at `p` for `steps` samples from step 0.
pub fn standing(id: u64, p: [f64; 2], steps: usize) -> AgentTrack {
    AgentTrack {
        id,
        start_step: 0,
        positions: vec![p; steps],
        radius: 0.3,
    }
}

/// A pedestrian walking from `p0` with constant velocity `v` for `steps` samples.
pub fn walking(id: u64, p0: [f64; 2], v: [f64; 2], steps: usize) -> AgentTrack {
    let positions = (0..steps)
        .map(|k| [p0[0] + v[0] * 0.1 * k as f64, p0[1] + v[1] * 0.1 * k as f64])
        .collect();
    AgentTrack {
        id,
        start_step: 0,
        positions,
        radius: 0.3,
    }
}
