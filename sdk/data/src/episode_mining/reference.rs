//! The straight-driving reference robot of the interaction criterion and the criterion itself:
//! whether it meets someone of an episode's replayed crowd at every reference speed.

use super::InteractionOptions;
use crate::scenario::{Episode, dist};

/// The straight-driving reference robot of the interaction criterion (module docs): at rest at
/// t = 0, constant acceleration up to `speed`, then constant speed to the goal, where it stops.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ReferenceRobot {
    /// Nominal speed, m/s.
    pub speed: f64,
    /// Acceleration from rest, m/s².
    pub accel: f64,
    /// Disc radius, metres.
    pub radius: f64,
}

impl ReferenceRobot {
    /// Distance driven after `t` seconds (ignoring the goal).
    pub fn distance_at(&self, t: f64) -> f64 {
        let t = t.max(0.0);
        let ta = self.speed / self.accel;
        if t <= ta {
            0.5 * self.accel * t * t
        } else {
            0.5 * self.speed * ta + self.speed * (t - ta)
        }
    }

    /// The time it takes to drive `distance`, seconds.
    pub fn arrival_time(&self, distance: f64) -> f64 {
        let d_acc = 0.5 * self.speed * self.speed / self.accel;
        if distance <= d_acc {
            (2.0 * distance / self.accel).sqrt()
        } else {
            self.speed / self.accel + (distance - d_acc) / self.speed
        }
    }

    /// Its position at time `t` on the segment `start`→`goal` (the goal once reached).
    pub fn position(&self, start: [f64; 2], goal: [f64; 2], t: f64) -> [f64; 2] {
        let d = dist(start, goal);
        if d <= 0.0 {
            return start;
        }
        let f = (self.distance_at(t) / d).min(1.0);
        [
            start[0] + f * (goal[0] - start[0]),
            start[1] + f * (goal[1] - start[1]),
        ]
    }

    /// Its positions at the steps `k·dt`, `k = 0 ..=` the first step at or after arrival.
    pub fn path(&self, start: [f64; 2], goal: [f64; 2], dt: f64) -> Vec<[f64; 2]> {
        let n = (self.arrival_time(dist(start, goal)) / dt - 1e-9)
            .ceil()
            .max(0.0) as usize;
        (0..=n)
            .map(|k| self.position(start, goal, k as f64 * dt))
            .collect()
    }
}

/// Where the reference robot first met a pedestrian.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ReferenceContact {
    /// Time from the episode start, seconds.
    pub time: f64,
    /// The pedestrian's [`crate::AgentTrack::id`].
    pub agent: u64,
    /// Centre distance at that time, metres.
    pub distance: f64,
}

/// The first counted contact of the reference robot at nominal `speed` with a replayed agent
/// of `episode`, up to the instant it reaches the goal, or `None`. A contact is judged at its
/// onset (the first step of an overlap with that agent, or the agent's first sample): it
/// counts when the agent's track has existed in the episode for `opts.min_track_age` by then
/// (module docs), so a track that begins on top of the reference never counts, however long
/// it stays there.
pub fn reference_contact(
    episode: &Episode,
    speed: f64,
    opts: &InteractionOptions,
) -> Option<ReferenceContact> {
    let robot = opts.reference(speed);
    let start = [episode.start.x, episode.start.y];
    let dt = episode.dt;
    let arrival = robot.arrival_time(dist(start, episode.goal));
    let mut touching = vec![false; episode.agents.len()];
    for k in 0..=episode.steps() {
        let t = k as f64 * dt;
        if t > arrival + 1e-9 {
            break;
        }
        let p = robot.position(start, episode.goal, t);
        for (a, was) in episode.agents.iter().zip(touching.iter_mut()) {
            let q = k.checked_sub(a.start_step).and_then(|i| a.positions.get(i));
            let Some(q) = q else {
                *was = false;
                continue;
            };
            let d = dist(*q, p);
            let now = d < robot.radius + a.radius;
            let age = (k - a.start_step) as f64 * dt;
            if now && !*was && age >= opts.min_track_age - 1e-9 {
                return Some(ReferenceContact {
                    time: t,
                    agent: a.id,
                    distance: d,
                });
            }
            *was = now;
        }
    }
    None
}

/// True when the reference robot meets someone at every speed of `opts.reference_speeds`.
pub fn is_interactive(episode: &Episode, opts: &InteractionOptions) -> bool {
    opts.reference_speeds
        .iter()
        .all(|&v| reference_contact(episode, v, opts).is_some())
}
