//! The planner interface: an [`Observation`] of the world goes in, a [`Plan`] comes out.
//!
//! Human2Nav, ORCA and SARL all implement [`Planner`]; the simulator, the CLI and robot
//! integrations only ever see this trait, so a plugin planner and a built-in are used alike.
//! All quantities are SI and in the world frame unless a field says otherwise.

use crate::obstacle::{Obstacle, OccupancyGrid};
use crate::se2::{Pose2, Twist2};
use serde::{Deserialize, Serialize};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// Another agent (a pedestrian) as the robot perceives it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct AgentState {
    /// Stable identity within an episode.
    pub id: u64,
    /// Position `[x, y]` in metres, world frame.
    pub position: [f64; 2],
    /// Velocity `[v_x, v_y]` in m/s, world frame.
    pub velocity: [f64; 2],
    /// Radius of the disc used for collision checks, metres.
    pub radius: f64,
    /// Recent positions, oldest first, at the episode's time step (may be empty).
    #[serde(default)]
    pub history: Vec<[f64; 2]>,
}

impl AgentState {
    /// Where the agent is `t` seconds on, walking on at its velocity (constant velocity,
    /// [`crate::forecast::walk_on`]).
    pub fn walked_on(&self, t: f64) -> [f64; 2] {
        crate::forecast::walk_on(self.position, self.velocity, t)
    }
}

/// The frame an observation is in when it does not say: `"world"`.
pub const DEFAULT_FRAME: &str = "world";

fn default_frame() -> String {
    DEFAULT_FRAME.to_owned()
}

/// Everything a planner may use at one planning instant.
///
/// Every pose, position and velocity is in one world-fixed frame, [`Observation::frame_id`]
/// (the "world frame" of the field docs), at [`Observation::time`]; the robot's velocity is in
/// its body frame. Pedestrians a tracker reports in another frame or at another time are added
/// with [`Observation::add_tracked`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Observation {
    /// Simulation or wall-clock time in seconds.
    pub time: f64,
    /// Name of the world frame of this observation (`map`, `odom`, ...). Default `"world"`.
    #[serde(default = "default_frame")]
    pub frame_id: String,
    /// The robot's pose in the world frame.
    pub ego: Pose2,
    /// The robot's body-frame velocity.
    pub ego_velocity: Twist2,
    /// The goal position `[x, y]` in the world frame.
    pub goal: [f64; 2],
    /// The other agents in view.
    pub agents: Vec<AgentState>,
    /// Static obstacles in the world frame (walls, pillars, parked carts).
    #[serde(default)]
    pub obstacles: Vec<Obstacle>,
    /// A static occupancy grid in the world frame (its occupied cells are obstacles too).
    #[serde(default)]
    pub occupancy: Option<OccupancyGrid>,
}

impl Default for Observation {
    /// The robot at rest at the origin of the world frame, the goal there too, nothing around.
    fn default() -> Self {
        Self {
            time: 0.0,
            frame_id: default_frame(),
            ego: Pose2::IDENTITY,
            ego_velocity: Twist2::ZERO,
            goal: [0.0, 0.0],
            agents: Vec::new(),
            obstacles: Vec::new(),
            occupancy: None,
        }
    }
}

/// Diagnostics a planner may attach to its plan (all optional, for figures and reports).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PlanInfo {
    /// Candidate trajectories before any guidance, world frame, each `T` poses.
    pub candidates: Vec<Vec<Pose2>>,
    /// Candidate trajectories after guidance, world frame (empty when guidance is off).
    pub guided: Vec<Vec<Pose2>>,
    /// Index in `candidates` of the sample whose path the plan follows (`None` when the plan
    /// follows none of them, e.g. a kept previous plan or braking to a stop).
    pub selected: Option<usize>,
    /// Φ of the selected trajectory before guidance (`None` when the plan follows no sample).
    pub phi_before: Option<f64>,
    /// Φ of the selected trajectory after guidance (`None` when the plan follows no sample).
    pub phi_after: Option<f64>,
    /// Algorithm 1 iterations run for this plan (`None` when guidance did not run).
    pub guidance_iterations: Option<usize>,
    /// True when the planner fell back to its documented safe behaviour (stop in place).
    pub fallback: bool,
    /// Free-form notes (why a fallback happened, for instance).
    pub notes: Vec<String>,
    /// Set when this plan is a substitute because the planner failed (a plugin planner that
    /// missed its deadline gets the stop-in-place plan with this set): callers count it as a
    /// failed planner call, not as the planner's own fallback.
    pub error: Option<String>,
    /// How far each stage of an anytime planner got ([`Planner::plan_within`]); `None` for a
    /// planner without stages.
    pub stages: Option<Stages>,
    /// What is wrong with the robot's own state that the planner planned through anyway: the
    /// robot starts overlapping an obstacle, or faster than its limits. An observation is
    /// refused ([`Observation::validate`]) only when no robot could be in it; these states a
    /// real robot can reach (pushed into a table, odometry glitches), and a plan (braking at
    /// worst) is still wanted, so the planner that knows the robot flags them here instead.
    pub warnings: Vec<String>,
}

/// A stage of an anytime planning call, in the order they run.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Stage {
    /// Integrating the flow model from the source samples.
    Sampling,
    /// Algorithm 1's iterations.
    Guidance,
    /// The last-step correction (one QP per candidate).
    Correction,
}

impl Stage {
    /// Lower-case name used in reports (`sampling`, `guidance`, `correction`).
    pub fn name(self) -> &'static str {
        match self {
            Stage::Sampling => "sampling",
            Stage::Guidance => "guidance",
            Stage::Correction => "correction",
        }
    }
}

impl std::fmt::Display for Stage {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// How much of one stage ran: `done` of `planned` units (integration steps, iterations or
/// candidates).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct StageProgress {
    /// Units completed.
    pub done: usize,
    /// Units the stage would have run without a deadline (0: the stage is off).
    pub planned: usize,
}

impl StageProgress {
    /// True when every planned unit ran.
    pub fn complete(&self) -> bool {
        self.done >= self.planned
    }
}

/// Which stages of an anytime planning call ran, and how far.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Stages {
    /// Integration steps of the flow model that ran (the rest, if any, was extrapolated).
    pub sampling: StageProgress,
    /// Algorithm 1 iterations completed.
    pub guidance: StageProgress,
    /// Candidates the last-step correction ran on.
    pub correction: StageProgress,
    /// The first stage the deadline cut short (`None`: the call finished every stage).
    pub cut_short: Option<Stage>,
}

/// When an anytime planning call must return its best plan so far.
///
/// A planner checks it before each unit of work (a network call, a QP) and never starts one
/// after it has passed. Clone it freely: a clock-based deadline is a copy of an instant.
#[derive(Clone, Default)]
pub struct Deadline(DeadlineKind);

#[derive(Clone, Default)]
enum DeadlineKind {
    #[default]
    Never,
    At(Instant),
    Probe(Arc<dyn Fn() -> bool + Send + Sync>),
}

impl Deadline {
    /// No deadline: every stage runs to completion.
    pub fn never() -> Self {
        Self(DeadlineKind::Never)
    }

    /// The deadline is the instant `at` of the monotonic clock.
    pub fn at(at: Instant) -> Self {
        Self(DeadlineKind::At(at))
    }

    /// The deadline is `budget` from now; a zero budget still lets a planner return its
    /// safe plan.
    pub fn after(budget: Duration) -> Self {
        Self(DeadlineKind::At(Instant::now() + budget))
    }

    /// The deadline has passed when `passed()` says so: for a clock of the caller's own, such as
    /// simulated time or a robot middleware's clock. `passed` must be cheap; it is called before
    /// every unit of work.
    pub fn from_fn(passed: impl Fn() -> bool + Send + Sync + 'static) -> Self {
        Self(DeadlineKind::Probe(Arc::new(passed)))
    }

    /// True once the deadline has passed.
    pub fn passed(&self) -> bool {
        match &self.0 {
            DeadlineKind::Never => false,
            DeadlineKind::At(at) => Instant::now() >= *at,
            DeadlineKind::Probe(passed) => passed(),
        }
    }

    /// True for [`Deadline::never`].
    pub fn is_never(&self) -> bool {
        matches!(self.0, DeadlineKind::Never)
    }
}

impl std::fmt::Debug for Deadline {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match &self.0 {
            DeadlineKind::Never => f.write_str("Deadline::never()"),
            DeadlineKind::At(at) => {
                let left = at.saturating_duration_since(Instant::now());
                write!(f, "Deadline(in {left:?})")
            }
            DeadlineKind::Probe(_) => f.write_str("Deadline::from_fn(..)"),
        }
    }
}

/// A planned trajectory in the world frame: `poses[k]` is the target at `t0 + k·dt`.
#[derive(Clone, Debug, PartialEq)]
pub struct Plan {
    /// Time of the first pose, s (the observation's time).
    pub t0: f64,
    /// Time between poses, s.
    pub dt: f64,
    /// `poses[0]` is the robot's pose at `t0`.
    pub poses: Vec<Pose2>,
    /// Diagnostics: candidates, Φ, stages, notes.
    pub info: PlanInfo,
}

impl Plan {
    /// The "stop in place" plan: every waypoint equals the current pose.
    pub fn stop_in_place(
        obs: &Observation,
        dt: f64,
        horizon: usize,
        why: impl Into<String>,
    ) -> Plan {
        Plan {
            t0: obs.time,
            dt,
            poses: vec![obs.ego; horizon.max(1)],
            info: PlanInfo {
                fallback: true,
                notes: vec![why.into()],
                ..PlanInfo::default()
            },
        }
    }

    /// Time covered by the plan, `(T − 1)·dt`.
    pub fn duration(&self) -> f64 {
        self.dt * self.poses.len().saturating_sub(1) as f64
    }

    /// True when every pose is finite (a planner must never return anything else).
    pub fn is_finite(&self) -> bool {
        self.t0.is_finite() && self.dt.is_finite() && self.poses.iter().all(|p| p.is_finite())
    }
}

/// Why a planner could not produce a plan.
#[derive(Debug, thiserror::Error)]
pub enum PlanError {
    /// The observation has a non-finite or negative field (named in the message); the caller
    /// must fix it.
    #[error("invalid observation: {0}")]
    InvalidObservation(String),
    /// The planner's settings are out of range (the field is named in the message).
    #[error("invalid planner settings: {0}")]
    InvalidSettings(String),
    /// The planner failed on this call (a plugin planner's error, say).
    #[error("planner `{planner}` failed: {message}")]
    Failed {
        /// The planner's name.
        planner: String,
        /// Its explanation.
        message: String,
    },
    /// The planner refuses every call after an earlier failure (a panic, a crashed helper
    /// process that was restarted too often).
    #[error("planner `{planner}` is unusable after an earlier failure: {message}")]
    Unusable {
        /// The planner's name.
        planner: String,
        /// What happened.
        message: String,
    },
}

/// Observation → plan. Implementations must never return a plan with a non-finite value.
pub trait Planner: Send {
    /// A short, stable name used in reports (`human2nav`, `orca`, `sarl`, ...).
    fn name(&self) -> &str;

    /// Forgets any state carried between calls (warm starts), at the start of an episode.
    fn reset(&mut self) {}

    /// Plans from one observation.
    fn plan(&mut self, obs: &Observation) -> Result<Plan, PlanError>;

    /// Plans from one observation, returning the best plan found when `deadline` passes.
    ///
    /// An anytime planner (Human2Nav) starts no network call after the deadline and always
    /// returns a plan it considers safe, reporting how far it got in [`PlanInfo::stages`]. A
    /// planner whose cost is small and fixed (ORCA, SARL, plugins) may ignore the deadline:
    /// that is what this provided method does.
    fn plan_within(&mut self, obs: &Observation, deadline: &Deadline) -> Result<Plan, PlanError> {
        let _ = deadline;
        self.plan(obs)
    }
}

/// Largest `|coordinate|` (m) of a position in an observation: the bound on datasets,
/// episodes and obstacles ([`crate::obstacle::MAX_OBSTACLE_COORDINATE`]).
pub const MAX_COORDINATE: f64 = crate::obstacle::MAX_OBSTACLE_COORDINATE;

/// Largest speed (m/s) of the robot or of an agent in an observation: several times anything
/// that moves in a crowd; a faster one is a unit error, not a scene.
pub const MAX_SPEED: f64 = 30.0;

impl Observation {
    /// Checks every number is finite, positions within [`MAX_COORDINATE`] and speeds within
    /// [`MAX_SPEED`]; names the first offending field. Every front end (the CLI, the C API,
    /// Python) plans through this check.
    pub fn validate(&self) -> Result<(), PlanError> {
        let bad = |what: String| Err(PlanError::InvalidObservation(what));
        let far = |p: [f64; 2]| p.iter().any(|v| v.abs() > MAX_COORDINATE);
        let fast = |v: [f64; 2]| v[0].hypot(v[1]) > MAX_SPEED;
        if !self.time.is_finite() {
            return bad("time is not finite".into());
        }
        if !self.ego.is_finite() {
            return bad("ego pose is not finite".into());
        }
        if far([self.ego.x, self.ego.y]) {
            return bad(format!(
                "ego pose is more than {MAX_COORDINATE} m from the origin"
            ));
        }
        if !self.ego_velocity.is_finite() {
            return bad("ego velocity is not finite".into());
        }
        if fast([self.ego_velocity.vx, self.ego_velocity.vy]) {
            return bad(format!("ego velocity is faster than {MAX_SPEED} m/s"));
        }
        if !self.goal.iter().all(|v| v.is_finite()) {
            return bad("goal is not finite".into());
        }
        if far(self.goal) {
            return bad(format!(
                "goal is more than {MAX_COORDINATE} m from the origin"
            ));
        }
        for a in &self.agents {
            let finite = a.position.iter().chain(&a.velocity).all(|v| v.is_finite())
                && a.radius.is_finite()
                && a.radius >= 0.0;
            if !finite {
                return bad(format!("agent {} has a non-finite or negative field", a.id));
            }
            if far(a.position) || fast(a.velocity) {
                return bad(format!(
                    "agent {} is more than {MAX_COORDINATE} m from the origin or faster than \
                     {MAX_SPEED} m/s",
                    a.id
                ));
            }
        }
        for (i, o) in self.obstacles.iter().enumerate() {
            o.validate()
                .or_else(|why| bad(format!("obstacles[{i}]: {why}")))?;
        }
        if let Some(grid) = &self.occupancy {
            grid.validate()
                .or_else(|why| bad(format!("occupancy: {why}")))?;
        }
        Ok(())
    }
}
