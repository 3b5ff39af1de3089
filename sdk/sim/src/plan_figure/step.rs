//! One planning step set up from a benchmark episode: the episode read and chosen, the robot's
//! start pose and the observation at the step's time (see the module docs of `plan_figure`).

use crate::episode::Episode;
use crate::error::SimError;
use crate::replay::CrowdReplay;
use crate::runner::StartHeading;
use human2nav_core::obstacle;
use human2nav_core::{Observation, Pose2, Twist2};
use std::path::Path;

/// How a planning step is set up from an episode (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StepOptions {
    /// Episode time of the crowd (s). Default 0.
    pub time: f64,
    /// Pedestrians beyond this distance from the robot are not observed (m). Default 10, the
    /// simulator's default.
    pub sensor_range: f64,
    /// Recorded positions per observed pedestrian. Default 8 (0.8 s), the simulator's default.
    pub history_len: usize,
    /// The robot's forward speed (m/s). Default 0: an episode starts at rest.
    pub ego_speed: f64,
    /// The robot's heading. Default: facing the goal.
    pub start_heading: StartHeading,
}

impl Default for StepOptions {
    fn default() -> Self {
        Self {
            time: 0.0,
            sensor_range: 10.0,
            history_len: 8,
            ego_speed: 0.0,
            start_heading: StartHeading::FaceGoal,
        }
    }
}

impl StepOptions {
    /// Checks every field; the error names the first offending one.
    pub fn validate(&self) -> Result<(), SimError> {
        let bad = |field: &str, message: String| Err(SimError::setting("step", field, message));
        if !(self.time.is_finite() && self.time >= 0.0) {
            return bad("time", format!("must be finite and ≥ 0, got {}", self.time));
        }
        if !(self.sensor_range.is_finite() && self.sensor_range > 0.0) {
            return bad(
                "sensor_range",
                format!("must be finite and > 0, got {}", self.sensor_range),
            );
        }
        if !self.ego_speed.is_finite() {
            return bad(
                "ego_speed",
                format!("must be finite, got {}", self.ego_speed),
            );
        }
        Ok(())
    }
}

/// Reads an episode file: an [`EpisodeSuite`](crate::episode::EpisodeSuite) (`human2nav data
/// episodes`) or one [`Episode`] as JSON, through the benchmark's reader
/// ([`crate::episode::load_episode_file`]): the same files are accepted, with the same checks.
pub fn load_episodes(path: &Path) -> Result<Vec<Episode>, SimError> {
    let episodes = crate::episode::load_episode_file(path)?.episodes;
    if episodes.is_empty() {
        return Err(SimError::Empty(format!(
            "{} holds no episode",
            path.display()
        )));
    }
    Ok(episodes)
}

/// The episode with identifier `id` if given, else the one at `index`.
pub fn select_episode<'a>(
    episodes: &'a [Episode],
    index: usize,
    id: Option<&str>,
) -> Result<&'a Episode, SimError> {
    let found = match id {
        Some(id) => episodes.iter().find(|e| e.id == id),
        None => episodes.get(index),
    };
    found.ok_or_else(|| SimError::Episodes {
        suite: "episode file".into(),
        message: match id {
            Some(id) => format!("no episode with id `{id}`"),
            None => format!(
                "index {index} is out of range ({} episodes)",
                episodes.len()
            ),
        },
    })
}

/// The robot's start pose in an episode.
pub fn start_pose(episode: &Episode, heading: StartHeading) -> Pose2 {
    let s = episode.start;
    match heading {
        StartHeading::Episode => s,
        StartHeading::FaceGoal => {
            let (dx, dy) = (episode.goal[0] - s.x, episode.goal[1] - s.y);
            let theta = if dx.hypot(dy) > 1e-9 {
                dy.atan2(dx)
            } else {
                s.theta
            };
            Pose2::new(s.x, s.y, theta)
        }
    }
}

/// The observation of one planning step on `episode` (see the module docs); a time past the
/// episode's end (its `time_budget`) is an error naming the episode and its length.
pub fn observation_at(episode: &Episode, opts: &StepOptions) -> Result<Observation, SimError> {
    opts.validate()?;
    // Past the end the replayed crowd has left: a plan there would be among nobody.
    if opts.time > episode.time_budget {
        return Err(SimError::setting(
            "step",
            "time",
            format!(
                "{} s is past the end of episode `{}`, which lasts {} s",
                opts.time, episode.id, episode.time_budget
            ),
        ));
    }
    let ego = start_pose(episode, opts.start_heading);
    let agents = CrowdReplay::new(episode).observe(
        opts.time,
        [ego.x, ego.y],
        opts.sensor_range,
        opts.history_len,
    );
    Ok(Observation {
        time: opts.time,
        ego,
        ego_velocity: Twist2::new(opts.ego_speed, 0.0, 0.0),
        goal: episode.goal,
        agents,
        obstacles: obstacle::within(&episode.obstacles, [ego.x, ego.y], opts.sensor_range),
        ..Default::default()
    })
}
