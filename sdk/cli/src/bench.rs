//! `human2nav bench`: the closed-loop benchmark (suites × robots × methods) and its report.
//!
//! Method kinds: `straight` and `plugin` (ORCA ships as a plugin) are built by
//! [`human2nav_sim::config::builtin_method`]; `human2nav` (the reference planner with the
//! shipped flow model, see [`human2nav_method`]) is built here because it needs libtorch.
//!
//! Episodes: a `real` suite reads its episode file; when the file is missing but the datasets
//! are present (per `--data-config`), its episodes are mined first exactly as
//! `human2nav data episodes` does and written there. Without the datasets the suite falls back
//! to synthetic episodes, with a warning on stderr and in the report.

use anyhow::{Context, anyhow, bail};
use clap::Args;
use human2nav_core::ablation::Arm;
use human2nav_core::human2nav::Human2NavSettings;
use human2nav_core::lock::DirLock;
use human2nav_flow::planner::{PlannerConfig, PlannerModel, RobotPlanner, load_model};
use human2nav_plugin::PluginHost;
use human2nav_sim::MethodSpec;
use human2nav_sim::config::MethodConfig;
use human2nav_sim::config::{
    BenchConfig, build_suites, builtin_method, ensure_episode_files, load_robots_with,
};
use human2nav_sim::driver::{self, BenchPlan};
use indicatif::{ProgressBar, ProgressStyle};
use std::collections::HashMap;
use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::Arc;

/// Arguments of `human2nav bench`.
#[derive(Debug, Args)]
pub struct BenchArgs {
    /// Benchmark configuration (TOML); relative paths inside it resolve against the workspace
    /// root.
    #[arg(long, default_value = "sdk/configs/bench.toml")]
    pub config: PathBuf,
    /// Output directory for results.csv, report.md and the figures [default: out/bench, or
    /// out/bench-quick with --quick, under the workspace root].
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Run a few episodes per scenario class (each suite's `quick_per_class`).
    #[arg(long)]
    pub quick: bool,
    /// Override the configuration's seed.
    #[arg(long)]
    pub seed: Option<u64>,
    /// Worker threads for the episodes [default: one per core].
    #[arg(long)]
    pub threads: Option<usize>,
    /// Data configuration used to mine the held-out episodes when a real suite's file is
    /// missing and the datasets are present.
    #[arg(long, default_value = "sdk/configs/data.toml")]
    pub data_config: PathBuf,
    /// Failed runs to draw per method (`failures_<method>_<k>.png`, four per figure; those the
    /// most other methods succeeded on first) [default: 4, or 1 with --quick].
    #[arg(long)]
    pub failures: Option<usize>,
    /// Run only these methods of the configuration (names, comma-separated).
    #[arg(long, value_delimiter = ',')]
    pub methods: Vec<String>,
    /// Run only these robots of the configuration (names, comma-separated).
    #[arg(long, value_delimiter = ',')]
    pub robots: Vec<String>,
    /// Run only these suites of the configuration (names, comma-separated). An `empty` suite
    /// still takes its episodes from the configuration's first other suite.
    #[arg(long, value_delimiter = ',')]
    pub suites: Vec<String>,
}

/// Keeps the items named in `only` (all when it is empty); an unknown name is an error that
/// lists the known ones.
fn select<T>(
    items: Vec<T>,
    only: &[String],
    what: &str,
    name: impl Fn(&T) -> &str,
) -> anyhow::Result<Vec<T>> {
    if only.is_empty() {
        return Ok(items);
    }
    let known: Vec<&str> = items.iter().map(&name).collect();
    if let Some(bad) = only.iter().find(|o| !known.contains(&o.as_str())) {
        bail!(
            "--{what}s: no {what} `{bad}` in the configuration (it has {})",
            known.join(", ")
        );
    }
    Ok(items
        .into_iter()
        .filter(|i| only.iter().any(|o| o == name(i)))
        .collect())
}

/// Runs the benchmark; fails when a method misses SR = 1 on an empty-world suite or a planner
/// call failed.
pub fn run(args: BenchArgs) -> anyhow::Result<ExitCode> {
    let mut cfg = BenchConfig::load(&args.config)
        .with_context(|| format!("loading {}", args.config.display()))?;
    if let Some(seed) = args.seed {
        cfg.seed = seed;
    }
    let out = match &args.out {
        Some(p) => p.clone(),
        None => cfg.base_dir.join(if args.quick {
            "out/bench-quick"
        } else {
            "out/bench"
        }),
    };
    let _lock = DirLock::acquire(&out, "human2nav bench")
        .with_context(|| format!("locking the output folder {}", out.display()))?;
    let host = Arc::new(PluginHost::new());
    let robots = select(load_robots_with(&cfg, &host)?, &args.robots, "robot", |r| {
        &r.name
    })?;
    let mut methods: Vec<MethodSpec> = Vec::new();
    let configured = select(cfg.methods.clone(), &args.methods, "method", |m| &m.name)?;
    for m in &configured {
        match builtin_method(m, &cfg, &host)? {
            Some(spec) => methods.push(spec),
            None if m.kind == "human2nav" => methods.push(human2nav_method(m, &cfg)?),
            None => bail!(
                "method `{}`: unknown kind `{}` (this build knows `straight`, `plugin` and `human2nav`)",
                m.name,
                m.kind
            ),
        }
    }
    // Check the names before mining anything.
    select(cfg.suites.clone(), &args.suites, "suite", |s| &s.name)?;
    // A relative data config that is not there from the current directory is the workspace's.
    let data_config = if args.data_config.is_relative() && !args.data_config.exists() {
        cfg.base_dir.join(&args.data_config)
    } else {
        args.data_config.clone()
    };
    let fallback = ensure_real_episodes(&cfg, &data_config)?;
    let suites = select(
        build_suites(&cfg, args.quick, fallback.as_deref())?,
        &args.suites,
        "suite",
        |s| &s.name,
    )?;
    for s in &suites {
        eprintln!("suite `{}`: {} episodes", s.name, s.episodes.len());
        match &s.note {
            Some(note) if note.starts_with("Warning:") => {
                eprintln!("  warning: {}", &note[8..].trim_start())
            }
            Some(note) => eprintln!("  {note}"),
            None => {}
        }
    }

    let list = |flag: &str, names: &[String]| {
        if names.is_empty() {
            String::new()
        } else {
            format!(" --{flag} {}", names.join(","))
        }
    };
    // The options that shape the report (--out and --threads do not change its numbers).
    let command = format!(
        "human2nav bench --config {}{}{}{}{}{}{}",
        args.config.display(),
        if args.quick { " --quick" } else { "" },
        args.seed
            .map(|s| format!(" --seed {s}"))
            .unwrap_or_default(),
        list("methods", &args.methods),
        list("robots", &args.robots),
        list("suites", &args.suites),
        args.failures
            .map(|n| format!(" --failures {n}"))
            .unwrap_or_default()
    );
    let plan = BenchPlan {
        suites: &suites,
        robots: &robots,
        methods: &methods,
        sim: &cfg.sim,
        seed: cfg.seed,
        quick: args.quick,
        snapshot_method: cfg.snapshot_method(),
        command,
        threads: args.threads,
        failures: args.failures.unwrap_or(if args.quick { 1 } else { 4 }),
    };
    let bar = ProgressBar::new(0).with_style(
        ProgressStyle::with_template(
            "{elapsed_precise} [{bar:40}] {pos}/{len} episode runs, ETA {eta}",
        )
        .unwrap_or_else(|_| ProgressStyle::default_bar())
        .progress_chars("=> "),
    );
    let done = std::sync::atomic::AtomicBool::new(false);
    let outcome = std::thread::scope(|scope| {
        if !std::io::stderr().is_terminal() {
            scope.spawn(|| log_progress(&bar, &done));
        }
        let outcome = driver::run(&plan, &out, &bar);
        done.store(true, std::sync::atomic::Ordering::Relaxed);
        outcome
    })?;

    for f in host.failures() {
        eprintln!("warning: a plugin instance failed: {f:?}");
    }
    println!(
        "{} episode runs in {:.1} s",
        outcome.rows.len(),
        outcome.wall_time
    );
    for (m, runs, secs) in &outcome.times.per_method {
        if *runs > 0 {
            println!(
                "  {m}: {runs} runs, {secs:.0} thread-s ({:.2} s per run)",
                secs / *runs as f64
            );
        }
    }
    println!("report:  {}", outcome.report_md.display());
    println!("results: {}", outcome.results_csv.display());
    for f in &outcome.figures {
        println!("figure:  {}", f.display());
    }
    for f in &outcome.planner_failures {
        eprintln!(
            "planner calls FAILED: method `{}` on robot `{}`: {} of {} calls in {} runs ({} runs \
             where every call failed)",
            f.method, f.robot, f.failed, f.calls, f.runs, f.runs_all_failed
        );
    }
    for (m, r, sr) in &outcome.empty_world_failures {
        eprintln!(
            "empty-world sanity FAILED: method `{m}` on robot `{r}`: SR = {:.1} %",
            100.0 * sr
        );
    }
    if outcome.passed() {
        Ok(ExitCode::SUCCESS)
    } else {
        Ok(ExitCode::FAILURE)
    }
}

/// Where stderr is not a terminal (a log file, CI), the progress bar draws nothing: print its
/// position, elapsed time and ETA as a line once a minute instead, until `done`.
fn log_progress(bar: &ProgressBar, done: &std::sync::atomic::AtomicBool) {
    let tick = std::time::Duration::from_millis(500);
    let mut waited = std::time::Duration::ZERO;
    while !done.load(std::sync::atomic::Ordering::Relaxed) {
        std::thread::sleep(tick);
        waited += tick;
        if waited.as_secs() < 60 {
            continue;
        }
        waited = std::time::Duration::ZERO;
        let Some(len) = bar.length().filter(|&n| n > 0) else {
            continue;
        };
        let pos = bar.position();
        if pos < len {
            eprintln!(
                "{pos}/{len} episode runs, {:.0} s elapsed, ETA {:.0} s",
                bar.elapsed().as_secs_f64(),
                bar.eta().as_secs_f64()
            );
        } else {
            eprintln!(
                "all {len} episode runs done; drawing the figures (the snapshots and failure \
                 pictures run their episodes again)"
            );
            return;
        }
    }
}

/// [`ensure_episode_files`], telling stderr what it mines.
pub(crate) fn ensure_real_episodes(
    cfg: &BenchConfig,
    data_config: &Path,
) -> anyhow::Result<Option<String>> {
    Ok(ensure_episode_files(cfg, data_config, &|m| {
        eprintln!("{m}")
    })?)
}

/// A `human2nav` method: the reference planner with the model and settings of a planner
/// configuration. Its `config` table takes `planner` (the planner TOML, relative to the
/// workspace root; default `sdk/configs/planner.toml`) and either `guidance` (bool; `false` is
/// the "w/o guidance" ablation) or `arm` (one of the guidance ablation's arms, `raw`, `alg1`,
/// `qp` or `alg1+qp`, see [`human2nav_core::ablation::Arm`]). Each episode gets a fresh planner (model loaded from disk, source
/// noise seeded with the episode's seed) for the robot of that episode, with the robot's Φ
/// including its plugin constraint terms; libtorch runs one thread per planner (the episodes
/// already run in parallel).
pub(crate) fn human2nav_method(m: &MethodConfig, cfg: &BenchConfig) -> anyhow::Result<MethodSpec> {
    let field = |key: &str| format!("methods[{}].config.{key}", m.name);
    for key in m.config.keys() {
        if !["planner", "guidance", "arm"].contains(&key.as_str()) {
            bail!(
                "{}: unknown key (expected `planner`, `guidance` or `arm`)",
                field(key)
            );
        }
    }
    if m.config.contains_key("guidance") && m.config.contains_key("arm") {
        bail!(
            "{}: give `guidance` or `arm`, not both (`arm = \"raw\"` is `guidance = false`)",
            field("arm")
        );
    }
    let planner_toml = match m.config.get("planner") {
        Some(v) => cfg
            .resolve(Path::new(v.as_str().ok_or_else(|| {
                anyhow!("{}: must be a path", field("planner"))
            })?)),
        None => cfg.resolve(Path::new("sdk/configs/planner.toml")),
    };
    let mut planner_cfg = PlannerConfig::load(&planner_toml)?;
    if let Some(v) = m.config.get("guidance") {
        planner_cfg.human2nav.guidance.enabled = v
            .as_bool()
            .ok_or_else(|| anyhow!("{}: must be true or false", field("guidance")))?;
    }
    if let Some(v) = m.config.get("arm") {
        let arm: Arm = v
            .as_str()
            .ok_or_else(|| anyhow!("{}: must be a string", field("arm")))?
            .parse()
            .map_err(|e| anyhow!("{}: {e}", field("arm")))?;
        planner_cfg.human2nav = arm.settings(&planner_cfg.human2nav);
    }
    let model_dir = planner_cfg.model_dir(&cfg.base_dir);
    let backend = planner_cfg.backend;
    // Fail now, with the folder named, rather than once per episode; the native weights are
    // read this once and shared by every run's planner.
    let shared =
        match load_model(&model_dir, backend).with_context(|| format!("method `{}`", m.name))? {
            PlannerModel::Native(model) => Some(model),
            PlannerModel::Torch(_) => None,
        };
    human2nav_flow::tch::set_num_threads(1);

    let mut profiles = HashMap::new();
    for path in &cfg.robots {
        let path = cfg.resolve(path);
        let profile = human2nav_flow::planner::load_profile(&path)?;
        profiles.insert(profile.name.clone(), profile);
    }
    let settings = planner_cfg.human2nav;
    Ok(MethodSpec::new(m.name.clone(), move |ctx| {
        let profile = profiles
            .get(&ctx.robot.name)
            .cloned()
            .ok_or_else(|| format!("no robot profile named `{}`", ctx.robot.name))?;
        let model = match &shared {
            Some(native) => PlannerModel::Native(native.clone()),
            None => load_model(&model_dir, backend)?,
        };
        let planner = RobotPlanner::new(
            profile,
            model,
            Human2NavSettings {
                seed: ctx.seed,
                ..settings
            },
        )?;
        Ok(Box::new(planner.planner))
    })
    .with_replan_hz(m.replan_hz))
}
