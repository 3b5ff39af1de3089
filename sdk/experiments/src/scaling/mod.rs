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

mod report;
mod setup;
mod stages;

use crate::train::TrainConfig;
use anyhow::{Context, bail};
use human2nav_core::input::{MAX_CONFIG_BYTES, read_user_file};
use human2nav_core::lock::DirLock;
use human2nav_data::cache::TupleCache;
use human2nav_flow::tch;
use human2nav_sim::config::BenchConfig;
use human2nav_sim::{ResultRow, RobotSetup, Suite};
use indicatif::{MultiProgress, ProgressBar, ProgressStyle};
use serde::Deserialize;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Name of the method in the results (Human2Nav with guidance).
const METHOD: &str = "human2nav";

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
