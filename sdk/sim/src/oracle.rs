//! `oracle`: a clairvoyant reference planner. It reads the episode's recorded crowd, so in a
//! replayed suite it knows where every pedestrian will be for the next seconds, and searches the
//! robot's own motions for one that keeps clear of all of them.
//!
//! It is not a method to compare planners with but a yardstick for the suites: on a replayed
//! crowd, which does not react to the robot, some collisions cannot be avoided at all (a
//! pedestrian walking straight at a robot that cannot get out of the way in time), and the
//! oracle's success rate estimates how many episodes can be solved with perfect prediction.
//! It is a search over a finite set of motions, so it bounds the attainable success rate from
//! below: an episode it fails may still have a solution outside its candidate set. In a reactive
//! suite the crowd departs from its recording near the robot, so there its knowledge is only
//! approximately right.
//!
//! Each call rolls out the robot's own motions ([`human2nav_core::motions`]: two-segment twist
//! profiles from its current pose and body velocity, the first segment `switch_time` long, up to
//! `horizon` seconds; `speed_levels`, `turn_levels` and `lateral_levels` size the grid). Every
//! pair of targets is tried, or `max_candidates` of them spread evenly over all pairs when there
//! are more. Every rolled-out motion is within the robot's limits, so the simulator's tracking
//! follows it closely.
//!
//! With `prediction = "constant_velocity"` the same search sees only what a planner sees: the
//! pedestrians of the observation, each extrapolated at its observed velocity. The two settings
//! separate what prediction is worth from what the search over motions is worth.
//! `prediction = "seen"` lies between them: the recorded future of the pedestrians the robot
//! observes now, and nothing of those it cannot see yet (out of sensor range, or not yet in the
//! recording). It is what perfect prediction of the observed crowd would give, so the gap from
//! it to the oracle is what no predictor, however good, can close.
//!
//! A motion is scored by its first contact: a pose whose footprint comes within `margin` of a
//! pedestrian's disc (at that pose's time, from the recording) or of a static obstacle. Motions
//! without contact beat every motion with one; among those, a later contact is better. Ties are
//! broken by the closest approach to the goal along the motion (0 once within `goal_tolerance`,
//! where the motion ends: no contact after it counts), then by how early it comes.

use crate::episode::Episode;
use crate::error::SimError;
use crate::replay::CrowdReplay;
use human2nav_core::motions::{GridLevels, MotionGrid, Target};
use human2nav_core::obstacle::footprint_clearance;
use human2nav_core::robot::footprint::{FootprintShape, clearance_at, reach};
use human2nav_core::{Limits, Observation, Plan, PlanError, PlanInfo, Planner, Pose2};
use serde::{Deserialize, Serialize};

/// Where the search takes the pedestrians' future from.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Prediction {
    /// The episode's recording (exact in a replayed crowd): the oracle.
    #[default]
    Recorded,
    /// The observed pedestrians at their observed velocities: what a planner can know.
    ConstantVelocity,
    /// The recorded future of the pedestrians observed now (by id); nobody else: perfect
    /// prediction of what the robot sees.
    Seen,
}

/// Settings of the clairvoyant planner.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct OracleConfig {
    /// Where the pedestrians' future comes from. Default `recorded`.
    pub prediction: Prediction,
    /// How far ahead a motion is rolled out and checked (s). Default 4.
    pub horizon: f64,
    /// Spacing of the plan's poses (s). Default 0.1.
    pub plan_dt: f64,
    /// Duration of the first segment (s). Default 1.
    pub switch_time: f64,
    /// Forward speed targets per segment (at least 2). Default 7.
    pub speed_levels: usize,
    /// Turn targets per segment (odd, so that straight is one; at least 1). Default 7.
    pub turn_levels: usize,
    /// Sideways speed targets per segment for an omnidirectional robot (odd; at least 1).
    /// Default 3.
    pub lateral_levels: usize,
    /// Clearance below which a pose counts as a contact (m). Default 0.05.
    pub margin: f64,
    /// Most motions rolled out per call. Default 3000.
    pub max_candidates: usize,
    /// A motion that comes this close to the goal ends there: contacts after it do not count
    /// (m). Default 0.3; the benchmark sets its goal tolerance.
    pub goal_tolerance: f64,
}

impl Default for OracleConfig {
    fn default() -> Self {
        Self {
            prediction: Prediction::Recorded,
            horizon: 4.0,
            plan_dt: 0.1,
            switch_time: 1.0,
            speed_levels: 7,
            turn_levels: 7,
            lateral_levels: 3,
            margin: 0.05,
            max_candidates: 3000,
            goal_tolerance: 0.3,
        }
    }
}

/// Largest number of plan poses ([`OracleConfig::horizon`] / [`OracleConfig::plan_dt`]).
pub const MAX_POSES: usize = 1000;

/// Largest number of levels of one grid axis.
pub const MAX_LEVELS: usize = 101;

/// Largest [`OracleConfig::max_candidates`].
pub const MAX_CANDIDATES: usize = 1_000_000;

impl OracleConfig {
    /// Checks every field; the error names the offending one.
    pub fn validate(&self) -> Result<(), SimError> {
        let bad = |field: &str, msg: String| Err(SimError::setting("oracle", field, msg));
        for (field, v) in [
            ("horizon", self.horizon),
            ("plan_dt", self.plan_dt),
            ("switch_time", self.switch_time),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return bad(field, format!("must be finite and > 0, got {v}"));
            }
        }
        for (field, v) in [
            ("margin", self.margin),
            ("goal_tolerance", self.goal_tolerance),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return bad(field, format!("must be finite and >= 0, got {v}"));
            }
        }
        let poses = self.poses();
        if !(2..=MAX_POSES).contains(&poses) {
            return bad(
                "horizon",
                format!(
                    "horizon / plan_dt must give 1 to {} steps, got {poses} poses",
                    MAX_POSES - 1
                ),
            );
        }
        if !(2..=MAX_LEVELS).contains(&self.speed_levels) {
            return bad(
                "speed_levels",
                format!("must be in 2..={MAX_LEVELS}, got {}", self.speed_levels),
            );
        }
        for (field, n) in [
            ("turn_levels", self.turn_levels),
            ("lateral_levels", self.lateral_levels),
        ] {
            if n % 2 == 0 || n > MAX_LEVELS {
                return bad(
                    field,
                    format!("must be odd and at most {MAX_LEVELS}, got {n}"),
                );
            }
        }
        if !(1..=MAX_CANDIDATES).contains(&self.max_candidates) {
            return bad(
                "max_candidates",
                format!(
                    "must be in 1..={MAX_CANDIDATES}, got {}",
                    self.max_candidates
                ),
            );
        }
        Ok(())
    }

    /// Number of plan poses, `poses[0]` (the robot now) included.
    fn poses(&self) -> usize {
        (self.horizon / self.plan_dt).round() as usize + 1
    }
}

/// The clairvoyant planner (name `oracle`) of one episode.
#[derive(Clone, Debug)]
pub struct OraclePlanner {
    cfg: OracleConfig,
    grid: MotionGrid,
    footprint: Vec<FootprintShape>,
    /// Radius about the base-link origin that covers the footprint (broad phase).
    cover: f64,
    episode: Episode,
}

impl OraclePlanner {
    /// The oracle of `episode` for a robot with `limits` and `footprint` (base-link frame).
    pub fn new(
        cfg: OracleConfig,
        limits: Limits,
        footprint: Vec<FootprintShape>,
        episode: Episode,
    ) -> Result<Self, SimError> {
        cfg.validate()?;
        if footprint.is_empty() {
            return Err(SimError::setting(
                "oracle",
                "footprint",
                "the robot has no footprint",
            ));
        }
        let cover = reach(&footprint);
        let grid = MotionGrid::new(
            limits,
            GridLevels {
                speed: cfg.speed_levels,
                turn: cfg.turn_levels,
                lateral: cfg.lateral_levels,
            },
        );
        Ok(Self {
            cfg,
            grid,
            footprint,
            cover,
            episode,
        })
    }

    /// Rolls out `pair` into `poses` (`poses[0]` is the robot).
    fn rollout(&self, obs: &Observation, pair: (Target, Target), poses: &mut Vec<Pose2>) {
        let switch = (self.cfg.switch_time / self.cfg.plan_dt).round().max(1.0) as usize;
        let steps = self.cfg.poses() - 1;
        poses.clear();
        poses.push(obs.ego);
        self.grid.rollout(
            obs.ego,
            obs.ego_velocity,
            pair,
            switch,
            self.cfg.plan_dt,
            steps,
            poses,
        );
    }

    /// Index of the first pose of `poses` up to `last` that touches a pedestrian or an
    /// obstacle (`crowd[k]`: the pedestrians at pose `k`'s time).
    fn first_contact(
        &self,
        obs: &Observation,
        crowd: &[Vec<([f64; 2], f64)>],
        poses: &[Pose2],
        last: usize,
    ) -> Option<usize> {
        let margin = self.cfg.margin;
        (1..=last.min(poses.len() - 1)).find(|&k| {
            let p = poses[k];
            let hits_person = crowd[k].iter().any(|&(q, r)| {
                let reach = self.cover + r + margin;
                let (dx, dy) = (q[0] - p.x, q[1] - p.y);
                dx * dx + dy * dy < reach * reach && clearance_at(&self.footprint, p, q, r) < margin
            });
            hits_person
                || obs
                    .obstacles
                    .iter()
                    .any(|o| footprint_clearance(&self.footprint, p, o) < margin)
        })
    }
}

/// A motion's score: lower is better (module docs).
#[derive(Clone, Copy, Debug, PartialEq, PartialOrd)]
struct Score {
    /// 0 without contact, else `1 / (index of the first contact)`.
    contact: f64,
    /// Closest distance to the goal along the motion (m).
    goal_distance: f64,
    /// Index of that pose.
    when: usize,
}

impl Planner for OraclePlanner {
    fn name(&self) -> &str {
        match self.cfg.prediction {
            Prediction::Recorded => "oracle",
            Prediction::ConstantVelocity => "search-cv",
            Prediction::Seen => "oracle-seen",
        }
    }

    fn plan(&mut self, obs: &Observation) -> Result<Plan, PlanError> {
        obs.validate()?;
        let n = self.cfg.poses();
        // Where everybody will be at each pose's time.
        let replay = CrowdReplay::new(&self.episode);
        let seen = |id: u64| obs.agents.iter().any(|a| a.id == id);
        let crowd: Vec<Vec<([f64; 2], f64)>> = (0..n)
            .map(|k| {
                let dt = k as f64 * self.cfg.plan_dt;
                match self.cfg.prediction {
                    Prediction::Recorded | Prediction::Seen => replay
                        .at(obs.time + dt)
                        .into_iter()
                        .filter(|s| self.cfg.prediction == Prediction::Recorded || seen(s.id))
                        .map(|s| (s.position, s.radius))
                        .collect(),
                    Prediction::ConstantVelocity => obs
                        .agents
                        .iter()
                        .map(|a| (a.walked_on(dt), a.radius))
                        .collect(),
                }
            })
            .collect();
        let mut poses = Vec::with_capacity(n);
        let mut best: Option<(Score, Vec<Pose2>)> = None;
        for pair in self.grid.spread(self.cfg.max_candidates) {
            self.rollout(obs, pair, &mut poses);
            let distance = |p: &Pose2| (p.x - obs.goal[0]).hypot(p.y - obs.goal[1]);
            // A motion that arrives ends there (distance 0 from then on); else its closest
            // approach counts.
            let (when, goal_distance) = match poses
                .iter()
                .position(|p| distance(p) <= self.cfg.goal_tolerance)
            {
                Some(k) => (k, 0.0),
                None => poses
                    .iter()
                    .enumerate()
                    .map(|(k, p)| (k, distance(p)))
                    .min_by(|a, b| a.1.total_cmp(&b.1))
                    .unwrap_or((0, f64::INFINITY)),
            };
            let last = if goal_distance == 0.0 { when } else { n - 1 };
            let contact = self
                .first_contact(obs, &crowd, &poses, last)
                .map_or(0.0, |k| 1.0 / k as f64);
            let score = Score {
                contact,
                goal_distance,
                when,
            };
            if best.as_ref().is_none_or(|(b, _)| score < *b) {
                best = Some((score, poses.clone()));
            }
        }
        let (score, poses) = best.ok_or_else(|| PlanError::Failed {
            planner: "oracle".into(),
            message: "no candidate motions".into(),
        })?;
        let mut info = PlanInfo::default();
        if score.contact > 0.0 {
            info.notes.push(format!(
                "every motion touches someone; the first contact is {:.1} s away at best",
                self.cfg.plan_dt / score.contact
            ));
        }
        Ok(Plan {
            t0: obs.time,
            dt: self.cfg.plan_dt,
            poses,
            info,
        })
    }
}
