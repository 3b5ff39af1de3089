//! The data-scaling experiment behind `human2nav scaling --config sdk/configs/scaling.toml
//! [--out DIR] [--quick]`: the human-data curve of the paper's Fig. 5. For each fraction of the training scenes (a seeded choice; the
//! subsets are nested because every fraction keeps a prefix of the same shuffled scene list)
//! the flow model is retrained with the settings of the train config, then Human2Nav with
//! guidance (the planner config with its `model` replaced) runs closed loop on one benchmark
//! suite, and the success rates per fraction go into `scaling.csv`, `report.md` and
//! `fig5_sr_vs_training_data.png`, plotted as in the paper against the hours of recorded human
//! data trained on (the recorded time of the chosen scenes' tracks, from the cache manifest),
//! with ±1 standard error shaded.
//!
//! [`run`] takes a [`ScalingRequest`] and the caller's [`MultiProgress`], and returns a
//! [`ScalingOutcome`].
//!
//! Output layout under `--out` (default `out/scaling`, or `out/scaling-quick` with `--quick`):
//!
//! * `models/frac-<pct>/`: the exported model of each fraction (card, weights, loss curve) and
//!   `scaling_stamp.toml`, written last; a fraction whose stamp matches the current settings
//!   is not retrained (the command is resumable);
//! * `train/frac-<pct>/checkpoint/`: the training checkpoints (an interrupted training resumes
//!   from there);
//!   (these two folders go under `--models` instead when it is given: a run on another suite
//!   pointed at an earlier run's folder reuses its models; `--suite` picks that suite);
//! * `frac-<pct>/planner.toml` and `frac-<pct>/results.csv`: the planner used and one row per
//!   episode × robot; `frac-<pct>/closed_loop.toml`: the same rows with what they were measured
//!   with (model, planner, episodes, robots, simulation settings, seed), reused by a later run
//!   with equal settings, so an interrupted run repeats neither finished trainings nor finished
//!   closed loops;
//! * `scaling.csv` (one row per fraction), `report.md`, `fig5_sr_vs_training_data.png`.

use crate::bench::{ensure_real_episodes, human2nav_method};
use crate::train::{self, TrainConfig};
use anyhow::{Context, bail};
use human2nav_core::input::{MAX_CONFIG_BYTES, read_user_file};
use human2nav_core::lock::DirLock;
use human2nav_data::cache::TupleCache;
use human2nav_data::tuples::Split;
use human2nav_flow::card::ModelCard;
use human2nav_flow::model::{CARD_FILE, WEIGHTS_FILE};
use human2nav_flow::planner::{PlannerConfig, load_profile};
use human2nav_flow::train::TrainOptions;
use human2nav_flow::{NetConfig, tch};
use human2nav_sim::config::{BenchConfig, MethodConfig, build_suites, load_robots};
use human2nav_sim::episode::{ScenarioClass, ScenarioTitle};
use human2nav_sim::figures::{scaling_points, sr_vs_training_data};
use human2nav_sim::report::{results_csv, summarize};
use human2nav_sim::{ResultRow, RobotSetup, SimConfig, Suite, SuiteKind, run_bench};
use indicatif::{MultiProgress, ProgressBar, ProgressStyle};
use serde::{Deserialize, Serialize};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Name of the method in the results (Human2Nav with guidance).
const METHOD: &str = "human2nav";

/// File in a model folder recording the settings it was trained with.
const STAMP_FILE: &str = "scaling_stamp.toml";

/// File in a fraction's folder with its closed-loop rows and what they were measured with.
const CLOSED_LOOP_FILE: &str = "closed_loop.toml";

/// The options of one scaling run (those of `human2nav scaling`).
#[derive(Clone, Debug, Default)]
pub struct ScalingRequest {
    /// Scaling configuration (TOML); relative paths inside it resolve against the workspace
    /// root.
    pub config: PathBuf,
    /// Output directory; `None` is `out/scaling`, or `out/scaling-quick` when `quick`, under
    /// the workspace root.
    pub out: Option<PathBuf>,
    /// Short check: `quick_steps` training steps per model, the suite's `quick_per_class`
    /// episodes per scenario class and the `quick_robots`.
    pub quick: bool,
    /// Torch threads for training; `None` is the train config's `run.threads`. The episodes
    /// run on one worker per core (`RAYON_NUM_THREADS` overrides).
    pub threads: Option<usize>,
    /// Measure this suite of the bench config instead of the scaling config's `suite`.
    pub suite: Option<String>,
    /// Folder that holds (or will hold) the fraction models and their training runs
    /// (`models/`, `train/`); `None` is the output directory. Pointing a run on another suite
    /// at an earlier run's output reuses its models instead of training them again.
    pub models: Option<PathBuf>,
}

impl ScalingRequest {
    /// The command line written into the report.
    pub fn command(&self) -> String {
        format!(
            "human2nav scaling --config {}{}{}{}{}{}",
            self.config.display(),
            self.out
                .as_ref()
                .map(|p| format!(" --out {}", p.display()))
                .unwrap_or_default(),
            if self.quick { " --quick" } else { "" },
            self.threads
                .map(|t| format!(" --threads {t}"))
                .unwrap_or_default(),
            self.suite
                .as_ref()
                .map(|s| format!(" --suite {s}"))
                .unwrap_or_default(),
            self.models
                .as_ref()
                .map(|p| format!(" --models {}", p.display()))
                .unwrap_or_default()
        )
    }
}

/// What a scaling run produced.
#[derive(Debug)]
pub struct ScalingOutcome {
    /// One result per fraction, in the configuration's order.
    pub fractions: Vec<FractionResult>,
    /// `report.md`.
    pub report: PathBuf,
    /// `scaling.csv`.
    pub csv: PathBuf,
    /// `fig5_sr_vs_training_data.png`.
    pub figure: PathBuf,
    /// Wall time of the whole run, seconds.
    pub wall_time_s: f64,
}

/// The whole `scaling.toml`.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ScalingConfig {
    /// Training configuration (network, optimiser, tuple cache). Default
    /// `sdk/configs/train.toml`.
    train: PathBuf,
    /// Benchmark configuration whose suite, robots, simulation settings and seed are used.
    /// Default `sdk/configs/bench.toml`.
    bench: PathBuf,
    /// Planner configuration; its `model` is replaced by each fraction's model. Default
    /// `sdk/configs/planner.toml`.
    planner: PathBuf,
    /// Data configuration used to mine the held-out episodes when the suite's episode file is
    /// missing and the datasets are present. Default `sdk/configs/data.toml`.
    data: PathBuf,
    /// The benchmark suite measured. Default `real`.
    suite: String,
    /// Shares of the training scenes, each in (0, 1]. Default `[0.1, 0.25, 0.5, 1.0]`.
    fractions: Vec<f64>,
    /// Training steps per model. Default: the train config's `train.steps`.
    steps: Option<u64>,
    /// Training steps per model with `--quick`. Default 50.
    quick_steps: u64,
    /// Episodes per scenario class (at most; the report notes classes with fewer). Default: the
    /// suite's `per_class`; `--quick` always takes the suite's `quick_per_class`.
    per_class: Option<usize>,
    /// Robot names (a subset of the bench config's robots). Default: all of them.
    robots: Vec<String>,
    /// Robot names with `--quick`. Default: `robots`.
    quick_robots: Vec<String>,
    /// Seed of the scene choice and of training (`train.seed`). Default: the train config's.
    seed: Option<u64>,
}

impl Default for ScalingConfig {
    fn default() -> Self {
        Self {
            train: PathBuf::from("sdk/configs/train.toml"),
            bench: PathBuf::from("sdk/configs/bench.toml"),
            planner: PathBuf::from("sdk/configs/planner.toml"),
            data: PathBuf::from("sdk/configs/data.toml"),
            suite: "real".into(),
            fractions: vec![0.1, 0.25, 0.5, 1.0],
            steps: None,
            quick_steps: 50,
            per_class: None,
            robots: Vec::new(),
            quick_robots: Vec::new(),
            seed: None,
        }
    }
}

/// The folder name of a fraction: `frac-<percent, three digits>`.
fn fraction_name(f: f64) -> String {
    format!("frac-{:03}", (100.0 * f).round() as u64)
}

impl ScalingConfig {
    /// Reads, parses and checks a `scaling.toml`; the error names the file and the field.
    pub fn load(path: &Path) -> anyhow::Result<Self> {
        let text = read_user_file(path, "configuration", MAX_CONFIG_BYTES)
            .with_context(|| format!("reading {}", path.display()))?;
        let cfg: Self =
            toml::from_str(&text).with_context(|| format!("parsing {}", path.display()))?;
        cfg.validate()
            .with_context(|| format!("in {}", path.display()))?;
        Ok(cfg)
    }

    /// Checks every field; the error names the first offending one.
    fn validate(&self) -> anyhow::Result<()> {
        if self.fractions.is_empty() {
            bail!("fractions: list at least one share of the training scenes");
        }
        for (i, &f) in self.fractions.iter().enumerate() {
            if !(f.is_finite() && f > 0.0 && f <= 1.0) {
                bail!("fractions[{i}]: must lie in (0, 1], got {f}");
            }
            let name = fraction_name(f);
            if self.fractions[..i]
                .iter()
                .any(|&g| fraction_name(g) == name)
            {
                bail!("fractions[{i}]: {f} repeats a fraction (same whole percent)");
            }
        }
        if self.steps == Some(0) {
            bail!("steps: must be at least 1");
        }
        if self.quick_steps == 0 {
            bail!("quick_steps: must be at least 1");
        }
        if self.per_class == Some(0) {
            bail!("per_class: must be at least 1");
        }
        if self.suite.is_empty() {
            bail!("suite: must name a suite of the bench config");
        }
        Ok(())
    }
}

/// What a model folder was trained with; a folder whose stamp equals the current one is
/// complete and reused.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct Stamp {
    fraction: f64,
    /// The tuple cache trained on.
    cache: String,
    net: NetConfig,
    train: TrainOptions,
}

/// What a fraction's closed-loop rows were measured with; rows stored with an equal stamp are
/// reused instead of running the episodes again.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct ClosedLoopStamp {
    model: Stamp,
    /// The planner configuration with this fraction's model.
    planner: toml::Table,
    suite: String,
    /// Episode ids, in order.
    episodes: Vec<String>,
    /// Each robot's name, footprint and limits.
    robots: Vec<String>,
    sim: SimConfig,
    seed: u64,
}

/// Contents of [`CLOSED_LOOP_FILE`].
#[derive(Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct ClosedLoopFile {
    stamp: ClosedLoopStamp,
    rows: Vec<ResultRow>,
}

/// The stored rows of `path` when they were measured with `stamp`.
fn stored_rows(path: &Path, stamp: &ClosedLoopStamp) -> Option<Vec<ResultRow>> {
    let text = std::fs::read_to_string(path).ok()?;
    let file: ClosedLoopFile = toml::from_str(&text).ok()?;
    (file.stamp == *stamp).then_some(file.rows)
}

/// The parts of a training checkpoint's `state.toml` that decide whether it can be resumed.
#[derive(Debug, Deserialize)]
struct CheckpointHead {
    step: u64,
    net: NetConfig,
    options: TrainOptions,
}

/// Whether a checkpoint in `ckpt` must be discarded: it is ahead of the requested steps or
/// was trained with other settings (a resume would fail or export the wrong model).
fn stale_checkpoint(ckpt: &Path, net: &NetConfig, opts: &TrainOptions) -> Option<String> {
    let path = ckpt.join("state.toml");
    let text = std::fs::read_to_string(&path).ok()?;
    let head: CheckpointHead = match toml::from_str(&text) {
        Ok(h) => h,
        Err(e) => return Some(format!("{} is unreadable ({e})", path.display())),
    };
    let mut same = head.options.clone();
    same.steps = opts.steps;
    if head.step > opts.steps {
        Some(format!(
            "{} is at step {}, beyond the requested {}",
            path.display(),
            head.step,
            opts.steps
        ))
    } else if same != *opts || head.net != *net {
        Some(format!("{} has other settings", path.display()))
    } else {
        None
    }
}

/// One fraction's training and measurement.
#[derive(Debug)]
pub struct FractionResult {
    /// The share of the training scenes, in (0, 1].
    pub fraction: f64,
    /// The fraction's folder name, `frac-<percent>`.
    pub name: String,
    /// The training scenes chosen.
    pub scenes: Vec<String>,
    /// Recorded time of those scenes' tracks, hours (the x-axis of Fig. 5, as in the paper).
    pub recorded_hours: f64,
    /// Training tuples of the exported model (from its card; 0 when the card has no record).
    pub train_tuples: usize,
    /// Optimiser steps of the exported model (from its card).
    pub steps: u64,
    /// Final validation loss (from its card; NaN when the card has no record).
    pub final_val_loss: f64,
    /// Accumulated training time from the model card (over resumes).
    pub training_time_s: f64,
    /// `false` when the model folder was complete and reused.
    pub trained: bool,
    /// Wall time of this invocation's training stage (loading, training, export).
    pub train_stage_s: f64,
    /// Wall time of this invocation's closed-loop stage.
    pub bench_stage_s: f64,
    /// `false` when the stored closed-loop rows matched and were reused.
    pub measured: bool,
    /// One row per episode × robot.
    pub rows: Vec<ResultRow>,
}

/// `p` itself when absolute, else `p` under `root`.
fn resolve(root: &Path, p: &Path) -> PathBuf {
    if p.is_absolute() {
        p.to_path_buf()
    } else {
        root.join(p)
    }
}

/// A line above the bars; printed directly when they are hidden (no terminal, e.g. a log
/// file), where `MultiProgress::println` prints nothing.
fn say(multi: &MultiProgress, line: String) {
    if multi.is_hidden() || multi.println(&line).is_err() {
        eprintln!("{line}");
    }
}

/// The style of the stage bar (two stages per fraction: training, closed loop).
fn stage_style() -> ProgressStyle {
    ProgressStyle::with_template("{elapsed_precise} [{bar:30}] stage {pos}/{len}  ETA {eta}  {msg}")
        .unwrap_or_else(|_| ProgressStyle::default_bar())
        .progress_chars("=> ")
}

/// Everything a scaling run needs, loaded and checked before the first training.
struct Setup {
    cfg: ScalingConfig,
    out: PathBuf,
    /// Where the fraction models and their training runs are (`models/`, `train/`).
    models: PathBuf,
    train: TrainSettings,
    bench_path: PathBuf,
    bcfg: BenchConfig,
    suite: Suite,
    per_class: usize,
    robots: Vec<RobotSetup>,
    planner_path: PathBuf,
    planner_table: toml::Table,
}

/// The training side of a [`Setup`].
struct TrainSettings {
    path: PathBuf,
    cfg: TrainConfig,
    device: tch::Device,
    cache_dir: PathBuf,
    cache: TupleCache,
}

/// A fraction's model after its training stage.
struct TrainedModel {
    name: String,
    model_dir: PathBuf,
    scenes: Vec<String>,
    recorded_hours: f64,
    stamp: Stamp,
    /// The model folder was complete and reused.
    complete: bool,
    train_stage_s: f64,
    card: ModelCard,
}

/// Runs the scaling experiment of `request`: trains (or reuses) a model per fraction, runs its
/// closed loop (or reuses the stored rows), and writes `scaling.csv`, `report.md` and the
/// figure. The stage bars go into `multi`, the progress lines above them (or to stderr when
/// the bars are hidden).
pub fn run(request: &ScalingRequest, multi: &MultiProgress) -> anyhow::Result<ScalingOutcome> {
    let started = Instant::now();
    let cfg = load_config(request)?;
    let (root, out, models) = locations(request);
    let _lock = DirLock::acquire(&out, "human2nav scaling")
        .with_context(|| format!("locking the output folder {}", out.display()))?;
    let _models_lock = if models != out {
        Some(
            DirLock::acquire(&models, "human2nav scaling")
                .with_context(|| format!("locking the models folder {}", models.display()))?,
        )
    } else {
        None
    };
    let setup = Setup::load(cfg, request, &root, out, models)?;

    let stages = multi.add(ProgressBar::new(2 * setup.cfg.fractions.len() as u64));
    stages.set_style(stage_style());
    let mut results = Vec::new();
    for &fraction in &setup.cfg.fractions {
        let model = setup.train_stage(fraction, multi, &stages)?;
        stages.inc(1);
        results.push(setup.closed_loop_stage(fraction, model, multi, &stages)?);
        stages.inc(1);
    }
    stages.finish_and_clear();
    setup.write_outputs(request, results, started)
}

/// Reads, parses and checks the scaling configuration and the request's options.
fn load_config(request: &ScalingRequest) -> anyhow::Result<ScalingConfig> {
    let mut cfg = ScalingConfig::load(&request.config)?;
    if request.threads == Some(0) {
        bail!("--threads must be at least 1");
    }
    if let Some(suite) = &request.suite {
        if suite.is_empty() {
            bail!("--suite must name a suite of the bench config");
        }
        cfg.suite = suite.clone();
    }
    Ok(cfg)
}

/// The workspace root (found from the configuration's folder, else the current directory),
/// the absolute output folder and the absolute folder of the fraction models.
fn locations(request: &ScalingRequest) -> (PathBuf, PathBuf, PathBuf) {
    let cwd = std::env::current_dir().unwrap_or_else(|_| PathBuf::from("."));
    let config_dir = request
        .config
        .parent()
        .map(|d| cwd.join(d))
        .unwrap_or_else(|| cwd.clone());
    let root = human2nav_data::paths::find_workspace_root(&config_dir)
        .or_else(|| human2nav_data::paths::find_workspace_root(&cwd))
        .unwrap_or_else(|| cwd.clone());
    // Absolute, so the model folders written into the planner configs do not depend on the
    // directory their paths are later resolved against.
    let out = match &request.out {
        Some(p) => cwd.join(p),
        None => root.join(if request.quick {
            "out/scaling-quick"
        } else {
            "out/scaling"
        }),
    };
    let models = request
        .models
        .as_ref()
        .map_or_else(|| out.clone(), |p| cwd.join(p));
    (root, out, models)
}

/// The train config with the scaling overrides (steps, seed, threads, no time cap), its
/// device and its tuple cache.
fn train_settings(
    cfg: &ScalingConfig,
    request: &ScalingRequest,
    root: &Path,
) -> anyhow::Result<TrainSettings> {
    let path = resolve(root, &cfg.train);
    let mut tcfg = TrainConfig::load(&path)?;
    tcfg.train.steps = if request.quick {
        cfg.quick_steps
    } else {
        cfg.steps.unwrap_or(tcfg.train.steps)
    };
    if let Some(seed) = cfg.seed {
        tcfg.train.seed = seed;
    }
    if let Some(t) = request.threads {
        tcfg.run.threads = t;
    }
    // This command is the long run: no per-invocation cap (interrupting it is safe, the
    // training resumes from its checkpoint).
    tcfg.run.max_minutes = 0.0;
    tcfg.validate()
        .with_context(|| format!("in {}", path.display()))?;
    let device = train::device_of(&tcfg.run.device)?;
    let cache_dir = resolve(root, &tcfg.data.cache);
    let cache = train::open_cache(&cache_dir, &tcfg, &path)?;
    Ok(TrainSettings {
        path,
        cfg: tcfg,
        device,
        cache_dir,
        cache,
    })
}

/// The bench config reduced to the measured suite (with the `per_class` override), that
/// suite built (its episodes mined first when needed) and its episodes per class.
fn bench_suite(
    cfg: &ScalingConfig,
    request: &ScalingRequest,
    root: &Path,
) -> anyhow::Result<(PathBuf, BenchConfig, Suite, usize)> {
    let bench_path = resolve(root, &cfg.bench);
    let mut bcfg = BenchConfig::load(&bench_path)
        .with_context(|| format!("loading {}", bench_path.display()))?;
    let Some(suite_cfg) = bcfg.suites.iter().find(|s| s.name == cfg.suite).cloned() else {
        bail!(
            "suite: `{}` is not a suite of {} (it has: {})",
            cfg.suite,
            bench_path.display(),
            bcfg.suites
                .iter()
                .map(|s| s.name.as_str())
                .collect::<Vec<_>>()
                .join(", ")
        );
    };
    if suite_cfg.kind == SuiteKind::Empty {
        bail!(
            "suite: `{}` is an empty-world suite; measure a suite with pedestrians",
            cfg.suite
        );
    }
    let mut suite_cfg = suite_cfg;
    if let Some(n) = cfg.per_class {
        suite_cfg.per_class = n;
    }
    let per_class = if request.quick {
        suite_cfg.quick_per_class
    } else {
        suite_cfg.per_class
    };
    bcfg.suites = vec![suite_cfg];
    let fallback = ensure_real_episodes(&bcfg, &resolve(root, &cfg.data), &|m| eprintln!("{m}"))?;
    let suite = build_suites(&bcfg, request.quick, fallback.as_deref())?
        .into_iter()
        .next()
        .context("the bench config built no suite")?;
    Ok((bench_path, bcfg, suite, per_class))
}

/// The robots measured: the configuration's `robots` (or `quick_robots` when quick and
/// given), all of the bench config's when the list is empty.
fn pick_robots(
    cfg: &ScalingConfig,
    request: &ScalingRequest,
    bcfg: &BenchConfig,
    bench_path: &Path,
) -> anyhow::Result<Vec<RobotSetup>> {
    let all_robots = load_robots(bcfg)?;
    let (robots_key, robot_names) = if request.quick && !cfg.quick_robots.is_empty() {
        ("quick_robots", &cfg.quick_robots)
    } else {
        ("robots", &cfg.robots)
    };
    if robot_names.is_empty() {
        return Ok(all_robots);
    }
    let mut picked = Vec::new();
    for (i, name) in robot_names.iter().enumerate() {
        let Some(r) = all_robots.iter().find(|r| &r.name == name) else {
            bail!(
                "{robots_key}[{i}]: no robot named `{name}` in {} (it has: {})",
                bench_path.display(),
                all_robots
                    .iter()
                    .map(|r| r.name.as_str())
                    .collect::<Vec<_>>()
                    .join(", ")
            );
        };
        picked.push(r.clone());
    }
    Ok(picked)
}

/// The planner configuration as a table (its `model` is replaced per fraction), checked now
/// rather than after the first training, together with every robot profile the Human2Nav
/// method loads.
fn planner_settings(
    cfg: &ScalingConfig,
    root: &Path,
    bcfg: &BenchConfig,
) -> anyhow::Result<(PathBuf, toml::Table)> {
    let planner_path = resolve(root, &cfg.planner);
    let planner_text = read_user_file(&planner_path, "planner configuration", MAX_CONFIG_BYTES)
        .with_context(|| format!("reading {}", planner_path.display()))?;
    let planner_table: toml::Table = toml::from_str(&planner_text)
        .with_context(|| format!("parsing {}", planner_path.display()))?;
    PlannerConfig::from_toml_str(&planner_text, &planner_path)?;
    for p in &bcfg.robots {
        load_profile(&bcfg.resolve(p))?;
    }
    Ok((planner_path, planner_table))
}

impl Setup {
    /// Loads and checks the training, benchmark and planner settings, and reports the
    /// experiment's size on stderr.
    fn load(
        cfg: ScalingConfig,
        request: &ScalingRequest,
        root: &Path,
        out: PathBuf,
        models: PathBuf,
    ) -> anyhow::Result<Setup> {
        let train = train_settings(&cfg, request, root)?;
        let (bench_path, bcfg, suite, per_class) = bench_suite(&cfg, request, root)?;
        let robots = pick_robots(&cfg, request, &bcfg, &bench_path)?;
        let (planner_path, planner_table) = planner_settings(&cfg, root, &bcfg)?;
        eprintln!(
            "suite `{}` ({}): {} episodes (up to {per_class} per class) × {} robot(s); {} fractions × {} training steps",
            suite.name,
            suite.kind.as_str(),
            suite.episodes.len(),
            robots.len(),
            cfg.fractions.len(),
            train.cfg.train.steps
        );
        if let Some(note) = &suite.note {
            eprintln!("  {note}");
        }
        Ok(Setup {
            cfg,
            out,
            models,
            train,
            bench_path,
            bcfg,
            suite,
            per_class,
            robots,
            planner_path,
            planner_table,
        })
    }

    /// Trains the model of `fraction` into `models/<name>`, unless that folder is complete
    /// with an equal stamp; a stale checkpoint is discarded first.
    fn train_stage(
        &self,
        fraction: f64,
        multi: &MultiProgress,
        stages: &ProgressBar,
    ) -> anyhow::Result<TrainedModel> {
        let tr = &self.train;
        let manifest = tr.cache.manifest();
        let name = fraction_name(fraction);
        let model_dir = self.models.join("models").join(&name);
        let run_dir = self.models.join("train").join(&name);
        let picked = tr
            .cache
            .pick_scenes(Split::Train, fraction, tr.cfg.train.seed)?;
        let scenes: Vec<String> = picked
            .iter()
            .map(|&i| manifest.scenes[i as usize].name.clone())
            .collect();
        let recorded_hours = picked
            .iter()
            .map(|&i| manifest.scenes[i as usize].duration)
            .sum::<f64>()
            / 3600.0;

        stages.set_message(format!("training {name} ({} scenes)", scenes.len()));
        let stamp = Stamp {
            fraction,
            cache: tr.cache_dir.display().to_string(),
            net: tr.cfg.net.clone(),
            train: tr.cfg.train.clone(),
        };
        let stamp_path = model_dir.join(STAMP_FILE);
        let complete = model_dir.join(CARD_FILE).is_file()
            && model_dir.join(WEIGHTS_FILE).is_file()
            && std::fs::read_to_string(&stamp_path)
                .ok()
                .and_then(|t| toml::from_str::<Stamp>(&t).ok())
                .is_some_and(|s| s == stamp);
        let t0 = Instant::now();
        if complete {
            say(
                multi,
                format!("{name}: model {} is complete, reused", model_dir.display()),
            );
        } else {
            let ckpt = run_dir.join("checkpoint");
            let stale = stale_checkpoint(&ckpt, &tr.cfg.net, &tr.cfg.train);
            if let Some(why) = &stale {
                say(multi, format!("{name}: training afresh: {why}"));
            }
            let _ = std::fs::remove_file(&stamp_path);
            let _ = std::fs::remove_file(self.out.join(&name).join(CLOSED_LOOP_FILE));
            let fcfg = self.fraction_train_config(fraction, &name);
            say(
                multi,
                format!(
                    "{name}: training {} steps on {} of {} training scenes into {}",
                    fcfg.train.steps,
                    scenes.len(),
                    manifest.scenes_in(Split::Train).len(),
                    model_dir.display()
                ),
            );
            tch::set_num_threads(fcfg.run.threads as i32);
            multi
                .suspend(|| {
                    train::train(
                        &fcfg,
                        &tr.cache,
                        &run_dir,
                        &model_dir,
                        tr.device,
                        stale.is_some(),
                    )
                })
                .with_context(|| format!("training {name}"))?;
            let stamp_text = toml::to_string(&stamp).context("serialising the stamp")?;
            std::fs::write(&stamp_path, stamp_text)
                .with_context(|| format!("writing {}", stamp_path.display()))?;
        }
        let train_stage_s = t0.elapsed().as_secs_f64();
        let card = ModelCard::load(&model_dir.join(CARD_FILE))?;
        Ok(TrainedModel {
            name,
            model_dir,
            scenes,
            recorded_hours,
            stamp,
            complete,
            train_stage_s,
            card,
        })
    }

    /// The train config (with the scaling overrides of [`train_settings`]) for the fraction
    /// `name`: its share of the training scenes and its own run name.
    fn fraction_train_config(&self, fraction: f64, name: &str) -> TrainConfig {
        let mut fcfg = self.train.cfg.clone();
        fcfg.data.train_fraction = fraction;
        fcfg.run.name = format!("{}-{name}", self.train.cfg.run.name);
        fcfg
    }

    /// Writes the fraction's planner config, runs its closed loop (unless the stored rows
    /// were measured with equal settings) and writes its `results.csv`.
    fn closed_loop_stage(
        &self,
        fraction: f64,
        model: TrainedModel,
        multi: &MultiProgress,
        stages: &ProgressBar,
    ) -> anyhow::Result<FractionResult> {
        let name = &model.name;
        stages.set_message(format!(
            "closed loop {name} ({} episode runs)",
            self.suite.episodes.len() * self.robots.len()
        ));
        let t1 = Instant::now();
        let planner_dir = self.out.join(name);
        std::fs::create_dir_all(&planner_dir)
            .with_context(|| format!("creating {}", planner_dir.display()))?;
        let (fraction_planner, table) = self.write_planner(&planner_dir, fraction, &model)?;
        let cl_stamp = ClosedLoopStamp {
            model: model.stamp.clone(),
            planner: table,
            suite: self.suite.name.clone(),
            episodes: self.suite.episodes.iter().map(|e| e.id.clone()).collect(),
            robots: self
                .robots
                .iter()
                .map(|r| {
                    format!(
                        "{} (footprint {} m, {:?})",
                        r.name, r.footprint_radius, r.limits
                    )
                })
                .collect(),
            sim: self
                .bcfg
                .sim
                .with_replan_hz(human2nav_replan_hz(&self.bcfg)),
            seed: self.bcfg.seed,
        };
        let cl_path = planner_dir.join(CLOSED_LOOP_FILE);
        let (rows, measured) = match stored_rows(&cl_path, &cl_stamp) {
            Some(rows) => {
                say(
                    multi,
                    format!(
                        "{name}: closed-loop results in {} match these settings, reused",
                        cl_path.display()
                    ),
                );
                (rows, false)
            }
            None => {
                let rows = closed_loop(
                    &fraction_planner,
                    &self.bcfg,
                    &self.suite,
                    &self.robots,
                    multi,
                )?;
                let file = ClosedLoopFile {
                    stamp: cl_stamp,
                    rows,
                };
                let text = toml::to_string(&file).context("serialising the closed-loop rows")?;
                std::fs::write(&cl_path, text)
                    .with_context(|| format!("writing {}", cl_path.display()))?;
                (file.rows, true)
            }
        };
        let csv = planner_dir.join("results.csv");
        std::fs::write(&csv, results_csv(&rows))
            .with_context(|| format!("writing {}", csv.display()))?;
        let bench_stage_s = t1.elapsed().as_secs_f64();
        let s = summarize(&rows);
        say(
            multi,
            format!(
                "{name}: SR {:.3} ± {:.3} over {} episode runs ({:.0} s training stage, {:.0} s closed loop)",
                s.sr, s.sr_se, s.n, model.train_stage_s, bench_stage_s
            ),
        );
        let info = model.card.training.as_ref();
        Ok(FractionResult {
            fraction,
            train_tuples: info.map(|i| i.train_tuples).unwrap_or(0),
            steps: info.map(|i| i.steps).unwrap_or(0),
            final_val_loss: info.map(|i| i.final_val_loss).unwrap_or(f64::NAN),
            training_time_s: info.map(|i| i.wall_time_s).unwrap_or(f64::NAN),
            name: model.name,
            scenes: model.scenes,
            recorded_hours: model.recorded_hours,
            trained: !model.complete,
            measured,
            train_stage_s: model.train_stage_s,
            bench_stage_s,
            rows,
        })
    }

    /// Writes `planner_dir/planner.toml`: the planner config with the fraction's model;
    /// returns its path and table.
    fn write_planner(
        &self,
        planner_dir: &Path,
        fraction: f64,
        model: &TrainedModel,
    ) -> anyhow::Result<(PathBuf, toml::Table)> {
        let mut table = self.planner_table.clone();
        table.insert(
            "model".into(),
            toml::Value::String(model.model_dir.display().to_string()),
        );
        let fraction_planner = planner_dir.join("planner.toml");
        std::fs::write(
            &fraction_planner,
            format!(
                "# {} with the model trained on {:.0} % of the training scenes.\n{}",
                self.planner_path.display(),
                100.0 * fraction,
                toml::to_string(&table).context("serialising the planner config")?
            ),
        )
        .with_context(|| format!("writing {}", fraction_planner.display()))?;
        Ok((fraction_planner, table))
    }

    /// Writes the figure, `scaling.csv` and `report.md`.
    fn write_outputs(
        &self,
        request: &ScalingRequest,
        results: Vec<FractionResult>,
        started: Instant,
    ) -> anyhow::Result<ScalingOutcome> {
        let runs: Vec<(f64, Vec<ResultRow>)> = results
            .iter()
            .map(|r| (r.recorded_hours, r.rows.clone()))
            .collect();
        let points = scaling_points(&runs, &self.suite.name, METHOD);
        let png = self.out.join("fig5_sr_vs_training_data.png");
        sr_vs_training_data(
            &png,
            &points,
            &format!(
                "Human2Nav (guided): SR against training data, suite `{}`",
                self.suite.name
            ),
        )?;
        let csv = self.out.join("scaling.csv");
        std::fs::write(&csv, scaling_csv(&results))
            .with_context(|| format!("writing {}", csv.display()))?;
        let report = self.out.join("report.md");
        std::fs::write(
            &report,
            report_markdown(
                &results,
                &self.settings(request),
                &self.robots,
                request.quick,
                started.elapsed().as_secs_f64(),
            ),
        )
        .with_context(|| format!("writing {}", report.display()))?;
        Ok(ScalingOutcome {
            fractions: results,
            report,
            csv,
            figure: png,
            wall_time_s: started.elapsed().as_secs_f64(),
        })
    }

    /// The report's settings table.
    fn settings(&self, request: &ScalingRequest) -> Vec<(String, String)> {
        let tr = &self.train;
        let manifest = tr.cache.manifest();
        let (suite, bcfg) = (&self.suite, &self.bcfg);
        vec![
            ("command".to_string(), format!("`{}`", request.command())),
            ("train config".into(), format!("`{}`", tr.path.display())),
            (
                "tuple cache".into(),
                format!(
                    "`{}` ({} data, {} training scenes)",
                    tr.cache_dir.display(),
                    manifest.source,
                    manifest.scenes_in(Split::Train).len()
                ),
            ),
            (
                "training".into(),
                format!(
                    "{} steps of batch {} per model, seed {} (scene choice and training), {} torch thread(s), device {:?}",
                    tr.cfg.train.steps,
                    tr.cfg.train.batch_size,
                    tr.cfg.train.seed,
                    tr.cfg.run.threads,
                    tr.device
                ),
            ),
            (
                "bench config".into(),
                format!("`{}`", self.bench_path.display()),
            ),
            (
                "suite".into(),
                format!(
                    "`{}` ({}), {} episodes, up to {} per scenario class{}",
                    suite.name,
                    suite.kind.as_str(),
                    suite.episodes.len(),
                    self.per_class,
                    suite
                        .note
                        .as_ref()
                        .map(|n| format!(": {n}"))
                        .unwrap_or_default()
                ),
            ),
            (
                "robots".into(),
                self.robots
                    .iter()
                    .map(|r| format!("`{}`", r.name))
                    .collect::<Vec<_>>()
                    .join(", "),
            ),
            (
                "method".into(),
                format!(
                    "Human2Nav with guidance: `{}` with `model` replaced per fraction",
                    self.planner_path.display()
                ),
            ),
            (
                "episode seed".into(),
                format!(
                    "{} (the bench config's; identical draws for every fraction)",
                    bcfg.seed
                ),
            ),
            (
                "simulation".into(),
                format!(
                    "step {} s, replanning {} Hz, goal tolerance {} m, budget max(episode budget, {} × empty-world time + {} s)",
                    bcfg.sim.dt,
                    bcfg.sim.replan_hz,
                    bcfg.sim.goal_tolerance,
                    bcfg.sim.budget_factor,
                    bcfg.sim.budget_margin
                ),
            ),
        ]
    }
}

/// The replanning rate of the bench config's first `human2nav` method (the guided one), which
/// the scaling runs share.
fn human2nav_replan_hz(bcfg: &BenchConfig) -> Option<f64> {
    bcfg.methods
        .iter()
        .find(|m| m.kind == "human2nav")
        .and_then(|m| m.replan_hz)
}

/// Runs Human2Nav with guidance (the planner config at `planner`) on every episode of `suite`
/// for every robot, in parallel; rows in job order.
fn closed_loop(
    planner: &Path,
    bcfg: &BenchConfig,
    suite: &Suite,
    robots: &[RobotSetup],
    multi: &MultiProgress,
) -> anyhow::Result<Vec<ResultRow>> {
    let mut method_table = toml::Table::new();
    method_table.insert(
        "planner".into(),
        toml::Value::String(planner.display().to_string()),
    );
    let method = human2nav_method(
        &MethodConfig {
            name: METHOD.into(),
            kind: "human2nav".into(),
            library: None,
            plugin: None,
            config: method_table,
            replan_hz: human2nav_replan_hz(bcfg),
            deadline_ms: None,
            isolation: Default::default(),
        },
        bcfg,
    )?;
    let bar = multi.add(ProgressBar::new(0));
    bar.set_style(
        ProgressStyle::with_template(
            "{elapsed_precise} [{bar:30}] {pos}/{len} episode runs  ETA {eta}",
        )
        .unwrap_or_else(|_| ProgressStyle::default_bar())
        .progress_chars("=> "),
    );
    let rows = run_bench(
        std::slice::from_ref(suite),
        robots,
        std::slice::from_ref(&method),
        &bcfg.sim,
        bcfg.seed,
        &bar,
    );
    bar.finish_and_clear();
    multi.remove(&bar);
    Ok(rows?)
}

/// `scaling.csv`: one row per fraction (SR overall and per scenario class, over every robot).
fn scaling_csv(results: &[FractionResult]) -> String {
    let mut out = String::from(
        "fraction,train_scenes,recorded_hours,train_tuples,steps,final_val_loss,episode_runs,sr,sr_se,\
         sr_co_flow,sr_cross_flow,sr_counter_flow,sr_multidirection_flow,tfs,collision_rate,\
         timeout_rate,model,closed_loop,training_time_s,train_stage_s,bench_stage_s\n",
    );
    for r in results {
        let s = summarize(&r.rows);
        let class_sr: Vec<String> = ScenarioClass::ALL
            .iter()
            .map(|&c| {
                let cs = summarize(r.rows.iter().filter(|x| x.scenario == c));
                if cs.n > 0 {
                    format!("{:.6}", cs.sr)
                } else {
                    String::new()
                }
            })
            .collect();
        let _ = writeln!(
            out,
            "{},{},{:.4},{},{},{:.6},{},{:.6},{:.6},{},{:.6},{:.6},{:.6},{},{},{:.1},{:.1},{:.1}",
            r.fraction,
            r.scenes.len(),
            r.recorded_hours,
            r.train_tuples,
            r.steps,
            r.final_val_loss,
            s.n,
            s.sr,
            s.sr_se,
            class_sr.join(","),
            s.tfs,
            s.collision_rate,
            s.timeout_rate,
            if r.trained { "trained" } else { "reused" },
            if r.measured { "measured" } else { "reused" },
            r.training_time_s,
            r.train_stage_s,
            r.bench_stage_s
        );
    }
    out
}

/// A share as a percentage with one decimal.
fn pct(v: f64) -> String {
    format!("{:.1}", 100.0 * v)
}

/// `report.md`: settings, the SR table per fraction (overall with its standard error, per
/// scenario class, per robot), the training record and the wall time of every stage.
fn report_markdown(
    results: &[FractionResult],
    settings: &[(String, String)],
    robots: &[RobotSetup],
    quick: bool,
    wall_s: f64,
) -> String {
    let mut md = String::new();
    report_intro(&mut md, settings, quick, wall_s);
    sr_table(&mut md, results);
    if robots.len() > 1 {
        robot_table(&mut md, results, robots);
    }
    models_table(&mut md, results);
    md
}

/// The report's title, what it measures, its wall time and the settings table.
fn report_intro(md: &mut String, settings: &[(String, String)], quick: bool, wall_s: f64) {
    let _ = writeln!(
        md,
        "# Success rate against the amount of human training data (paper Fig. 5)\n"
    );
    let _ = writeln!(
        md,
        "The flow model is retrained on each share of the training scenes (a seeded choice; the \
         smaller subsets are contained in the larger ones) and Human2Nav with guidance runs closed \
         loop on the same episodes. SR = success rate (goal reached within the time budget without \
         collision), in %; ± is the standard error sqrt(SR(1 − SR)/n).{}\n",
        if quick {
            " **Quick mode**: short trainings and a few episodes per class; the numbers only show \
             that the pipeline works."
        } else {
            ""
        }
    );
    let _ = writeln!(
        md,
        "Total wall time: {wall_s:.1} s. Figure: [fig5_sr_vs_training_data.png](fig5_sr_vs_training_data.png); \
         one row per fraction in [scaling.csv](scaling.csv); per-episode rows in `frac-<pct>/results.csv`.\n"
    );
    let _ = writeln!(md, "## Settings\n\n| setting | value |\n|---|---|");
    for (k, v) in settings {
        let _ = writeln!(md, "| {k} | {} |", v.replace('|', "\\|"));
    }
}

/// SR per fraction: overall with its standard error, per scenario class, TFS and the failure
/// rates.
fn sr_table(md: &mut String, results: &[FractionResult]) {
    let _ = writeln!(md, "\n## SR per fraction of the training scenes\n");
    let mut header =
        String::from("| training data | recorded hours | scenes | tuples | n | SR (%) |");
    let mut rule = String::from("|---|---|---|---|---|---|");
    for c in ScenarioClass::ALL {
        let _ = write!(header, " {} (%) |", c.title());
        rule.push_str("---|");
    }
    header.push_str(" TFS | collision (%) | timeout (%) |");
    rule.push_str("---|---|---|");
    let _ = writeln!(md, "{header}\n{rule}");
    for r in results {
        let s = summarize(&r.rows);
        let mut line = format!(
            "| {:.0} % | {:.2} | {} | {} | {} | {} ± {} |",
            100.0 * r.fraction,
            r.recorded_hours,
            r.scenes.len(),
            r.train_tuples,
            s.n,
            pct(s.sr),
            pct(s.sr_se)
        );
        for c in ScenarioClass::ALL {
            let cs = summarize(r.rows.iter().filter(|x| x.scenario == c));
            if cs.n > 0 {
                let _ = write!(line, " {} |", pct(cs.sr));
            } else {
                line.push_str(" – |");
            }
        }
        let _ = write!(
            line,
            " {:.3} | {} | {} |",
            s.tfs,
            pct(s.collision_rate),
            pct(s.timeout_rate)
        );
        let _ = writeln!(md, "{line}");
    }
}

/// SR per fraction and robot, with standard errors.
fn robot_table(md: &mut String, results: &[FractionResult], robots: &[RobotSetup]) {
    let _ = writeln!(md, "\n## SR per robot (%)\n");
    let mut header = String::from("| training data |");
    let mut rule = String::from("|---|");
    for r in robots {
        let _ = write!(header, " {} |", r.name);
        rule.push_str("---|");
    }
    let _ = writeln!(md, "{header}\n{rule}");
    for r in results {
        let mut line = format!("| {:.0} % |", 100.0 * r.fraction);
        for robot in robots {
            let s = summarize(r.rows.iter().filter(|x| x.robot == robot.name));
            let _ = write!(line, " {} ± {} |", pct(s.sr), pct(s.sr_se));
        }
        let _ = writeln!(md, "{line}");
    }
}

/// Each fraction's model, its training record and the wall time of both stages, then the
/// training scenes per fraction.
fn models_table(md: &mut String, results: &[FractionResult]) {
    let _ = writeln!(md, "\n## Models and wall time per stage\n");
    let _ = writeln!(
        md,
        "| training data | model | steps | final val loss | training time (card, s) | training stage (s) | closed-loop stage (s) |\n\
         |---|---|---|---|---|---|---|"
    );
    for r in results {
        let _ = writeln!(
            md,
            "| {:.0} % | `models/{}` ({}) | {} | {:.4} | {:.1} | {:.1} | {:.1}{} |",
            100.0 * r.fraction,
            r.name,
            if r.trained {
                "trained now"
            } else {
                "complete, reused"
            },
            r.steps,
            r.final_val_loss,
            r.training_time_s,
            r.train_stage_s,
            r.bench_stage_s,
            if r.measured {
                ""
            } else {
                " (stored rows reused)"
            }
        );
    }
    let _ = writeln!(md, "\nTraining scenes per fraction:\n");
    for r in results {
        let _ = writeln!(
            md,
            "- {:.0} % ({} scenes): {}",
            100.0 * r.fraction,
            r.scenes.len(),
            r.scenes.join(", ")
        );
    }
}
