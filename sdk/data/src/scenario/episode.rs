//! Benchmark episodes and episode suites: what an episode file holds, the bounds every reader
//! checks, and saving and loading suites.

use super::ScenarioClass;
use crate::error::DataError;
use human2nav_core::Pose2;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::Path;

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
    /// [`MAX_COORDINATE`](crate::input_limits::MAX_COORDINATE) m of the origin, agent radii finite and
    /// ≥ 0, every agent track starting within [`MAX_TIME`](crate::input_limits::MAX_TIME) s, holding
    /// at least one position and an id no other track has, and no step of a track faster than
    /// [`TRACK_SPEED_LIMIT`](crate::resample::TRACK_SPEED_LIMIT). The error names the field
    /// (`agents[3].positions[7]`) and what is wrong with it.
    pub fn validate(&self) -> Result<(), (String, String)> {
        use crate::input_limits::{MAX_COORDINATE, MAX_TIME};
        use crate::resample::{TRACK_SPEED_LIMIT, is_jump};
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
            // A step faster than anything that walks is a tracking error, and no observation
            // of it would be valid: `data build` cuts its tracks there.
            let jump = |&k: &usize| is_jump(a.positions[k - 1], a.positions[k], self.dt);
            if let Some(k) = (1..a.positions.len()).find(jump) {
                let (p, q) = (a.positions[k - 1], a.positions[k]);
                let step = (q[0] - p[0]).hypot(q[1] - p[1]);
                return field(
                    &format!("agents[{i}].positions[{k}]"),
                    format!(
                        "agent {} moves {:.2} m in one {} s step ({:.1} m/s; a track may move \
                         at {TRACK_SPEED_LIMIT:.1} m/s at most: split it where it jumps)",
                        a.id,
                        step,
                        self.dt,
                        step / self.dt
                    ),
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
        crate::input_limits::MAX_EPISODE_FILE_BYTES,
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
    /// [`MAX_EPISODE_FILE_BYTES`](crate::input_limits::MAX_EPISODE_FILE_BYTES)) and checks its
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
