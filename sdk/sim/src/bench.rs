//! The benchmark: suites of episodes × robots × methods, run in parallel, one result row each.
//!
//! Methods come in as [`MethodSpec`]s: a name plus a factory that builds a fresh
//! `Box<dyn Planner>` for one episode from a [`PlannerContext`] (the robot, the simulation
//! settings, the episode and a per-episode seed). A method that needs expensive shared state
//! (a loaded model) captures it in the closure, behind an `Arc`.
//!
//! Determinism: every episode gets the seed `mix(seed, suite, episode id, robot)` (the same
//! for every method, so methods are compared on identical draws), episodes run on rayon's
//! pool in a fixed shuffled order (for an even progress rate), and the rows come back in job
//! order (suite, robot, method, episode), whatever the scheduling.

use crate::crowd::CrowdModel;
use crate::episode::{Episode, ScenarioClass};
use crate::error::SimError;
use crate::metrics::EpisodeMetrics;
use crate::oracle::{OracleConfig, OraclePlanner};
use crate::runner::{EpisodeRun, RobotSetup, SimConfig, run_episode_with};
use crate::shard::ShardSpec;
use crate::straight::{StraightConfig, StraightPlanner};
use human2nav_core::Planner;
use indicatif::ProgressBar;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Share of `a_max` the `straight` baseline plans with by default. The tracking controller
/// follows a 10 Hz plan of straight segments, so its feed-forward speed steps by `a·0.1 s` at
/// every replanning and its derivative term adds `k_d` of that step: planning at 80 % of `a_max`
/// keeps the commands it asks for (the executed TFS) within `a_max`.
pub const STRAIGHT_ACCEL_SHARE: f64 = 0.8;

/// A boxed error from a method factory.
pub type BoxError = Box<dyn std::error::Error + Send + Sync>;

/// What a method factory gets to build a planner for one episode.
#[derive(Clone, Copy, Debug)]
pub struct PlannerContext<'a> {
    /// The robot the planner drives.
    pub robot: &'a RobotSetup,
    /// The simulation settings of the run (with the method's replanning rate).
    pub sim: &'a SimConfig,
    /// The episode the planner is built for.
    pub episode: &'a Episode,
    /// Deterministic per-episode seed for stochastic planners.
    pub seed: u64,
}

/// The factory signature of a [`MethodSpec`].
pub type PlannerFactory =
    dyn Fn(&PlannerContext<'_>) -> Result<Box<dyn Planner>, BoxError> + Send + Sync;

/// A benchmarked method: a report name, a planner factory and, optionally, its own
/// replanning rate.
pub struct MethodSpec {
    /// The method's name in the results and the report (unique in a benchmark).
    pub name: String,
    make: Box<PlannerFactory>,
    replan_hz: Option<f64>,
}

impl std::fmt::Debug for MethodSpec {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("MethodSpec")
            .field("name", &self.name)
            .field("replan_hz", &self.replan_hz)
            .finish_non_exhaustive()
    }
}

impl MethodSpec {
    /// A method from any factory.
    pub fn new(
        name: impl Into<String>,
        make: impl Fn(&PlannerContext<'_>) -> Result<Box<dyn Planner>, BoxError> + Send + Sync + 'static,
    ) -> Self {
        Self {
            name: name.into(),
            make: Box::new(make),
            replan_hz: None,
        }
    }

    /// This method replans at `replan_hz` instead of the simulation's rate (`None`: the
    /// simulation's). The rate must give a whole number of steps per period
    /// ([`SimConfig::validate`]); [`run_one`] fails otherwise.
    pub fn with_replan_hz(mut self, replan_hz: Option<f64>) -> Self {
        self.replan_hz = replan_hz;
        self
    }

    /// The closed-loop settings this method runs with.
    pub fn sim_config(&self, sim: &SimConfig) -> SimConfig {
        sim.with_replan_hz(self.replan_hz)
    }

    /// Builds the planner for one episode.
    pub fn make(&self, ctx: &PlannerContext<'_>) -> Result<Box<dyn Planner>, BoxError> {
        (self.make)(ctx)
    }

    /// The clairvoyant yardstick `oracle` ([`crate::oracle`]): it reads each episode's
    /// recorded crowd. Keys of `table` override [`OracleConfig`]; `goal_tolerance` defaults to
    /// the simulation's.
    pub fn oracle(name: impl Into<String>, table: &toml::Table) -> Result<Self, BoxError> {
        let base: OracleConfig = table.clone().try_into()?;
        base.validate()?;
        let has_tolerance = table.contains_key("goal_tolerance");
        Ok(Self::new(name, move |ctx| {
            let mut cfg = base.clone();
            if !has_tolerance {
                cfg.goal_tolerance = ctx.sim.goal_tolerance;
            }
            Ok(Box::new(OraclePlanner::new(
                cfg,
                ctx.robot.limits,
                ctx.robot.footprint.clone(),
                ctx.episode.clone(),
            )?) as Box<dyn Planner>)
        }))
    }

    /// The built-in `straight` baseline. Keys of `table` override [`StraightConfig`]; `speed`
    /// and `accel` default to the robot's `v_max` and [`STRAIGHT_ACCEL_SHARE`]` · a_max`.
    pub fn straight(name: impl Into<String>, table: &toml::Table) -> Result<Self, BoxError> {
        let base: StraightConfig = table.clone().try_into()?;
        base.validate()?;
        let (has_speed, has_accel) = (table.contains_key("speed"), table.contains_key("accel"));
        Ok(Self::new(name, move |ctx| {
            let mut cfg = base.clone();
            if !has_speed {
                cfg.speed = ctx.robot.limits.v_max;
            }
            if !has_accel {
                cfg.accel = STRAIGHT_ACCEL_SHARE * ctx.robot.limits.a_max;
            }
            Ok(Box::new(StraightPlanner::new(cfg)?) as Box<dyn Planner>)
        }))
    }
}

/// What kind of suite a set of episodes is.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SuiteKind {
    /// Held-out real episodes.
    Real,
    /// Episodes from the synthetic crowd generator.
    Synthetic,
    /// Episodes with every pedestrian removed (sanity: every working method must succeed).
    Empty,
    /// Generated corridor episodes with walls, doors and pillars
    /// ([`human2nav_data::corridor`]): the suite with static obstacles.
    Corridor,
}

impl SuiteKind {
    /// The kind's name in configurations, `results.csv` and the report.
    pub fn as_str(self) -> &'static str {
        match self {
            SuiteKind::Real => "real",
            SuiteKind::Synthetic => "synthetic",
            SuiteKind::Empty => "empty",
            SuiteKind::Corridor => "corridor",
        }
    }
}

/// A named list of episodes, the crowd model they run with and the methods that run them.
#[derive(Clone, Debug)]
pub struct Suite {
    /// Name in the results and the report (unique in a benchmark).
    pub name: String,
    /// Where the episodes came from.
    pub kind: SuiteKind,
    /// The episodes, each run once per robot and method.
    pub episodes: Vec<Episode>,
    /// Anything the report should say about how the suite was obtained (a fallback, say).
    pub note: Option<String>,
    /// How the pedestrians behave (replayed, or reactive to the robot).
    pub crowd: CrowdModel,
    /// The methods that run this suite (`None`: every method).
    pub methods: Option<Vec<String>>,
}

impl Suite {
    /// A suite of replayed episodes that every method runs.
    pub fn new(name: impl Into<String>, kind: SuiteKind, episodes: Vec<Episode>) -> Self {
        Self {
            name: name.into(),
            kind,
            episodes,
            note: None,
            crowd: CrowdModel::Replay,
            methods: None,
        }
    }

    /// True when `method` runs this suite.
    pub fn runs(&self, method: &str) -> bool {
        self.methods
            .as_ref()
            .is_none_or(|m| m.iter().any(|x| x == method))
    }
}

/// One result row: an episode × robot × method.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ResultRow {
    /// Name of the suite the episode belongs to.
    pub suite: String,
    /// Kind of that suite.
    pub suite_kind: SuiteKind,
    /// Scenario class of the episode.
    pub scenario: ScenarioClass,
    /// Episode id.
    pub episode: String,
    /// Scene (recording) the episode was cut from.
    pub scene: String,
    /// Robot name.
    pub robot: String,
    /// Method name.
    pub method: String,
    /// Seed the method's planner got for this run.
    pub seed: u64,
    /// Pedestrians in the episode.
    pub agents: usize,
    /// Relevant pedestrians (the data crate's density).
    pub density: usize,
    /// The run's metrics.
    pub metrics: EpisodeMetrics,
}

/// SplitMix64 finaliser.
fn mix64(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// FNV-1a of a string (stable across platforms and releases, unlike `DefaultHasher`).
fn fnv1a(s: &str) -> u64 {
    s.bytes().fold(0xCBF2_9CE4_8422_2325, |h, b| {
        (h ^ u64::from(b)).wrapping_mul(0x0100_0000_01B3)
    })
}

/// The per-episode seed (see the module docs).
pub fn episode_seed(seed: u64, suite: &str, episode: &str, robot: &str) -> u64 {
    mix64(seed ^ mix64(fnv1a(suite) ^ mix64(fnv1a(episode) ^ mix64(fnv1a(robot)))))
}

/// Runs one episode of one method on one robot and returns the run and its metrics.
pub fn run_one(
    suite: &Suite,
    episode: &Episode,
    robot: &RobotSetup,
    method: &MethodSpec,
    sim: &SimConfig,
    seed: u64,
) -> Result<(EpisodeRun, ResultRow), SimError> {
    let seed = episode_seed(seed, &suite.name, &episode.id, &robot.name);
    let sim = &method.sim_config(sim);
    sim.validate()?;
    let ctx = PlannerContext {
        robot,
        sim,
        episode,
        seed,
    };
    let mut planner = method.make(&ctx).map_err(|e| SimError::Method {
        method: method.name.clone(),
        robot: robot.name.clone(),
        episode: episode.id.clone(),
        message: e.to_string(),
    })?;
    let run = run_episode_with(episode, robot, planner.as_mut(), sim, &suite.crowd);
    let metrics = EpisodeMetrics::compute(&run, &robot.limits).against_human(&run, episode);
    let row = ResultRow {
        suite: suite.name.clone(),
        suite_kind: suite.kind,
        scenario: episode.scenario,
        episode: episode.id.clone(),
        scene: episode.scene.clone(),
        robot: robot.name.clone(),
        method: method.name.clone(),
        seed,
        agents: episode.agents.len(),
        density: episode.density,
        metrics,
    };
    Ok((run, row))
}

/// Runs every suite × robot × method × episode in parallel (a suite only with the methods it
/// names); rows in job order.
pub fn run_bench(
    suites: &[Suite],
    robots: &[RobotSetup],
    methods: &[MethodSpec],
    sim: &SimConfig,
    seed: u64,
    progress: &ProgressBar,
) -> Result<Vec<ResultRow>, SimError> {
    run_bench_timed(suites, robots, methods, sim, seed, progress).map(|(rows, _)| rows)
}

/// Where a benchmark's time went: per method, the runs and the thread-seconds they took.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct MethodTimes {
    /// `(method, runs, seconds)` in method order.
    pub per_method: Vec<(String, usize, f64)>,
}

/// [`run_bench`], also measuring the time each method's runs took (thread time: on `k` worker
/// threads the wall time is about the sum over methods divided by `k`).
pub fn run_bench_timed(
    suites: &[Suite],
    robots: &[RobotSetup],
    methods: &[MethodSpec],
    sim: &SimConfig,
    seed: u64,
    progress: &ProgressBar,
) -> Result<(Vec<ResultRow>, MethodTimes), SimError> {
    run_bench_shard(suites, robots, methods, sim, seed, None, None, progress)
}

/// One run of a benchmark, as [`run_ids`] lists them.
#[derive(Clone, Debug, PartialEq, Eq, Hash)]
pub struct RunId {
    /// The suite's name.
    pub suite: String,
    /// The robot's name.
    pub robot: String,
    /// The method's name.
    pub method: String,
    /// The episode's id.
    pub episode: String,
}

impl RunId {
    /// The run a result row is of.
    pub fn of(row: &ResultRow) -> Self {
        Self {
            suite: row.suite.clone(),
            robot: row.robot.clone(),
            method: row.method.clone(),
            episode: row.episode.clone(),
        }
    }
}

impl std::fmt::Display for RunId {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "suite `{}`, robot `{}`, method `{}`, episode `{}`",
            self.suite, self.robot, self.method, self.episode
        )
    }
}

/// Every run of a benchmark in job order, the order of its rows: suite, then robot, then
/// method (a suite only with the methods it names), then episode. Run `i` of this list is
/// the one [`crate::shard::ShardSpec::holds`] assigns.
pub fn run_ids(suites: &[Suite], robots: &[RobotSetup], methods: &[MethodSpec]) -> Vec<RunId> {
    jobs(suites, robots, methods)
        .into_iter()
        .map(|(s, r, _, m, e)| RunId {
            suite: s.name.clone(),
            robot: r.name.clone(),
            method: m.name.clone(),
            episode: e.id.clone(),
        })
        .collect()
}

type Job<'a> = (
    &'a Suite,
    &'a RobotSetup,
    usize,
    &'a MethodSpec,
    &'a Episode,
);

fn jobs<'a>(
    suites: &'a [Suite],
    robots: &'a [RobotSetup],
    methods: &'a [MethodSpec],
) -> Vec<Job<'a>> {
    let mut jobs = Vec::new();
    for s in suites {
        for r in robots {
            for (k, m) in methods.iter().enumerate().filter(|(_, m)| s.runs(&m.name)) {
                for e in &s.episodes {
                    jobs.push((s, r, k, m, e));
                }
            }
        }
    }
    jobs
}

/// [`run_bench_timed`] of the runs of `shard` only (every run when `None`): rows in job order.
/// An empty benchmark is an error; an empty shard (more shards than runs) is not. With
/// `record`, each run is also written as an MCAP file under that folder
/// ([`crate::record::record_run`], at [`crate::record::run_file`]).
pub fn run_bench_shard(
    suites: &[Suite],
    robots: &[RobotSetup],
    methods: &[MethodSpec],
    sim: &SimConfig,
    seed: u64,
    shard: Option<ShardSpec>,
    record: Option<&std::path::Path>,
    progress: &ProgressBar,
) -> Result<(Vec<ResultRow>, MethodTimes), SimError> {
    let mut jobs = jobs(suites, robots, methods);
    if jobs.is_empty() {
        return Err(SimError::Empty(
            "no suite, robot, method or episode selected".into(),
        ));
    }
    if let Some(shard) = shard {
        jobs = jobs
            .into_iter()
            .enumerate()
            .filter(|(i, _)| shard.holds(*i))
            .map(|(_, job)| job)
            .collect();
    }
    progress.set_length(jobs.len() as u64);
    // Run the jobs in a fixed pseudo-random order: in job order the cheap baselines and the
    // expensive Human2Nav runs come in long blocks, which made the progress bar's rate (and so
    // its ETA) swing by a factor of three. The rows are put back in job order.
    let mut order: Vec<usize> = (0..jobs.len()).collect();
    order.sort_by_key(|&i| mix64(i as u64 ^ 0x9e37_79b9_7f4a_7c15));
    let mut done: Vec<(usize, ResultRow, usize, f64)> = order
        .par_iter()
        .map(|&i| {
            let (s, r, k, m, e) = jobs[i];
            let started = std::time::Instant::now();
            let out = run_one(s, e, r, m, sim, seed).and_then(|(run, row)| {
                let secs = started.elapsed().as_secs_f64();
                if let Some(dir) = record {
                    crate::record::record_run(
                        &dir.join(crate::record::run_file(&row)),
                        e,
                        &run,
                        r,
                        &row,
                    )?;
                }
                Ok((i, row, k, secs))
            });
            progress.inc(1);
            out
        })
        .collect::<Result<_, SimError>>()?;
    progress.finish();
    done.sort_by_key(|(i, ..)| *i);
    let mut times = MethodTimes {
        per_method: methods.iter().map(|m| (m.name.clone(), 0, 0.0)).collect(),
    };
    for (_, _, k, secs) in &done {
        times.per_method[*k].1 += 1;
        times.per_method[*k].2 += secs;
    }
    Ok((done.into_iter().map(|(_, row, ..)| row).collect(), times))
}
