//! `human2nav bench`: the closed-loop benchmark (suites × robots × methods) and its report.
//! The benchmark itself is [`human2nav_experiments::bench`]; this module parses the options,
//! shows progress and prints the outcome.

use clap::Args;
use human2nav_experiments::bench::{Bench, BenchRequest};
use human2nav_sim::driver::BenchOutcome;
use human2nav_sim::report::PlannerFailures;
use human2nav_sim::shard::ShardSpec;
use indicatif::{ProgressBar, ProgressStyle};
use std::io::IsTerminal;
use std::path::PathBuf;
use std::process::ExitCode;

/// Arguments of `human2nav bench`.
#[derive(Debug, Args)]
pub struct BenchArgs {
    /// Benchmark configuration (TOML); relative paths inside it resolve against the workspace
    /// root [default: sdk/configs/bench.toml; with --merge, the one the shards name].
    #[arg(long)]
    pub config: Option<PathBuf>,
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
    /// Also write every run as an MCAP file that Foxglove opens (robot, footprint, people,
    /// obstacles, goal, each plan and its candidates, the outcome) under <out>/record/, as
    /// <suite>/<robot>/<method>/<episode>.mcap (zstd chunks, 0.1 to 0.3 MB per run: narrow with
    /// --quick, --suites, --methods and --robots). With --shard, each shard records its own
    /// runs, and --merge gathers them.
    #[arg(long)]
    pub record: bool,
    /// Run only the K-th of N slices of the runs (K from 1 to N; run i, counted from 0 in the
    /// order suite, robot, method, episode, belongs to slice i mod N + 1) and write them with
    /// what `--merge` needs (results.csv, results-exact.csv, shard.json) to the output folder
    /// [default: out/bench/shard-K-of-N, or under out/bench-quick with --quick]. No report or
    /// figures: `--merge` writes them.
    #[arg(long, value_name = "K/N", value_parser = parse_shard)]
    pub shard: Option<ShardSpec>,
    /// Join the folders of all N shards into the results.csv, report.md and figures one run
    /// writes (results.csv byte for byte; the figures re-run the runs they draw), and, when the
    /// shards ran with --record, their recordings into <out>/record/ as one run lays them out
    /// (hard links, or copies across file systems; shards that recorded and shards that did not
    /// are refused). The options come from the shards; `--out`, `--threads` and `--config` (when
    /// the configuration has moved; it must be the same) may be given.
    #[arg(
        long,
        value_name = "DIR",
        num_args = 1..,
        conflicts_with_all = ["quick", "seed", "methods", "robots", "suites", "failures", "shard", "data_config", "record"]
    )]
    pub merge: Vec<PathBuf>,
}

/// `--shard`'s parser: [`ShardSpec`]'s own, which says what is wrong.
fn parse_shard(s: &str) -> Result<ShardSpec, String> {
    s.parse()
}

impl BenchArgs {
    /// The library's request of these options.
    fn request(self) -> BenchRequest {
        BenchRequest {
            config: self
                .config
                .unwrap_or_else(|| PathBuf::from("sdk/configs/bench.toml")),
            out: self.out,
            quick: self.quick,
            seed: self.seed,
            threads: self.threads,
            data_config: self.data_config,
            failures: self.failures,
            methods: self.methods,
            robots: self.robots,
            suites: self.suites,
            shard: self.shard,
            record: self.record,
        }
    }
}

/// Runs the benchmark; fails when a method misses SR = 1 on an empty-world suite or a planner
/// call failed.
pub fn run(args: BenchArgs) -> anyhow::Result<ExitCode> {
    if !args.merge.is_empty() {
        return merge(args);
    }
    let shard = args.shard;
    let bench = Bench::prepare(&args.request(), &|m| eprintln!("{m}"))?;
    for s in bench.suites() {
        eprintln!("suite `{}`: {} episodes", s.name, s.episodes.len());
        match &s.note {
            Some(note) if note.starts_with("Warning:") => {
                eprintln!("  warning: {}", &note[8..].trim_start())
            }
            Some(note) => eprintln!("  {note}"),
            None => {}
        }
    }
    let bar = progress_bar();
    if shard.is_some() {
        return run_shard(&bench, &bar);
    }
    let done = std::sync::atomic::AtomicBool::new(false);
    let outcome = std::thread::scope(|scope| {
        if !std::io::stderr().is_terminal() {
            scope.spawn(|| log_progress(&bar, &done));
        }
        let outcome = bench.run(&bar);
        done.store(true, std::sync::atomic::Ordering::Relaxed);
        outcome
    })?;
    let embodiment_failed = report_plugin_failures(&bench);
    let code = print_outcome(&outcome)?;
    Ok(if embodiment_failed {
        ExitCode::FAILURE
    } else {
        code
    })
}

/// Prints the plugin instances that failed; true when one was a robot's embodiment, whose
/// failure halts that robot and leaves its runs meaningless (a planner plugin's failures are
/// counted per call instead, and judged with the outcome).
fn report_plugin_failures(bench: &Bench) -> bool {
    let mut embodiment = false;
    for f in bench.plugin_failures() {
        if f.kind == human2nav_plugin::PluginKind::Embodiment {
            embodiment = true;
            eprintln!(
                "error: {} failed, so the runs of its robot are not valid: {}",
                f.instance, f.message
            );
        } else {
            eprintln!("warning: a plugin instance failed: {f:?}");
        }
    }
    embodiment
}

/// The progress bar of the episode runs.
fn progress_bar() -> ProgressBar {
    ProgressBar::new(0).with_style(
        ProgressStyle::with_template(
            "{elapsed_precise} [{bar:40}] {pos}/{len} episode runs, ETA {eta}",
        )
        .unwrap_or_else(|_| ProgressStyle::default_bar())
        .progress_chars("=> "),
    )
}

/// `--shard K/N`: runs the slice and writes the shard folder.
fn run_shard(bench: &Bench, bar: &ProgressBar) -> anyhow::Result<ExitCode> {
    let done = std::sync::atomic::AtomicBool::new(false);
    let outcome = std::thread::scope(|scope| {
        if !std::io::stderr().is_terminal() {
            scope.spawn(|| log_progress(bar, &done));
        }
        let outcome = bench.run_shard(bar);
        done.store(true, std::sync::atomic::Ordering::Relaxed);
        outcome
    })?;
    let embodiment_failed = report_plugin_failures(bench);
    println!(
        "shard {}: {} of {} episode runs in {:.1} s",
        outcome.spec,
        outcome.rows.len(),
        outcome.total_runs,
        outcome.wall_time
    );
    for f in &outcome.files {
        println!("wrote:   {}", f.display());
    }
    println!(
        "when all {} shards are done: human2nav bench --merge <their folders> [--out DIR]",
        outcome.spec.count
    );
    print_failures(&outcome.planner_failures, &outcome.empty_world_failures);
    Ok(if outcome.passed() && !embodiment_failed {
        ExitCode::SUCCESS
    } else {
        ExitCode::FAILURE
    })
}

/// `--merge DIR...`: joins the shards into one run's output.
fn merge(args: BenchArgs) -> anyhow::Result<ExitCode> {
    let outcome = Bench::merge(
        &args.merge,
        args.config.as_deref(),
        args.out,
        args.threads,
        &|m| eprintln!("{m}"),
    )?;
    print_outcome(&outcome)
}

/// Prints where a run's output went and what failed; the exit code says whether it passed.
fn print_outcome(outcome: &BenchOutcome) -> anyhow::Result<ExitCode> {
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
    print_failures(&outcome.planner_failures, &outcome.empty_world_failures);
    if outcome.passed() {
        Ok(ExitCode::SUCCESS)
    } else {
        Ok(ExitCode::FAILURE)
    }
}

/// The failed planner calls and the empty-world misses, on stderr.
fn print_failures(planner: &[PlannerFailures], empty_world: &[(String, String, f64)]) {
    for f in planner {
        eprintln!(
            "planner calls FAILED: method `{}` on robot `{}`: {} of {} calls in {} runs ({} runs \
             where every call failed)",
            f.method, f.robot, f.failed, f.calls, f.runs, f.runs_all_failed
        );
    }
    for (m, r, sr) in empty_world {
        eprintln!(
            "empty-world sanity FAILED: method `{m}` on robot `{r}`: SR = {:.1} %",
            100.0 * sr
        );
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
