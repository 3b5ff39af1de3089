//! Scenario classes, benchmark episodes and their mining from real scenes.
//!
//! # Classification (thresholds in [`ClassifyOptions`])
//! The reference direction `u` is the unit vector from the ego's start to its goal. Each
//! relevant other agent whose mean velocity (over the time it is relevant) exceeds
//! `moving_speed` (0.3 m/s) votes by the angle `α` between its velocity and `u`:
//! co-flow if `|α| ≤ 45°`, counter-flow if `|α| ≥ 135°`, cross-flow otherwise. Slower agents
//! do not vote. The window's class is the flow holding at least `dominant_share` (70 %) of the
//! votes; when no flow reaches that share the class is multidirection-flow; with no vote at
//! all the window is unclassified.
//!
//! # Density
//! An other agent is relevant when it comes within `density_radius` (3 m) of the ego
//! pedestrian's real position at some step between the start and the moment the ego reaches
//! the goal. The density is the number of relevant agents (any class, moving or not).
//!
//! # Episodes (rules in [`MiningOptions`])
//! From every ego pedestrian of a held-out scene, at starts spaced so that one ego's episodes
//! never overlap: the start pose is the ego's pose, the goal is its position at the first step
//! at which it is `goal_distance` (5 m) from the start in a straight line (within
//! `max_goal_time` = 10 s), and the time budget is `budget_factor · distance / reference_speed`
//! (2.5 · 5 m / 1 m/s = 12.5 s): a robot driving straight at 1 m/s needs 40 % of it in an empty
//! world. The episode is kept when the whole budget lies inside the recording, no other agent
//! comes within `min_start_clearance` (1.5 m) of the start during the first `start_window`
//! (1.5 s), and the density is within `[min_density, max_density]` (1–15). The start rule
//! keeps out episodes no method can pass: the pedestrians are replayed non-reactively, so one
//! who walks through the start point (often the ego's companion in a group) would hit a robot
//! that has not yet had time to accelerate away; 1.5 m is the contact distance of the largest
//! shipped footprint (0.90 m) with a pedestrian (0.30 m), plus 0.30 m. The exported agents are every other track present
//! during the budget that comes within `export_radius` (10 m) of the start→goal segment,
//! replayed non-reactively; the ego itself is removed (the robot replaces it).

mod classes;
mod episode;
mod mining;
mod selection;
#[cfg(test)]
mod tests;

pub use classes::{ClassifyOptions, ScenarioClass, classify, flow_of};
pub use episode::{
    AgentTrack, EPISODES_VERSION, Episode, EpisodeSuite, MAX_EPISODE_DT, MAX_TIME_BUDGET,
    MIN_EPISODE_DT,
};
#[cfg(test)]
pub(crate) use mining::test_track;
pub use mining::{MiningOptions, MiningStats, Reject, mine_scene, try_episode};
pub(crate) use mining::{
    dist, export_agents, goal_index, positive, relevant_agents, start_blocked,
};
pub use selection::{select, select_across_scenes};
