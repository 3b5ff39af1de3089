//! `human2nav bench`: the closed-loop benchmark (suites × robots × methods) and its report.
//!
//! Method kinds: `straight` and `plugin` (ORCA ships as a plugin) are built by
//! [`human2nav_sim::config::builtin_method`]; any other kind is an error in this build.

use anyhow::{Context, bail};
use clap::Args;
use human2nav_plugin::PluginHost;
use human2nav_sim::MethodSpec;
use human2nav_sim::config::{BenchConfig, build_suites, builtin_method, load_robots};
use human2nav_sim::driver::{self, BenchPlan};
use indicatif::{ProgressBar, ProgressStyle};
use std::path::PathBuf;
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
}

/// Runs the benchmark; fails when a method misses SR = 1 on an empty-world suite.
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
    let robots = load_robots(&cfg)?;
    let host = Arc::new(PluginHost::new());
    let mut methods: Vec<MethodSpec> = Vec::new();
    for m in &cfg.methods {
        match builtin_method(m, &cfg, &host)? {
            Some(spec) => methods.push(spec),
            None => bail!(
                "method `{}`: unknown kind `{}` (this build knows `straight` and `plugin`)",
                m.name,
                m.kind
            ),
        }
    }
    let suites = build_suites(&cfg, args.quick)?;
    for s in &suites {
        eprintln!("suite `{}`: {} episodes", s.name, s.episodes.len());
        if let Some(note) = &s.note {
            eprintln!("  {note}");
        }
    }

    let command = format!(
        "human2nav bench --config {}{}{}",
        args.config.display(),
        if args.quick { " --quick" } else { "" },
        args.seed
            .map(|s| format!(" --seed {s}"))
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
    };
    let bar = ProgressBar::new(0).with_style(
        ProgressStyle::with_template(
            "{elapsed_precise} [{bar:40}] {pos}/{len} episode runs, ETA {eta}",
        )
        .unwrap_or_else(|_| ProgressStyle::default_bar())
        .progress_chars("=> "),
    );
    let outcome = driver::run(&plan, &out, &bar)?;

    for f in host.failures() {
        eprintln!("warning: a plugin instance failed: {f:?}");
    }
    println!(
        "{} episode runs in {:.1} s",
        outcome.rows.len(),
        outcome.wall_time
    );
    println!("report:  {}", outcome.report_md.display());
    println!("results: {}", outcome.results_csv.display());
    for f in &outcome.figures {
        println!("figure:  {}", f.display());
    }
    if outcome.empty_world_failures.is_empty() {
        return Ok(ExitCode::SUCCESS);
    }
    for (m, r, sr) in &outcome.empty_world_failures {
        eprintln!(
            "empty-world sanity FAILED: method `{m}` on robot `{r}`: SR = {:.1} %",
            100.0 * sr
        );
    }
    Ok(ExitCode::FAILURE)
}
