//! The crowd around the robot during a run: recorded pedestrians replayed as they walked
//! ([`CrowdModel::Replay`], the paper's protocol), or replayed but responding to the robot
//! ([`CrowdModel::Reactive`]).
//!
//! # The reactive crowd
//!
//! Each pedestrian follows its recorded track and reacts to the robot only (the recording
//! already holds how people reacted to each other), by the social force model of Helbing &
//! Molnár ([`human2nav_core::social_force`], with their parameters) with a driving term whose
//! desired velocity pulls the pedestrian back onto the recording:
//!
//! ```text
//! v_des = v_rec(t) + (p_rec(t) − p) / T_return          capped at |v_des| ≤ v_cap
//! a     = (v_des − v) / τ  +  w(φ) · (V0/σ) · exp(−d / σ) · n
//! ```
//!
//! * `p_rec`, `v_rec`: the recorded position and velocity at `t` ([`crate::replay`]);
//!   `v_cap = 1.3 · max(|v_rec|, 0.5 m/s)`, at most the speed a recorded track may have
//!   ([`TRACK_SPEED_LIMIT`], under the bound every observation is checked against);
//! * `d`: the clearance from the pedestrian's disc to the robot's footprint (the collision
//!   body the simulator checks), `n` the unit direction from the centre of the nearest
//!   footprint shape to the pedestrian (the circular specification's centre-to-centre
//!   direction; a flat face's normal would push a walker meeting it head-on straight back);
//! * `T_return = 1 s` (ours, not from the literature): a pedestrian pushed off its recorded
//!   path walks back onto it over about a second, hurrying at up to `v_cap` to catch up with
//!   where the recording is by then.
//!
//! A pedestrian the robot does not affect (repulsion below 0.01 m/s², that is, more than about
//! 2 m from the robot's footprint) and who is back on its recording (within 1 cm and
//! 5 cm/s) is replayed exactly, so a reactive run differs from the replay only near the robot.
//! Pedestrians appear and disappear when their recorded tracks do. What a planner observes
//! (positions, velocities and the 0.1 s history) is the simulated crowd; the velocity, as in a
//! replay, is the last step's, never the recording's next segment.

use crate::episode::{AgentTrack, Episode};
use crate::replay::{CrowdReplay, PedestrianSample};
use human2nav_core::robot::footprint::{self, FootprintShape};
pub use human2nav_core::social_force::SocialForce;
use human2nav_core::{AgentState, Pose2};
use human2nav_data::resample::TRACK_SPEED_LIMIT;

/// How the pedestrians of a suite behave.
#[derive(Clone, Debug, Default, PartialEq)]
pub enum CrowdModel {
    /// Replayed exactly as recorded (non-reactive).
    #[default]
    Replay,
    /// Recorded paths with a social-force response to the robot (module docs).
    Reactive(SocialForce),
}

impl CrowdModel {
    /// `replay` or `reactive`.
    pub fn name(&self) -> &'static str {
        match self {
            CrowdModel::Replay => "replay",
            CrowdModel::Reactive(_) => "reactive",
        }
    }
}

/// Below this repulsion (m/s²) the robot does not affect a pedestrian.
const ENGAGE: f64 = 0.01;
/// A pedestrian this close to its recording (m, m/s) is back on it.
const REJOIN_POSITION: f64 = 0.01;
const REJOIN_VELOCITY: f64 = 0.05;

/// One simulated pedestrian of a reactive crowd.
#[derive(Clone, Debug)]
struct Walker {
    position: [f64; 2],
    velocity: [f64; 2],
    /// Off its recording (simulated rather than replayed).
    displaced: bool,
    /// Positions at the episode's step, oldest first (the last one at or before the current
    /// time), for what the planners observe.
    history: Vec<[f64; 2]>,
    /// Track sample index of the last history entry.
    history_index: Option<usize>,
}

/// The crowd during one run: where everyone is at the current step.
#[derive(Debug)]
pub struct Crowd<'a> {
    replay: CrowdReplay<'a>,
    force: Option<SocialForce>,
    /// Per track of the episode (reactive only), `None` while the track is absent.
    walkers: Vec<Option<Walker>>,
    /// Who is present now, in track order.
    present: Vec<PedestrianSample>,
    time: f64,
}

impl<'a> Crowd<'a> {
    /// The crowd of `episode` at time 0.
    pub fn new(episode: &'a Episode, model: &CrowdModel) -> Self {
        let mut crowd = Self {
            replay: CrowdReplay::new(episode),
            force: match model {
                CrowdModel::Replay => None,
                CrowdModel::Reactive(f) => Some(*f),
            },
            walkers: vec![None; episode.agents.len()],
            present: Vec::new(),
            time: 0.0,
        };
        crowd.refresh(0.0, None, 0.0);
        crowd
    }

    /// True for a reactive crowd.
    pub fn is_reactive(&self) -> bool {
        self.force.is_some()
    }

    /// Everyone present at the current time, in track order.
    pub fn present(&self) -> &[PedestrianSample] {
        &self.present
    }

    /// Advances the crowd to `t`, `dt` after the current time, with the robot (its footprint
    /// at `robot`) as it was during the step. A replayed crowd ignores the robot.
    pub fn advance(&mut self, t: f64, robot: &[FootprintShape], pose: Pose2) {
        let dt = t - self.time;
        self.refresh(t, Some((robot, pose)), dt);
    }

    fn refresh(&mut self, t: f64, robot: Option<(&[FootprintShape], Pose2)>, dt: f64) {
        self.time = t;
        let episode = self.replay.episode();
        let Some(force) = self.force else {
            self.present = self.replay.at(t);
            return;
        };
        self.present.clear();
        for (k, track) in episode.agents.iter().enumerate() {
            let Some(rec) = self.replay.sample(track, t) else {
                self.walkers[k] = None;
                continue;
            };
            let walker = self.walkers[k].get_or_insert_with(|| Walker {
                position: rec.position,
                velocity: rec.velocity,
                displaced: false,
                history: Vec::new(),
                history_index: None,
            });
            let push = match (robot, dt > 0.0) {
                (Some((shapes, pose)), true) => repulsion(&force, shapes, pose, walker, &rec),
                _ => [0.0, 0.0],
            };
            let engaged = push[0].hypot(push[1]) >= ENGAGE;
            if engaged || walker.displaced {
                step_walker(&force, walker, &rec, push, dt);
                let back = dist(walker.position, rec.position) < REJOIN_POSITION
                    && dist(walker.velocity, rec.velocity) < REJOIN_VELOCITY;
                walker.displaced = engaged || !back;
            }
            if !walker.displaced {
                walker.position = rec.position;
                walker.velocity = rec.velocity;
            }
            record_history(walker, track, episode.dt, t);
            self.present.push(PedestrianSample {
                position: walker.position,
                velocity: walker.velocity,
                ..rec
            });
        }
    }

    /// The pedestrian `id` at the current time, if present.
    pub fn get(&self, id: u64) -> Option<&PedestrianSample> {
        self.present.iter().find(|p| p.id == id)
    }

    /// How long pedestrian `id`'s track has existed at the current time (s).
    pub fn age(&self, id: u64) -> Option<f64> {
        let episode = self.replay.episode();
        let track = episode.agents.iter().find(|a| a.id == id)?;
        Some(self.time - track.start_step as f64 * episode.dt)
    }

    /// The pedestrians present within `range` of `centre` as a planner observes them, with up
    /// to `history_len` positions at the episode's step (see [`CrowdReplay::observe`]). The
    /// velocity is causal: a walker on its recording is seen with the recording's
    /// [`CrowdReplay::observed_velocity`], a displaced one with the velocity of its last step.
    pub fn observe(&self, centre: [f64; 2], range: f64, history_len: usize) -> Vec<AgentState> {
        if self.force.is_none() {
            return self.replay.observe(self.time, centre, range, history_len);
        }
        let episode = self.replay.episode();
        let mut out = Vec::new();
        for (walker, track) in self.walkers.iter().zip(&episode.agents) {
            let Some(w) = walker else { continue };
            if dist(w.position, centre) > range {
                continue;
            }
            let from = w.history.len().saturating_sub(history_len);
            let velocity = if w.displaced {
                w.velocity
            } else {
                // On its recording: `w.position` is the recorded position at this time.
                self.replay.velocity_into(track, self.time, w.position)
            };
            out.push(AgentState {
                id: track.id,
                position: w.position,
                velocity,
                radius: track.radius,
                history: w.history[from..].to_vec(),
            });
        }
        out
    }
}

/// `p` (world frame) in the body frame of `pose`.
fn to_body(pose: Pose2, p: [f64; 2]) -> [f64; 2] {
    let (s, c) = pose.theta.sin_cos();
    let (dx, dy) = (p[0] - pose.x, p[1] - pose.y);
    [c * dx + s * dy, -s * dx + c * dy]
}

fn dist(a: [f64; 2], b: [f64; 2]) -> f64 {
    (a[0] - b[0]).hypot(a[1] - b[1])
}

/// The robot's push on `walker` (m/s²; module docs).
fn repulsion(
    force: &SocialForce,
    shapes: &[FootprintShape],
    pose: Pose2,
    walker: &Walker,
    rec: &PedestrianSample,
) -> [f64; 2] {
    let p = walker.position;
    let d = footprint::clearance_at(shapes, pose, p, rec.radius);
    if !d.is_finite() {
        return [0.0, 0.0];
    }
    let magnitude = force.magnitude(d, rec.radius);
    if magnitude < 0.1 * ENGAGE {
        return [0.0, 0.0];
    }
    // The circular specification's direction: from the centre of the nearest body shape to
    // the pedestrian. (The normal of a flat face would push a walker who meets it head-on
    // straight back, never around.)
    let body = to_body(pose, p);
    let nearest = shapes
        .iter()
        .min_by(|x, y| x.signed_distance(body).total_cmp(&y.signed_distance(body)));
    let centre = match nearest {
        Some(FootprintShape::Disc { center, .. } | FootprintShape::Rect { center, .. }) => {
            let (sn, cs) = pose.theta.sin_cos();
            [
                pose.x + cs * center[0] - sn * center[1],
                pose.y + sn * center[0] + cs * center[1],
            ]
        }
        None => [pose.x, pose.y],
    };
    let (dx, dy) = (p[0] - centre[0], p[1] - centre[1]);
    let r = dx.hypot(dy);
    let n = if r > 1e-12 {
        [dx / r, dy / r]
    } else {
        [1.0, 0.0]
    };
    // Anisotropy: the walker's own velocity, or the recording's when it is nearly still; a
    // walker slower than 5 cm/s either way sees the robot wherever it is.
    let heading = if walker.velocity[0].hypot(walker.velocity[1]) > 0.05 {
        walker.velocity
    } else {
        rec.velocity
    };
    let heading = if heading[0].hypot(heading[1]) > 0.05 {
        heading
    } else {
        [0.0, 0.0]
    };
    let weight = force.weight(heading, n);
    [weight * magnitude * n[0], weight * magnitude * n[1]]
}

/// One semi-implicit Euler step of a displaced walker.
fn step_walker(
    force: &SocialForce,
    walker: &mut Walker,
    rec: &PedestrianSample,
    push: [f64; 2],
    dt: f64,
) {
    // Never faster than a recorded track may move, so that every observation stays valid.
    let cap = force
        .speed_cap(rec.velocity[0].hypot(rec.velocity[1]))
        .min(TRACK_SPEED_LIMIT);
    let desired = [
        rec.velocity[0] + (rec.position[0] - walker.position[0]) / force.return_time,
        rec.velocity[1] + (rec.position[1] - walker.position[1]) / force.return_time,
    ];
    (walker.position, walker.velocity) =
        force.step(walker.position, walker.velocity, desired, push, cap, dt);
}

/// Appends the walker's position to its history each time `t` passes a sample of its track.
fn record_history(walker: &mut Walker, track: &AgentTrack, dt: f64, t: f64) {
    let index = ((t / dt - track.start_step as f64 + 1e-9).floor().max(0.0) as usize)
        .min(track.positions.len().saturating_sub(1));
    if walker.history_index == Some(index) {
        return;
    }
    // Samples passed before the walker existed (or between two steps) come from the
    // recording as long as it has not been displaced.
    let first = match walker.history_index {
        Some(i) => i + 1,
        None => 0,
    };
    for i in first..index {
        walker.history.push(track.positions[i]);
    }
    walker.history.push(if walker.displaced {
        walker.position
    } else {
        track.positions[index]
    });
    walker.history_index = Some(index);
    const KEEP: usize = 64;
    if walker.history.len() > 2 * KEEP {
        walker.history.drain(..walker.history.len() - KEEP);
    }
}
