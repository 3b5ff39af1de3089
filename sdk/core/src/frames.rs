//! Frames and time stamps: pedestrians as a tracker reports them, in its own frame at its own
//! time, brought into an [`Observation`]'s world frame at the observation's time.
//!
//! A robot stack usually plans in `map` or `odom` while its people tracker publishes in
//! another frame (`odom`, the camera's) with a stamp a few tens of milliseconds old.
//! [`Observation::add_tracked`] transforms each pedestrian through a chain of
//! [`FrameTransform`]s (tf2's parent → child transforms, looked up by the caller at the
//! observation's time) and moves it at its velocity from the tracker's stamp to the
//! observation's time.

use crate::planner::{AgentState, Observation, PlanError};
use crate::se2::Pose2;
use serde::{Deserialize, Serialize};
use std::collections::VecDeque;

/// Largest `|observation time − stamp|` of tracked pedestrians (s): older tracks are stale,
/// and a stamp in the future is a clock error.
pub const MAX_STAMP_OFFSET: f64 = 1.0;

/// Longest chain of transforms followed from one frame to another.
pub const MAX_FRAME_CHAIN: usize = 32;

/// Where frame `child` sits in frame `parent`: a point `p` given in `child` is `pose.act(p)`
/// in `parent` (the parent → child transform of tf2).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FrameTransform {
    /// The frame the pose is expressed in.
    pub parent: String,
    /// The frame the pose places.
    pub child: String,
    /// `child`'s origin and heading in `parent`.
    pub pose: Pose2,
}

/// Pedestrians as a tracker reports them.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TrackedAgents {
    /// The frame their positions and velocities are in.
    pub frame_id: String,
    /// The time they were observed (s, the observation's clock).
    pub stamp: f64,
    /// The pedestrians, in `frame_id` at `stamp` (histories too).
    pub agents: Vec<AgentState>,
}

/// The pose of frame `from` in frame `to` through `transforms` (each usable in either
/// direction), or `None` without a chain of at most [`MAX_FRAME_CHAIN`] links.
pub fn lookup(from: &str, to: &str, transforms: &[FrameTransform]) -> Option<Pose2> {
    // Breadth-first from `to`: the pose of each reached frame in `to`.
    let mut reached: Vec<(&str, Pose2, usize)> = vec![(to, Pose2::IDENTITY, 0)];
    let mut queue = VecDeque::from([0usize]);
    while let Some(i) = queue.pop_front() {
        let (frame, pose, depth) = reached[i];
        if frame == from {
            return Some(pose);
        }
        if depth >= MAX_FRAME_CHAIN {
            continue;
        }
        for t in transforms {
            let next = if t.parent == frame {
                Some((t.child.as_str(), pose.compose(t.pose)))
            } else if t.child == frame {
                Some((t.parent.as_str(), pose.compose(t.pose.inverse())))
            } else {
                None
            };
            if let Some((name, p)) = next {
                if reached.iter().all(|(f, _, _)| *f != name) {
                    reached.push((name, p, depth + 1));
                    queue.push_back(reached.len() - 1);
                }
            }
        }
    }
    None
}

impl Observation {
    /// Adds pedestrians reported in frame `tracked.frame_id` at `tracked.stamp`: each moves at
    /// its velocity to the observation's time, then goes through `transforms` into the
    /// observation's frame (positions, velocities and histories). Errors, naming the frames or
    /// the stamp, leave the observation unchanged: an unknown frame, a stamp more than
    /// [`MAX_STAMP_OFFSET`] s from the observation's time, a non-finite number.
    pub fn add_tracked(
        &mut self,
        tracked: &TrackedAgents,
        transforms: &[FrameTransform],
    ) -> Result<(), PlanError> {
        let bad = |m: String| Err(PlanError::InvalidObservation(m));
        let age = self.time - tracked.stamp;
        if !(age.is_finite() && age.abs() <= MAX_STAMP_OFFSET) {
            return bad(format!(
                "pedestrians in `{}` stamped {} s, {} s from the observation's time {} (at \
                 most {MAX_STAMP_OFFSET} s)",
                tracked.frame_id, tracked.stamp, age, self.time
            ));
        }
        let Some(pose) = lookup(&tracked.frame_id, &self.frame_id, transforms) else {
            let known: Vec<String> = transforms
                .iter()
                .map(|t| format!("{} → {}", t.parent, t.child))
                .collect();
            return bad(format!(
                "no chain of transforms from `{}` to the observation's frame `{}` (given: {})",
                tracked.frame_id,
                self.frame_id,
                if known.is_empty() {
                    "none".to_owned()
                } else {
                    known.join(", ")
                }
            ));
        };
        if !pose.is_finite() {
            return bad(format!(
                "the transform from `{}` to `{}` is not finite",
                tracked.frame_id, self.frame_id
            ));
        }
        let moved: Vec<AgentState> = tracked
            .agents
            .iter()
            .map(|a| {
                let at_now = a.walked_on(age);
                AgentState {
                    position: pose.act(at_now),
                    velocity: pose.rotate(a.velocity),
                    history: a.history.iter().map(|p| pose.act(*p)).collect(),
                    ..a.clone()
                }
            })
            .collect();
        let mut candidate = self.agents.clone();
        candidate.extend(moved);
        let before = std::mem::replace(&mut self.agents, candidate);
        if let Err(e) = self.validate() {
            self.agents = before;
            return Err(e);
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::FRAC_PI_2;

    fn person(x: f64, y: f64, vx: f64, vy: f64) -> AgentState {
        AgentState {
            id: 4,
            position: [x, y],
            velocity: [vx, vy],
            radius: 0.3,
            history: vec![[x - vx * 0.1, y - vy * 0.1]],
        }
    }

    fn map_odom_camera() -> Vec<FrameTransform> {
        vec![
            FrameTransform {
                parent: "map".into(),
                child: "odom".into(),
                pose: Pose2::new(10.0, 0.0, FRAC_PI_2),
            },
            FrameTransform {
                parent: "odom".into(),
                child: "camera".into(),
                pose: Pose2::new(1.0, 0.0, 0.0),
            },
        ]
    }

    #[test]
    fn pedestrians_in_another_frame_and_time_land_in_the_observation() {
        let mut obs = Observation {
            time: 5.0,
            frame_id: "map".into(),
            ..Observation::default()
        };
        let tracked = TrackedAgents {
            frame_id: "camera".into(),
            stamp: 4.9,
            agents: vec![person(2.0, 0.0, 1.0, 0.0)],
        };
        obs.add_tracked(&tracked, &map_odom_camera()).unwrap();
        // 0.1 s later at 1 m/s: (2.1, 0) in the camera, (3.1, 0) in odom, (10, 3.1) in map.
        let a = &obs.agents[0];
        assert!((a.position[0] - 10.0).abs() < 1e-12 && (a.position[1] - 3.1).abs() < 1e-12);
        assert!(a.velocity[0].abs() < 1e-12 && (a.velocity[1] - 1.0).abs() < 1e-12);
        assert!((a.history[0][1] - 2.9).abs() < 1e-12);

        // The other way round: the observation in the camera frame, people given in map.
        let mut cam = Observation {
            time: 5.0,
            frame_id: "camera".into(),
            ..Observation::default()
        };
        let in_map = TrackedAgents {
            frame_id: "map".into(),
            stamp: 5.0,
            agents: vec![person(10.0, 3.0, 0.0, 0.0)],
        };
        cam.add_tracked(&in_map, &map_odom_camera()).unwrap();
        let p = cam.agents[0].position;
        assert!((p[0] - 2.0).abs() < 1e-12 && p[1].abs() < 1e-12, "{p:?}");
    }

    #[test]
    fn unknown_frames_and_stale_stamps_are_errors_that_change_nothing() {
        let mut obs = Observation {
            time: 5.0,
            frame_id: "map".into(),
            ..Observation::default()
        };
        let lost = TrackedAgents {
            frame_id: "lidar".into(),
            stamp: 5.0,
            agents: vec![person(1.0, 0.0, 0.0, 0.0)],
        };
        let err = obs.add_tracked(&lost, &map_odom_camera()).unwrap_err();
        assert!(err.to_string().contains("`lidar`"), "{err}");
        let stale = TrackedAgents {
            frame_id: "odom".into(),
            stamp: 2.0,
            ..lost.clone()
        };
        let err = obs.add_tracked(&stale, &map_odom_camera()).unwrap_err();
        assert!(err.to_string().contains("stamped 2 s"), "{err}");
        let nan = TrackedAgents {
            frame_id: "odom".into(),
            stamp: 5.0,
            agents: vec![person(f64::NAN, 0.0, 0.0, 0.0)],
        };
        assert!(obs.add_tracked(&nan, &map_odom_camera()).is_err());
        assert!(obs.agents.is_empty());
    }
}
