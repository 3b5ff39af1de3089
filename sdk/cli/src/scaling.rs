//! `human2nav scaling`: SR against the amount of training data (the paper's Fig. 5). The
//! experiment itself is [`human2nav_experiments::scaling`]; this module parses the options and
//! prints where the outputs went.

use clap::Args;
use human2nav_experiments::scaling::{self, ScalingRequest};
use indicatif::MultiProgress;
use std::path::PathBuf;
use std::process::ExitCode;

/// Arguments of `human2nav scaling`.
#[derive(Debug, Args)]
pub struct ScalingArgs {
    /// Scaling configuration (TOML); relative paths inside it resolve against the workspace
    /// root.
    #[arg(long, default_value = "sdk/configs/scaling.toml")]
    config: PathBuf,
    /// Output directory [default: out/scaling, or out/scaling-quick with --quick, under the
    /// workspace root].
    #[arg(long)]
    out: Option<PathBuf>,
    /// Short check: `quick_steps` training steps per model, the suite's `quick_per_class`
    /// episodes per scenario class and the `quick_robots`.
    #[arg(long)]
    quick: bool,
    /// Torch threads for training [default: the train config's `run.threads`]. The episodes
    /// run on one worker per core (`RAYON_NUM_THREADS` overrides).
    #[arg(long)]
    threads: Option<usize>,
    /// Measure this suite of the bench config instead of the scaling config's `suite`.
    #[arg(long)]
    suite: Option<String>,
    /// Folder of the fraction models and their training runs (`models/`, `train/`)
    /// [default: the output directory]. Give an earlier run's --out to measure its models on
    /// another suite without training them again.
    #[arg(long)]
    models: Option<PathBuf>,
}

/// Runs `human2nav scaling`.
pub fn run(args: ScalingArgs) -> anyhow::Result<ExitCode> {
    let request = ScalingRequest {
        config: args.config,
        out: args.out,
        quick: args.quick,
        threads: args.threads,
        suite: args.suite,
        models: args.models,
    };
    let outcome = scaling::run(&request, &MultiProgress::new())?;
    println!(
        "{} fractions in {:.1} s",
        outcome.fractions.len(),
        outcome.wall_time_s
    );
    println!("report:  {}", outcome.report.display());
    println!("results: {}", outcome.csv.display());
    println!("figure:  {}", outcome.figure.display());
    Ok(ExitCode::SUCCESS)
}
