//! Non-reactive pedestrian replay: recorded tracks interpolated to any simulation time.
//!
//! A track with samples `q_0 … q_{n−1}` at times `t_k = (start_step + k)·dt` is *present* for
//! `t ∈ [t_0, t_{n−1}]` (a single-sample track only at `t_0`, within half a simulation step).
//! Between samples the position is interpolated linearly; the velocity of [`CrowdReplay::sample`]
//! is the finite difference of the segment containing `t` (`(q_{k+1} − q_k)/dt`; the last
//! segment at the final sample; zero for a single sample). Pedestrians never react to the robot.
//!
//! What a planner observes ([`CrowdReplay::observe`]) is causal: the position at `t`, the
//! history up to the last sample not after `t`, and the velocity over the last step
//! ([`CrowdReplay::observed_velocity`]), as a tracker would estimate it. The segment velocity of
//! `sample` is the one the pedestrian moves with next, 0.1 s of the future at the planners'
//! instants; it serves the collision bookkeeping, never an observation.

use crate::episode::{AgentTrack, Episode};
use human2nav_core::AgentState;

/// Tolerance on presence tests, in units of the episode step.
const PRESENCE_EPS: f64 = 1e-9;

/// One pedestrian's state at a given time.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PedestrianSample {
    /// The pedestrian's id in the episode.
    pub id: u64,
    /// Position (m, world frame).
    pub position: [f64; 2],
    /// Velocity (m/s, world frame).
    pub velocity: [f64; 2],
    /// Body radius (m).
    pub radius: f64,
}

/// Replays an episode's pedestrians.
#[derive(Clone, Copy, Debug)]
pub struct CrowdReplay<'a> {
    episode: &'a Episode,
}

impl<'a> CrowdReplay<'a> {
    /// A replay of `episode`'s recorded pedestrians.
    pub fn new(episode: &'a Episode) -> Self {
        Self { episode }
    }

    /// The episode being replayed.
    pub fn episode(&self) -> &'a Episode {
        self.episode
    }

    /// The state of `track` at time `t`, or `None` when it is not present then.
    pub fn sample(&self, track: &AgentTrack, t: f64) -> Option<PedestrianSample> {
        let dt = self.episode.dt;
        let n = track.positions.len();
        if n == 0 || dt.is_nan() || dt <= 0.0 || !t.is_finite() {
            return None;
        }
        // Position along the track in (fractional) samples.
        let s = t / dt - track.start_step as f64;
        if s < -PRESENCE_EPS || s > (n - 1) as f64 + PRESENCE_EPS {
            return None;
        }
        if n == 1 {
            return Some(PedestrianSample {
                id: track.id,
                position: track.positions[0],
                velocity: [0.0, 0.0],
                radius: track.radius,
            });
        }
        let s = s.clamp(0.0, (n - 1) as f64);
        let k = (s.floor() as usize).min(n - 2);
        let f = s - k as f64;
        let (a, b) = (track.positions[k], track.positions[k + 1]);
        Some(PedestrianSample {
            id: track.id,
            position: [a[0] + f * (b[0] - a[0]), a[1] + f * (b[1] - a[1])],
            velocity: [(b[0] - a[0]) / dt, (b[1] - a[1]) / dt],
            radius: track.radius,
        })
    }

    /// The velocity of `track` at `t` as a tracker estimates it from what it has seen: the
    /// displacement over the last step, `(p(t) − p(t − dt))/dt` (from the track's first sample
    /// while it is younger than a step), zero at the first sample, `None` when the track is
    /// not present at `t`. It uses positions at `t` and before only.
    pub fn observed_velocity(&self, track: &AgentTrack, t: f64) -> Option<[f64; 2]> {
        let now = self.sample(track, t)?;
        Some(self.velocity_into(track, t, now.position))
    }

    /// [`Self::observed_velocity`] of a present track whose position at `t` is `now`.
    pub(crate) fn velocity_into(&self, track: &AgentTrack, t: f64, now: [f64; 2]) -> [f64; 2] {
        let dt = self.episode.dt;
        let back = (t - dt).max(track.start_step as f64 * dt);
        let span = t - back;
        match self.sample(track, back) {
            Some(before) if span > PRESENCE_EPS * dt => [
                (now[0] - before.position[0]) / span,
                (now[1] - before.position[1]) / span,
            ],
            _ => [0.0, 0.0],
        }
    }

    /// Every pedestrian present at `t`, in track order.
    pub fn at(&self, t: f64) -> Vec<PedestrianSample> {
        self.episode
            .agents
            .iter()
            .filter_map(|tr| self.sample(tr, t))
            .collect()
    }

    /// The pedestrians present at `t` within `range` of `centre` (centre distance), as the
    /// planner observes them: the position at `t`, the [`Self::observed_velocity`] and up to
    /// `history_len` recorded positions (at the episode's step, oldest first, ending at the last
    /// sample not after `t`). At a sample time (the planners' instants at 10 Hz) nothing in it
    /// depends on the recording after `t`; between samples the position is the pedestrian's
    /// interpolated position at `t`, which the next sample shapes as it shapes the simulated
    /// world.
    pub fn observe(
        &self,
        t: f64,
        centre: [f64; 2],
        range: f64,
        history_len: usize,
    ) -> Vec<AgentState> {
        let dt = self.episode.dt;
        let mut out = Vec::new();
        for tr in &self.episode.agents {
            let Some(s) = self.sample(tr, t) else {
                continue;
            };
            let (dx, dy) = (s.position[0] - centre[0], s.position[1] - centre[1]);
            if dx.hypot(dy) > range {
                continue;
            }
            let history = if history_len == 0 {
                Vec::new()
            } else {
                let idx = ((t / dt - tr.start_step as f64 + PRESENCE_EPS)
                    .floor()
                    .max(0.0) as usize)
                    .min(tr.positions.len() - 1);
                let from = (idx + 1).saturating_sub(history_len);
                tr.positions[from..=idx].to_vec()
            };
            out.push(AgentState {
                id: s.id,
                position: s.position,
                velocity: self.velocity_into(tr, t, s.position),
                radius: s.radius,
                history,
            });
        }
        out
    }

    /// The last time any pedestrian is present (0 for an empty episode).
    pub fn end_time(&self) -> f64 {
        let dt = self.episode.dt;
        self.episode
            .agents
            .iter()
            .filter(|t| !t.positions.is_empty())
            .map(|t| (t.start_step + t.positions.len() - 1) as f64 * dt)
            .fold(0.0, f64::max)
    }
}
