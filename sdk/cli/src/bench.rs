//! `human2nav bench`: the closed-loop benchmark (suites × robots × methods) and its report.
//! The benchmark itself is [`human2nav_experiments::bench`]; this module parses the options,
//! shows progress and prints the outcome.

use clap::Args;
use human2nav_experiments::bench::{Bench, BenchRequest};
use indicatif::{ProgressBar, ProgressStyle};
use std::io::IsTerminal;
use std::path::PathBuf;
use std::process::ExitCode;

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

impl BenchArgs {
    /// The library's request of these options.
    fn request(self) -> BenchRequest {
        BenchRequest {
            config: self.config,
            out: self.out,
            quick: self.quick,
            seed: self.seed,
            threads: self.threads,
            data_config: self.data_config,
            failures: self.failures,
            methods: self.methods,
            robots: self.robots,
            suites: self.suites,
        }
    }
}

/// Runs the benchmark; fails when a method misses SR = 1 on an empty-world suite or a planner
/// call failed.
pub fn run(args: BenchArgs) -> anyhow::Result<ExitCode> {
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
        let outcome = bench.run(&bar);
        done.store(true, std::sync::atomic::Ordering::Relaxed);
        outcome
    })?;

    for f in bench.plugin_failures() {
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
