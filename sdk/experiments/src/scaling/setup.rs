//! Loading a scaling run's settings before the first training: the train config with the
//! scaling overrides, the measured suite, the robots and the planner configuration.

use super::{ScalingConfig, ScalingRequest, Setup, TrainSettings, resolve};
use crate::bench::ensure_real_episodes;
use crate::train::{self, TrainConfig};
use anyhow::{Context, bail};
use human2nav_core::input::{MAX_CONFIG_BYTES, read_user_file};
use human2nav_flow::planner::{PlannerConfig, load_profile};
use human2nav_sim::config::{BenchConfig, build_suites, load_robots};
use human2nav_sim::{RobotSetup, Suite, SuiteKind};
use std::path::{Path, PathBuf};

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
    pub(super) fn load(
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
}
