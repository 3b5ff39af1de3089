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

use crate::error::DataError;
use crate::resample::{Scene, StepIndex, Track};
use crate::track::AgentClass;
use human2nav_core::Pose2;
use rand::SeedableRng;
use rand::seq::SliceRandom;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::Path;

/// The four crowd scenarios of the paper (Figs. 4, 6, 8).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ScenarioClass {
    /// The crowd moves with the robot (`|α| ≤ 45°`, module docs).
    CoFlow,
    /// The crowd crosses the robot's path.
    CrossFlow,
    /// The crowd comes toward the robot (`|α| ≥ 135°`).
    CounterFlow,
    /// No direction holds the dominant share of the votes.
    MultidirectionFlow,
}

impl ScenarioClass {
    /// All classes in a fixed order.
    pub const ALL: [ScenarioClass; 4] = [
        Self::CoFlow,
        Self::CrossFlow,
        Self::CounterFlow,
        Self::MultidirectionFlow,
    ];

    /// The snake_case name used in files and reports.
    pub fn name(self) -> &'static str {
        match self {
            Self::CoFlow => "co_flow",
            Self::CrossFlow => "cross_flow",
            Self::CounterFlow => "counter_flow",
            Self::MultidirectionFlow => "multidirection_flow",
        }
    }

    /// Position in [`ScenarioClass::ALL`].
    pub fn index(self) -> usize {
        self as usize
    }

    /// Inverse of [`ScenarioClass::index`].
    pub fn from_index(i: usize) -> Option<Self> {
        Self::ALL.get(i).copied()
    }

    /// Parses a snake_case name.
    pub fn parse(s: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|c| c.name() == s)
    }
}

impl std::fmt::Display for ScenarioClass {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// Thresholds of the flow classification (module docs).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ClassifyOptions {
    /// Agents slower than this (m/s) do not vote. Default 0.3.
    pub moving_speed: f64,
    /// `|α|` up to this many degrees is co-flow. Default 45.
    pub co_angle_deg: f64,
    /// `|α|` from this many degrees on is counter-flow. Default 135.
    pub counter_angle_deg: f64,
    /// Share of votes a flow needs to name the window. Default 0.7.
    pub dominant_share: f64,
}

impl Default for ClassifyOptions {
    fn default() -> Self {
        Self {
            moving_speed: 0.3,
            co_angle_deg: 45.0,
            counter_angle_deg: 135.0,
            dominant_share: 0.7,
        }
    }
}

impl ClassifyOptions {
    /// Checks the thresholds are consistent.
    pub fn validate(&self) -> Result<(), DataError> {
        if !(self.moving_speed.is_finite() && self.moving_speed >= 0.0) {
            return Err(DataError::option(
                "classify.moving_speed",
                "must be finite and >= 0",
            ));
        }
        if !(0.0 < self.co_angle_deg
            && self.co_angle_deg <= self.counter_angle_deg
            && self.counter_angle_deg < 180.0)
        {
            return Err(DataError::option(
                "classify.co_angle_deg",
                "need 0 < co_angle_deg <= counter_angle_deg < 180",
            ));
        }
        if !(self.dominant_share > 0.5 && self.dominant_share <= 1.0) {
            return Err(DataError::option(
                "classify.dominant_share",
                "must be in (0.5, 1]",
            ));
        }
        Ok(())
    }
}

/// The flow one agent votes for, or `None` when it is (nearly) standing.
pub fn flow_of(
    direction: [f64; 2],
    velocity: [f64; 2],
    opts: &ClassifyOptions,
) -> Option<ScenarioClass> {
    let speed = velocity[0].hypot(velocity[1]);
    let norm = direction[0].hypot(direction[1]);
    let moving = speed > opts.moving_speed && norm > 0.0;
    if !moving {
        return None;
    }
    let cos = (velocity[0] * direction[0] + velocity[1] * direction[1]) / (speed * norm);
    let alpha = cos.clamp(-1.0, 1.0).acos().to_degrees();
    Some(if alpha <= opts.co_angle_deg {
        ScenarioClass::CoFlow
    } else if alpha >= opts.counter_angle_deg {
        ScenarioClass::CounterFlow
    } else {
        ScenarioClass::CrossFlow
    })
}

/// Classifies a window from the reference direction and the relevant agents' velocities.
pub fn classify(
    direction: [f64; 2],
    velocities: impl IntoIterator<Item = [f64; 2]>,
    opts: &ClassifyOptions,
) -> Option<ScenarioClass> {
    let mut votes = [0usize; 3];
    for v in velocities {
        match flow_of(direction, v, opts) {
            Some(ScenarioClass::CoFlow) => votes[0] += 1,
            Some(ScenarioClass::CrossFlow) => votes[1] += 1,
            Some(ScenarioClass::CounterFlow) => votes[2] += 1,
            _ => {}
        }
    }
    let total: usize = votes.iter().sum();
    if total == 0 {
        return None;
    }
    let flows = [
        ScenarioClass::CoFlow,
        ScenarioClass::CrossFlow,
        ScenarioClass::CounterFlow,
    ];
    for (k, &n) in votes.iter().enumerate() {
        if n as f64 >= opts.dominant_share * total as f64 {
            return Some(flows[k]);
        }
    }
    Some(ScenarioClass::MultidirectionFlow)
}

/// A non-reactive agent replayed during an episode.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AgentTrack {
    /// The agent's identity in its scene.
    pub id: u64,
    /// First step index (from the episode start) at which the agent exists.
    pub start_step: usize,
    /// World-frame positions, one per `dt` from `start_step`.
    pub positions: Vec<[f64; 2]>,
    /// Body radius, metres.
    pub radius: f64,
}

/// One benchmark episode: a robot start, a goal, a time budget and a replayed crowd.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Episode {
    /// Unique id within its suite (scene, ego and start time for mined episodes).
    pub id: String,
    /// The scene the crowd comes from (`dataset/scene`).
    pub scene: String,
    /// The dataset the crowd comes from (`eth`, `ucy`, `sdd`, `synthetic`).
    pub source: String,
    /// The crowd's class relative to the start→goal direction.
    pub scenario: ScenarioClass,
    /// Step of the agent tracks, seconds (0.1).
    pub dt: f64,
    /// Robot start pose, world frame.
    pub start: Pose2,
    /// Goal position, world frame.
    pub goal: [f64; 2],
    /// Time allowed to reach the goal, seconds.
    pub time_budget: f64,
    /// The crowd, replayed as recorded.
    pub agents: Vec<AgentTrack>,
    /// Number of relevant agents (module docs).
    pub density: usize,
    /// Static obstacles, world frame (walls, pillars; none in the mined real episodes).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub obstacles: Vec<human2nav_core::obstacle::Obstacle>,
    /// Where the pedestrian whose start and goal the robot takes walked, one position every
    /// `dt` from the start until they reached the goal (world frame, m): the recorded human
    /// the benchmark compares the robot's path with. Empty when the episode has none (the
    /// interaction suites put a pedestrian's walk into another moment's crowd).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub human_path: Vec<[f64; 2]>,
}

/// Largest time budget of an episode (s): an hour. The mined ones are 5–20 s; the simulator
/// keeps every step of a run, so a budget of `1e9` s asked it for tens of gigabytes.
pub const MAX_TIME_BUDGET: f64 = 3600.0;

/// Smallest step of an episode's agent tracks (s); the datasets give 0.1.
pub const MIN_EPISODE_DT: f64 = 1e-3;

/// Largest step of an episode's agent tracks (s).
pub const MAX_EPISODE_DT: f64 = 1.0;

impl Episode {
    /// Checks every number an episode file can hold, the one rule every reader applies
    /// ([`EpisodeSuite::load`], [`EpisodeSuite::load_any`], and through them the benchmark and
    /// `plan --episode`): `dt` in [[`MIN_EPISODE_DT`], [`MAX_EPISODE_DT`]], `time_budget` in
    /// (0, [`MAX_TIME_BUDGET`]], start, goal and agent positions finite and within
    /// [`MAX_COORDINATE`](crate::limits::MAX_COORDINATE) m of the origin, agent radii finite and
    /// ≥ 0, every agent track starting within [`MAX_TIME`](crate::limits::MAX_TIME) s, holding
    /// at least one position and an id no other track has. The error names the field
    /// (`agents[3].positions[7]`) and what is wrong with it.
    pub fn validate(&self) -> Result<(), (String, String)> {
        use crate::limits::{MAX_COORDINATE, MAX_TIME};
        let field = |f: &str, m: String| Err((f.to_string(), m));
        if !(self.dt.is_finite() && (MIN_EPISODE_DT..=MAX_EPISODE_DT).contains(&self.dt)) {
            return field(
                "dt",
                format!(
                    "must be in [{MIN_EPISODE_DT}, {MAX_EPISODE_DT}] s, got {}",
                    self.dt
                ),
            );
        }
        if !(self.time_budget.is_finite()
            && self.time_budget > 0.0
            && self.time_budget <= MAX_TIME_BUDGET)
        {
            return field(
                "time_budget",
                format!(
                    "must be in (0, {MAX_TIME_BUDGET}] s, got {}",
                    self.time_budget
                ),
            );
        }
        let in_range = |v: f64| v.is_finite() && v.abs() <= MAX_COORDINATE;
        let range = format!("must be finite with |v| ≤ {MAX_COORDINATE:e} m");
        if !(in_range(self.start.x) && in_range(self.start.y) && self.start.theta.is_finite()) {
            return field("start", format!("{range}, got {:?}", self.start));
        }
        if !self.goal.iter().all(|&v| in_range(v)) {
            return field("goal", format!("{range}, got {:?}", self.goal));
        }
        for (i, o) in self.obstacles.iter().enumerate() {
            o.validate()
                .or_else(|why| field(&format!("obstacles[{i}]"), why))?;
        }
        if let Some(k) = self
            .human_path
            .iter()
            .position(|p| !p.iter().all(|&v| in_range(v)))
        {
            return field(
                &format!("human_path[{k}]"),
                format!("{range}, got {:?}", self.human_path[k]),
            );
        }
        let mut ids: std::collections::HashMap<u64, usize> =
            std::collections::HashMap::with_capacity(self.agents.len());
        for (i, a) in self.agents.iter().enumerate() {
            // Two tracks of one id would be one person in two places (the replay, the BEV and
            // the metrics key people by id); a track of no positions is nobody.
            if let Some(first) = ids.insert(a.id, i) {
                return field(
                    &format!("agents[{i}].id"),
                    format!("{} is already the id of agents[{first}]", a.id),
                );
            }
            if a.positions.is_empty() {
                return field(
                    &format!("agents[{i}].positions"),
                    format!("agent {} has no positions", a.id),
                );
            }
            if !(a.radius.is_finite() && a.radius >= 0.0) {
                return field(
                    &format!("agents[{i}].radius"),
                    format!("must be finite and ≥ 0, got {}", a.radius),
                );
            }
            if a.start_step as f64 * self.dt > MAX_TIME {
                return field(
                    &format!("agents[{i}].start_step"),
                    format!(
                        "{} steps of {} s is later than {MAX_TIME} s",
                        a.start_step, self.dt
                    ),
                );
            }
            if let Some(k) = a
                .positions
                .iter()
                .position(|p| !p.iter().all(|&v| in_range(v)))
            {
                return field(
                    &format!("agents[{i}].positions[{k}]"),
                    format!("{range}, got {:?}", a.positions[k]),
                );
            }
        }
        Ok(())
    }

    /// Straight-line distance from start to goal, metres.
    pub fn goal_distance(&self) -> f64 {
        (self.goal[0] - self.start.x).hypot(self.goal[1] - self.start.y)
    }

    /// Number of steps of the episode (`ceil(time_budget / dt)`).
    pub fn steps(&self) -> usize {
        (self.time_budget / self.dt - 1e-9).ceil().max(0.0) as usize
    }
}

fn read_episode_file(path: &Path) -> Result<String, DataError> {
    human2nav_core::input::read_user_file(
        path,
        "episode file",
        crate::limits::MAX_EPISODE_FILE_BYTES,
    )
    .map_err(|e| DataError::io(path, e))
}

/// Version of the episode file format.
pub const EPISODES_VERSION: u32 = 1;

/// An episode suite as stored on disk (`episodes.json`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct EpisodeSuite {
    /// File format version ([`EPISODES_VERSION`]).
    pub version: u32,
    /// Where the episodes come from (`real: eth/eth, ucy/zara01, ...` or `synthetic`).
    pub source: String,
    /// Episodes per class.
    pub counts: BTreeMap<ScenarioClass, usize>,
    /// The episodes.
    pub episodes: Vec<Episode>,
}

impl EpisodeSuite {
    /// A suite with counts computed from its episodes.
    pub fn new(source: impl Into<String>, episodes: Vec<Episode>) -> Self {
        let mut counts: BTreeMap<ScenarioClass, usize> =
            ScenarioClass::ALL.iter().map(|c| (*c, 0)).collect();
        for e in &episodes {
            *counts.entry(e.scenario).or_default() += 1;
        }
        Self {
            version: EPISODES_VERSION,
            source: source.into(),
            counts,
            episodes,
        }
    }

    /// Writes the suite as JSON, creating parent directories. The file appears whole or not at
    /// all (written beside it, then renamed), so a benchmark reading it concurrently never sees
    /// half a suite.
    pub fn save(&self, path: &Path) -> Result<(), DataError> {
        if let Some(dir) = path.parent() {
            std::fs::create_dir_all(dir).map_err(|e| DataError::io(dir, e))?;
        }
        let body = serde_json::to_string(self).map_err(|e| DataError::Json {
            path: path.to_path_buf(),
            source: e,
        })?;
        let mut tmp = path.as_os_str().to_owned();
        tmp.push(format!(".{}.tmp", std::process::id()));
        let tmp = std::path::PathBuf::from(tmp);
        std::fs::write(&tmp, body).map_err(|e| DataError::io(&tmp, e))?;
        std::fs::rename(&tmp, path).map_err(|e| DataError::io(path, e))
    }

    /// Reads a suite (a regular file of at most
    /// [`MAX_EPISODE_FILE_BYTES`](crate::limits::MAX_EPISODE_FILE_BYTES)) and checks its
    /// version, counts and every episode ([`Episode::validate`]).
    pub fn load(path: &Path) -> Result<Self, DataError> {
        let body = read_episode_file(path)?;
        let suite: Self = serde_json::from_str(&body).map_err(|e| DataError::Json {
            path: path.to_path_buf(),
            source: e,
        })?;
        suite.check(path)?;
        Ok(suite)
    }

    /// Reads an episode file holding a suite ([`EpisodeSuite::load`]) or a single [`Episode`]
    /// (returned as a suite of one, its source the episode's), with the same checks.
    pub fn load_any(path: &Path) -> Result<Self, DataError> {
        let body = read_episode_file(path)?;
        let json = |source| DataError::Json {
            path: path.to_path_buf(),
            source,
        };
        let value: serde_json::Value = serde_json::from_str(&body).map_err(json)?;
        let suite = if value.get("episodes").is_some() {
            serde_json::from_value::<Self>(value).map_err(json)?
        } else {
            let episode = serde_json::from_value::<Episode>(value).map_err(json)?;
            Self::new(episode.source.clone(), vec![episode])
        };
        suite.check(path)?;
        Ok(suite)
    }

    /// The checks of [`EpisodeSuite::load`] on a suite read from `path`.
    fn check(&self, path: &Path) -> Result<(), DataError> {
        let bad = |message: String| DataError::Episodes {
            path: path.to_path_buf(),
            message,
        };
        if self.version != EPISODES_VERSION {
            return Err(bad(format!(
                "version: episode format version {} (this build reads {EPISODES_VERSION})",
                self.version
            )));
        }
        for (index, e) in self.episodes.iter().enumerate() {
            e.validate()
                .map_err(|(field, message)| DataError::Episode {
                    path: path.to_path_buf(),
                    index,
                    id: e.id.clone(),
                    field,
                    message,
                })?;
        }
        let recount = Self::new(self.source.clone(), Vec::new())
            .counts
            .into_keys()
            .map(|c| (c, self.episodes.iter().filter(|e| e.scenario == c).count()));
        for (c, n) in recount {
            if self.counts.get(&c).copied().unwrap_or(0) != n {
                return Err(bad(format!(
                    "counts: the header counts the {n} {c} episodes differently"
                )));
            }
        }
        Ok(())
    }
}

/// Rules for mining episodes (module docs).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct MiningOptions {
    /// Straight-line start→goal distance, metres. Default 5.
    pub goal_distance: f64,
    /// The ego must reach the goal distance within this time, seconds. Default 10.
    pub max_goal_time: f64,
    /// Budget = `budget_factor · distance / reference_speed`. Default 2.5.
    pub budget_factor: f64,
    /// Robot reference speed for the budget, m/s. Default 1.0.
    pub reference_speed: f64,
    /// Radius around the ego that makes an agent relevant, metres. Default 3.
    pub density_radius: f64,
    /// Exported agents come within this distance of the start→goal segment, metres. Default 10.
    pub export_radius: f64,
    /// No agent may come closer than this to the start during `start_window`, metres.
    /// Default 1.5.
    pub min_start_clearance: f64,
    /// How long after the start `min_start_clearance` holds, seconds (0: the first step only).
    /// Default 1.5.
    pub start_window: f64,
    /// Fewest relevant agents an episode may have (module docs, "Density").
    pub min_density: usize,
    /// Most relevant agents an episode may have.
    pub max_density: usize,
    /// Episodes per class to select. Default 50.
    pub per_class: usize,
    /// Radius of every replayed agent, metres. Default 0.3.
    pub agent_radius: f64,
    /// Seed of the selection shuffle.
    pub seed: u64,
    /// How the crowd's class is decided.
    pub classify: ClassifyOptions,
}

impl Default for MiningOptions {
    fn default() -> Self {
        Self {
            goal_distance: 5.0,
            max_goal_time: 10.0,
            budget_factor: 2.5,
            reference_speed: 1.0,
            density_radius: 3.0,
            export_radius: 10.0,
            min_start_clearance: 1.5,
            start_window: 1.5,
            min_density: 1,
            max_density: 15,
            per_class: 50,
            agent_radius: 0.3,
            seed: 7,
            classify: ClassifyOptions::default(),
        }
    }
}

/// `Ok` when `v` is finite and positive, else an error naming the option `key`.
pub(crate) fn positive(v: f64, key: &str) -> Result<(), DataError> {
    if v.is_finite() && v > 0.0 {
        Ok(())
    } else {
        Err(DataError::option(key, "must be finite and positive"))
    }
}

impl MiningOptions {
    /// Checks every option is usable.
    pub fn validate(&self) -> Result<(), DataError> {
        let pos = positive;
        pos(self.goal_distance, "episodes.goal_distance")?;
        pos(self.max_goal_time, "episodes.max_goal_time")?;
        pos(self.reference_speed, "episodes.reference_speed")?;
        pos(self.density_radius, "episodes.density_radius")?;
        pos(self.export_radius, "episodes.export_radius")?;
        pos(self.agent_radius, "episodes.agent_radius")?;
        if !(self.budget_factor.is_finite() && self.budget_factor >= 1.0) {
            return Err(DataError::option("episodes.budget_factor", "must be >= 1"));
        }
        // Upper bounds: a mined episode's budget must stay within MAX_TIME_BUDGET and every
        // step count derived from these within the scene.
        use crate::limits::{MAX_COORDINATE, MAX_TIME, option_in};
        option_in(self.budget_factor, 1.0, 100.0, "episodes.budget_factor")?;
        option_in(
            self.reference_speed,
            0.01,
            100.0,
            "episodes.reference_speed",
        )?;
        option_in(
            self.goal_distance,
            0.0,
            MAX_COORDINATE,
            "episodes.goal_distance",
        )?;
        option_in(self.max_goal_time, 0.0, MAX_TIME, "episodes.max_goal_time")?;
        option_in(self.start_window, 0.0, MAX_TIME, "episodes.start_window")?;
        for (v, f) in [
            (self.min_start_clearance, "episodes.min_start_clearance"),
            (self.start_window, "episodes.start_window"),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(DataError::option(f, "must be finite and >= 0"));
            }
        }
        if self.min_density > self.max_density {
            return Err(DataError::option(
                "episodes.min_density",
                "must not exceed max_density",
            ));
        }
        self.classify.validate()
    }

    /// The time budget for a start→goal distance, seconds.
    pub fn budget(&self, distance: f64) -> f64 {
        self.budget_factor * distance / self.reference_speed
    }
}

/// Counters of why candidate windows were rejected.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct MiningStats {
    /// Candidate windows examined.
    pub windows: usize,
    /// Rejected: [`Reject::GoalNotReached`].
    pub goal_not_reached: usize,
    /// Rejected: [`Reject::OutsideRecording`].
    pub outside_recording: usize,
    /// Rejected: [`Reject::StartBlocked`].
    pub start_blocked: usize,
    /// Rejected: [`Reject::DensityOutOfRange`].
    pub density_out_of_range: usize,
    /// Rejected: [`Reject::Unclassified`].
    pub unclassified: usize,
    /// Accepted windows per class, before the per-class selection.
    pub candidates: BTreeMap<ScenarioClass, usize>,
}

impl MiningStats {
    /// Adds another scene's counters.
    pub fn add(&mut self, o: &Self) {
        self.windows += o.windows;
        self.goal_not_reached += o.goal_not_reached;
        self.outside_recording += o.outside_recording;
        self.start_blocked += o.start_blocked;
        self.density_out_of_range += o.density_out_of_range;
        self.unclassified += o.unclassified;
        for (c, n) in &o.candidates {
            *self.candidates.entry(*c).or_default() += n;
        }
    }
}

pub(crate) fn dist(a: [f64; 2], b: [f64; 2]) -> f64 {
    (a[0] - b[0]).hypot(a[1] - b[1])
}

pub(crate) fn segment_distance(p: [f64; 2], a: [f64; 2], b: [f64; 2]) -> f64 {
    let ab = [b[0] - a[0], b[1] - a[1]];
    let l2 = ab[0] * ab[0] + ab[1] * ab[1];
    let t = if l2 > 0.0 {
        (((p[0] - a[0]) * ab[0] + (p[1] - a[1]) * ab[1]) / l2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    dist(p, [a[0] + t * ab[0], a[1] + t * ab[1]])
}

/// The agents that come within `radius` of a probe moving through the scene (the ego
/// pedestrian here, the reference robot in [`crate::interaction`]): at each `(global step,
/// probe position)`, every track present then except `exclude`. Returns (track index, mean
/// velocity over the steps it was in range), sorted by track index.
pub(crate) fn relevant_agents(
    scene: &Scene,
    index: &StepIndex,
    probe: impl IntoIterator<Item = (i64, [f64; 2])>,
    exclude: Option<usize>,
    radius: f64,
) -> Vec<(usize, [f64; 2])> {
    let mut acc: BTreeMap<usize, ([f64; 2], usize)> = BTreeMap::new();
    for (s, pe) in probe {
        for &j in index.at(s) {
            let j = j as usize;
            if Some(j) == exclude {
                continue;
            }
            let t = &scene.tracks[j];
            let Some(k) = t.local(s) else { continue };
            if dist(t.positions[k], pe) <= radius {
                let e = acc.entry(j).or_insert(([0.0, 0.0], 0));
                e.0[0] += t.velocities[k][0];
                e.0[1] += t.velocities[k][1];
                e.1 += 1;
            }
        }
    }
    acc.into_iter()
        .map(|(j, (v, n))| (j, [v[0] / n as f64, v[1] / n as f64]))
        .collect()
}

/// True when a track other than `exclude` comes within `min_start_clearance` of `start`
/// during the `start_window` after global step `s0` (module docs).
pub(crate) fn start_blocked(
    scene: &Scene,
    index: &StepIndex,
    exclude: Option<usize>,
    s0: i64,
    start: [f64; 2],
    opts: &MiningOptions,
) -> bool {
    let window = (opts.start_window / scene.dt + 1e-9).floor() as i64;
    (s0..=s0 + window).any(|step| {
        index.at(step).iter().any(|&j| {
            let j = j as usize;
            Some(j) != exclude
                && scene.tracks[j].local(step).is_some_and(|k| {
                    dist(scene.tracks[j].positions[k], start) < opts.min_start_clearance
                })
        })
    })
}

/// The local index at which track `t`, starting at local index `i0`, is first
/// `goal_distance` from its position there in a straight line, if within `max_goal_time`.
pub(crate) fn goal_index(t: &Track, i0: usize, dt: f64, opts: &MiningOptions) -> Option<usize> {
    let max_goal_steps = (opts.max_goal_time / dt).round() as usize;
    let p0 = t.positions[i0];
    (i0 + 1..t.len().min(i0 + max_goal_steps + 1))
        .find(|&i| dist(t.positions[i], p0) >= opts.goal_distance)
}

/// Why [`try_episode`] rejected a window.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Reject {
    /// The ego never gets `goal_distance` from its start within `max_goal_time`.
    GoalNotReached,
    /// The episode's time budget reaches past the end of the recording.
    OutsideRecording,
    /// Someone is too close to the start during `start_window`.
    StartBlocked,
    /// The number of relevant agents is outside `[min_density, max_density]`.
    DensityOutOfRange,
    /// No relevant agent moves fast enough to vote on a class.
    Unclassified,
}

/// The episode of ego track `ego` starting at its local index `i0` (module docs), or why
/// there is none. On success the second value is the ego's local index at the goal.
pub fn try_episode(
    scene: &Scene,
    index: &StepIndex,
    ego: usize,
    i0: usize,
    opts: &MiningOptions,
) -> Result<(Episode, usize), Reject> {
    let t = &scene.tracks[ego];
    let dt = scene.dt;
    let last = scene.step_range().map(|r| r.1).unwrap_or(i64::MIN);
    let p0 = t.positions[i0];
    let ig = goal_index(t, i0, dt, opts).ok_or(Reject::GoalNotReached)?;
    let s0 = t.start + i0 as i64;
    let sg = t.start + ig as i64;
    let goal = t.positions[ig];
    let distance = dist(goal, p0);
    let budget = opts.budget(distance);
    if budget.is_nan() || budget > MAX_TIME_BUDGET {
        // No episode file could hold it (Episode::validate).
        return Err(Reject::OutsideRecording);
    }
    let steps = (budget / dt - 1e-9).ceil() as i64;
    if s0 + steps > last {
        return Err(Reject::OutsideRecording);
    }
    if start_blocked(scene, index, Some(ego), s0, p0, opts) {
        return Err(Reject::StartBlocked);
    }
    let ego_path = (s0..=sg).filter_map(|s| t.local(s).map(|i| (s, t.positions[i])));
    let relevant = relevant_agents(scene, index, ego_path, Some(ego), opts.density_radius);
    let density = relevant.len();
    if density < opts.min_density || density > opts.max_density {
        return Err(Reject::DensityOutOfRange);
    }
    let u = [goal[0] - p0[0], goal[1] - p0[1]];
    let class =
        classify(u, relevant.iter().map(|r| r.1), &opts.classify).ok_or(Reject::Unclassified)?;
    let agents = export_agents(scene, index, Some(ego), s0, steps, p0, goal, opts);
    let episode = Episode {
        id: format!("{}/ped{}/t{:.1}", scene.name, t.source_id, s0 as f64 * dt),
        scene: scene.name.clone(),
        source: scene.dataset.clone(),
        scenario: class,
        dt,
        start: t.pose(i0),
        goal,
        time_budget: budget,
        agents,
        density,
        obstacles: Vec::new(),
        human_path: t.positions[i0..=ig].to_vec(),
    };
    Ok((episode, ig))
}

/// All candidate episodes of one scene (before per-class selection). One ego's windows
/// never overlap: the next window starts where the previous one reached its goal.
pub fn mine_scene(scene: &Scene, opts: &MiningOptions, stats: &mut MiningStats) -> Vec<Episode> {
    let index = scene.index();
    let mut out = Vec::new();
    for (e, ego) in scene.tracks.iter().enumerate() {
        if ego.class != AgentClass::Pedestrian {
            continue;
        }
        let mut i0 = 0usize;
        while i0 + 1 < ego.len() {
            stats.windows += 1;
            match try_episode(scene, &index, e, i0, opts) {
                Ok((ep, ig)) => {
                    *stats.candidates.entry(ep.scenario).or_default() += 1;
                    out.push(ep);
                    i0 = ig;
                }
                Err(why) => {
                    match why {
                        Reject::GoalNotReached => stats.goal_not_reached += 1,
                        Reject::OutsideRecording => stats.outside_recording += 1,
                        Reject::StartBlocked => stats.start_blocked += 1,
                        Reject::DensityOutOfRange => stats.density_out_of_range += 1,
                        Reject::Unclassified => stats.unclassified += 1,
                    }
                    // Retry one second later.
                    i0 += (1.0 / scene.dt).round().max(1.0) as usize;
                }
            }
        }
    }
    out
}

/// The replayed crowd of an episode whose step 0 is global step `s0`: every track present
/// during `[s0, s0 + steps]` (except `exclude`) that comes within `export_radius` of the
/// segment `a`–`b` then, clipped to that window, in track order.
pub(crate) fn export_agents(
    scene: &Scene,
    index: &StepIndex,
    exclude: Option<usize>,
    s0: i64,
    steps: i64,
    a: [f64; 2],
    b: [f64; 2],
    opts: &MiningOptions,
) -> Vec<AgentTrack> {
    let mut ids: Vec<usize> = Vec::new();
    for s in s0..=s0 + steps {
        for &j in index.at(s) {
            let j = j as usize;
            if Some(j) == exclude || ids.contains(&j) {
                continue;
            }
            let t: &Track = &scene.tracks[j];
            if let Some(k) = t.local(s)
                && segment_distance(t.positions[k], a, b) <= opts.export_radius
            {
                ids.push(j);
            }
        }
    }
    ids.sort_unstable();
    ids.into_iter()
        .map(|j| {
            let t = &scene.tracks[j];
            let from = t.start.max(s0);
            let to = t.end().min(s0 + steps + 1);
            AgentTrack {
                id: t.id,
                start_step: (from - s0) as usize,
                positions: (from..to)
                    .filter_map(|s| t.local(s).map(|k| t.positions[k]))
                    .collect(),
                radius: opts.agent_radius,
            }
        })
        .collect()
}

/// Picks up to `per_class` episodes of each class, spreading them over densities: classes are
/// filled round-robin over density values, each density's candidates in a seeded shuffled
/// order. The result is sorted by class, then id. Deterministic for a given input order.
pub fn select(candidates: Vec<Episode>, per_class: usize, seed: u64) -> Vec<Episode> {
    select_with(candidates, per_class, seed, false)
}

/// Like [`select`], but each density's next episode comes from the scene with the fewest
/// episodes in the class so far (the first in the shuffled order among ties), so that the
/// scenes with the most candidates do not fill the common densities.
pub fn select_across_scenes(candidates: Vec<Episode>, per_class: usize, seed: u64) -> Vec<Episode> {
    select_with(candidates, per_class, seed, true)
}

fn select_with(
    candidates: Vec<Episode>,
    per_class: usize,
    seed: u64,
    spread_scenes: bool,
) -> Vec<Episode> {
    let mut out = Vec::new();
    for class in ScenarioClass::ALL {
        let mut by_density: BTreeMap<usize, Vec<Episode>> = BTreeMap::new();
        for e in candidates.iter().filter(|e| e.scenario == class) {
            by_density.entry(e.density).or_default().push(e.clone());
        }
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(
            seed ^ (class.index() as u64).wrapping_mul(0x9E37_79B9),
        );
        for v in by_density.values_mut() {
            v.shuffle(&mut rng);
        }
        let mut per_scene: BTreeMap<String, usize> = BTreeMap::new();
        let mut picked = Vec::new();
        while picked.len() < per_class && by_density.values().any(|v| !v.is_empty()) {
            for v in by_density.values_mut() {
                if picked.len() >= per_class {
                    break;
                }
                let used = |e: &Episode| {
                    if spread_scenes {
                        per_scene.get(&e.scene).copied().unwrap_or(0)
                    } else {
                        0
                    }
                };
                // The first of the least used scenes, in the shuffled order.
                let Some(i) = (0..v.len()).min_by_key(|&i| used(&v[i])) else {
                    continue;
                };
                let e = v.remove(i);
                *per_scene.entry(e.scene.clone()).or_default() += 1;
                picked.push(e);
            }
        }
        picked.sort_by(|a, b| a.id.cmp(&b.id));
        out.extend(picked);
    }
    out
}

/// A straight pedestrian track from `from` at `velocity` (m/s), 0.1 s steps, from global step
/// `start` (for the tests of the miners).
#[cfg(test)]
pub(crate) fn test_track(
    id: u64,
    start: i64,
    from: [f64; 2],
    velocity: [f64; 2],
    steps: usize,
) -> Track {
    let positions: Vec<[f64; 2]> = (0..steps)
        .map(|k| {
            let t = 0.1 * k as f64;
            [from[0] + velocity[0] * t, from[1] + velocity[1] * t]
        })
        .collect();
    Track {
        id,
        source_id: id,
        class: AgentClass::Pedestrian,
        start,
        velocities: vec![velocity; steps],
        headings: vec![velocity[1].atan2(velocity[0]); steps],
        positions,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn flows_follow_the_angle_thresholds() {
        let o = ClassifyOptions::default();
        let u = [2.0, 0.0];
        assert_eq!(flow_of(u, [1.0, 0.9], &o), Some(ScenarioClass::CoFlow)); // 42°
        assert_eq!(flow_of(u, [1.0, 1.1], &o), Some(ScenarioClass::CrossFlow)); // 47.7°
        assert_eq!(flow_of(u, [0.0, -1.0], &o), Some(ScenarioClass::CrossFlow));
        assert_eq!(
            flow_of(u, [-1.0, 0.9], &o),
            Some(ScenarioClass::CounterFlow)
        );
        assert_eq!(flow_of(u, [0.1, 0.1], &o), None); // 0.14 m/s: standing
    }

    #[test]
    fn majority_and_mixture_rules() {
        let o = ClassifyOptions::default();
        let u = [0.0, 1.0];
        let co = [0.0, 1.2];
        let cross = [1.2, 0.0];
        let counter = [0.0, -1.2];
        assert_eq!(
            classify(u, [co, co, co, cross], &o),
            Some(ScenarioClass::CoFlow)
        ); // 75 %
        assert_eq!(
            classify(u, [co, co, cross], &o),
            Some(ScenarioClass::MultidirectionFlow)
        ); // 67 %
        assert_eq!(
            classify(u, [counter, [0.0, 0.0]], &o),
            Some(ScenarioClass::CounterFlow)
        );
        assert_eq!(
            classify(u, [cross, [-1.0, 0.1]], &o),
            Some(ScenarioClass::CrossFlow)
        );
        assert_eq!(classify(u, [[0.0, 0.1]], &o), None);
        assert_eq!(
            classify(u, [co, counter, cross], &o),
            Some(ScenarioClass::MultidirectionFlow)
        );
    }

    #[test]
    fn class_names_round_trip() {
        for c in ScenarioClass::ALL {
            assert_eq!(ScenarioClass::parse(c.name()), Some(c));
            assert_eq!(ScenarioClass::from_index(c.index()), Some(c));
            let json = serde_json::to_string(&c).unwrap();
            assert_eq!(json, format!("\"{}\"", c.name()));
        }
    }

    /// A straight track from `from` at `velocity` (m/s), 0.1 s steps, from global step 0.
    fn straight_track(id: u64, from: [f64; 2], velocity: [f64; 2], steps: usize) -> Track {
        test_track(id, 0, from, velocity, steps)
    }

    /// The ego walks +x at 1 m/s from the origin; one other pedestrian walks −y at `speed`
    /// from `(x, y)`.
    fn crossing_scene(other_from: [f64; 2], speed: f64) -> Scene {
        Scene {
            name: "hand".into(),
            dataset: "test".into(),
            format: "test".into(),
            dt: 0.1,
            tracks: vec![
                straight_track(0, [0.0, 0.0], [1.0, 0.0], 200),
                straight_track(1, other_from, [0.0, -speed], 200),
            ],
            stats: crate::resample::ResampleStats::default(),
            dropped: Vec::new(),
        }
    }

    #[test]
    fn a_pedestrian_reaching_the_start_within_the_window_blocks_it() {
        let opts = MiningOptions::default();
        assert_eq!((opts.min_start_clearance, opts.start_window), (1.5, 1.5));
        // 3 m away at the start, but 3 − 1.2·1.5 = 1.2 m < 1.5 m from it at 1.5 s.
        let scene = crossing_scene([0.0, 3.0], 1.2);
        let r = try_episode(&scene, &scene.index(), 0, 0, &opts);
        assert!(matches!(r, Err(Reject::StartBlocked)), "{r:?}");
        // The same with the first step only checked: kept.
        let first_step = MiningOptions {
            start_window: 0.0,
            ..opts.clone()
        };
        assert!(try_episode(&scene, &scene.index(), 0, 0, &first_step).is_ok());
        // Crossing the ego's path 2 m ahead: never within 1.5 m of the start point.
        let scene = crossing_scene([2.0, 4.0], 1.0);
        let (ep, _) = try_episode(&scene, &scene.index(), 0, 0, &opts).unwrap();
        assert_eq!(ep.scenario, ScenarioClass::CrossFlow);
        assert_eq!(ep.agents.len(), 1);
    }

    #[test]
    fn an_episode_with_one_id_twice_or_an_empty_track_is_refused() {
        let track = |id: u64, positions: Vec<[f64; 2]>| AgentTrack {
            id,
            start_step: 0,
            positions,
            radius: 0.3,
        };
        let mut ep = Episode {
            id: "e".into(),
            scene: "s".into(),
            source: "test".into(),
            scenario: ScenarioClass::CoFlow,
            dt: 0.1,
            start: Pose2::new(0.0, 0.0, 0.0),
            goal: [5.0, 0.0],
            time_budget: 12.5,
            agents: vec![track(3, vec![[1.0, 1.0]]), track(4, vec![[2.0, 1.0]])],
            density: 2,
            obstacles: Vec::new(),
            human_path: Vec::new(),
        };
        assert_eq!(ep.validate(), Ok(()));
        ep.agents[1].id = 3;
        let (field, why) = ep.validate().unwrap_err();
        assert_eq!(field, "agents[1].id");
        assert!(why.contains("already the id of agents[0]"), "{why}");
        ep.agents[1] = track(4, Vec::new());
        let (field, why) = ep.validate().unwrap_err();
        assert_eq!(field, "agents[1].positions");
        assert!(why.contains("no positions"), "{why}");
    }

    #[test]
    fn selection_across_scenes_spreads_each_density_over_the_scenes() {
        let ep = |scene: &str, k: usize, density: usize| Episode {
            id: format!("{scene}/{k}"),
            scene: scene.into(),
            source: "test".into(),
            scenario: ScenarioClass::CoFlow,
            dt: 0.1,
            start: Pose2::new(0.0, 0.0, 0.0),
            goal: [5.0, 0.0],
            time_budget: 12.5,
            agents: Vec::new(),
            density,
            obstacles: Vec::new(),
            human_path: Vec::new(),
        };
        // Scene a: 40 candidates at density 1 and 2 at density 9; scene b: 4 at density 1.
        let mut all: Vec<Episode> = (0..40).map(|k| ep("a", k, 1)).collect();
        all.extend((40..42).map(|k| ep("a", k, 9)));
        all.extend((0..4).map(|k| ep("b", k, 1)));
        let picked = select_across_scenes(all.clone(), 8, 3);
        assert_eq!(picked.len(), 8);
        // Density 9 gets its two, density 1 its six, shared between the scenes.
        assert_eq!(picked.iter().filter(|e| e.density == 9).count(), 2);
        assert_eq!(picked.iter().filter(|e| e.scene == "b").count(), 4);
        assert_eq!(select_across_scenes(all.clone(), 8, 3), picked);
        // `select` on the same candidates draws density 1 from the 44 regardless of scene.
        assert_eq!(
            select(all, 8, 3).iter().filter(|e| e.density == 9).count(),
            2
        );
    }

    #[test]
    fn segment_distance_closed_forms() {
        assert!((segment_distance([1.0, 2.0], [0.0, 0.0], [4.0, 0.0]) - 2.0).abs() < 1e-12);
        assert!((segment_distance([-3.0, 4.0], [0.0, 0.0], [4.0, 0.0]) - 5.0).abs() < 1e-12);
    }
}
