//! `human2nav train --config <toml>`: train the conditional flow-matching model on the tuple
//! cache, checkpoint and resume, export the EMA weights with a model card and a loss curve,
//! evaluate on the held-out test scenes, and measure latencies; `--bench-steps N` times
//! training steps on the cache instead and writes nothing.
//!
//! The training itself lives in [`human2nav_experiments::train`]; this is its command line.

use anyhow::Context;
use clap::Args;
use human2nav_core::lock::DirLock;
use human2nav_experiments::train::{
    TrainConfig, bench_train_steps, device_of, open_cache, run_evaluation, train,
};
use human2nav_flow::CfmModel;
use human2nav_flow::model::CARD_FILE;
use human2nav_flow::tch;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

/// Arguments of `human2nav train`.
#[derive(Debug, Args)]
pub struct TrainArgs {
    /// Training configuration (TOML), e.g. sdk/configs/train.toml.
    #[arg(long)]
    config: PathBuf,
    /// Start from scratch even if a checkpoint exists in the run directory.
    #[arg(long)]
    fresh: bool,
    /// Skip training: evaluate the exported model in `run.model_dir` on the test split.
    #[arg(long)]
    eval_only: bool,
    /// Measure forward and forward+VJP latency of the exported model (batch 1 and 16) and
    /// record them in its card; with --eval-only, nothing else runs.
    #[arg(long)]
    bench: bool,
    /// Override `run.threads`.
    #[arg(long)]
    threads: Option<usize>,
    /// Override `train.steps`.
    #[arg(long)]
    steps: Option<u64>,
    /// Throughput only: time this many training steps (after 5 untimed warm-up steps) of a
    /// fresh run on the tuple cache at `train.batch_size`, batch building included, and print
    /// milliseconds per step (median and mean, and per phase). Writes nothing: no checkpoint,
    /// model or card (compare with sdk/flow/reference/torch_train_step.py --bench).
    #[arg(long, value_name = "N", conflicts_with_all = ["fresh", "eval_only", "bench"])]
    bench_steps: Option<usize>,
}

/// Untimed steps before `--bench-steps` starts timing.
const BENCH_WARMUP_STEPS: usize = 5;

/// `--bench-steps`: times training steps and prints milliseconds per step.
fn bench_steps(
    cfg: &TrainConfig,
    cache: &human2nav_data::TupleCache,
    device: tch::Device,
    steps: usize,
) -> anyhow::Result<ExitCode> {
    anyhow::ensure!(steps > 0, "--bench-steps must be positive");
    let b = bench_train_steps(cfg, cache, device, steps, BENCH_WARMUP_STEPS)?;
    let stat = |v: &[f64]| {
        let median = human2nav_sim::stats::median(v).unwrap_or(f64::NAN);
        (median, v.iter().sum::<f64>() / v.len() as f64)
    };
    let (median, mean) = stat(&b.step_ms);
    println!(
        "train step: batch {}, {} torch threads, {steps} steps after {BENCH_WARMUP_STEPS} warm-up: \
         median {median:.2} ms, mean {mean:.2} ms per step ({:.0} samples/s at the median)",
        cfg.train.batch_size,
        cfg.run.threads,
        cfg.train.batch_size as f64 * 1e3 / median
    );
    for (name, v) in [
        ("batch building", &b.batch_ms),
        ("forward + loss", &b.forward_ms),
        ("backward", &b.backward_ms),
        ("clip + AdamW + EMA", &b.update_ms),
    ] {
        let (median, mean) = stat(v);
        println!("  {name:<20} median {median:7.2} ms  mean {mean:7.2} ms");
    }
    Ok(ExitCode::SUCCESS)
}

/// The workspace root: the nearest ancestor of the current directory whose Cargo.toml has a
/// `[workspace]` table (else the current directory).
fn workspace_root() -> PathBuf {
    let cwd = std::env::current_dir().unwrap_or_else(|_| PathBuf::from("."));
    for dir in cwd.ancestors() {
        let manifest = dir.join("Cargo.toml");
        if std::fs::read_to_string(&manifest).is_ok_and(|t| t.contains("[workspace]")) {
            return dir.to_path_buf();
        }
    }
    cwd
}

fn resolve(root: &Path, p: &Path) -> PathBuf {
    if p.is_absolute() {
        p.to_path_buf()
    } else {
        root.join(p)
    }
}

/// Runs `human2nav train`.
pub fn run(args: TrainArgs) -> anyhow::Result<ExitCode> {
    let mut cfg = TrainConfig::load(&args.config)?;
    if let Some(t) = args.threads {
        cfg.run.threads = t;
    }
    if let Some(s) = args.steps {
        cfg.train.steps = s;
    }
    cfg.validate()
        .with_context(|| format!("in {}", args.config.display()))?;

    let root = workspace_root();
    let out_dir = resolve(
        &root,
        cfg.run
            .out_dir
            .as_deref()
            .unwrap_or(&PathBuf::from("out/train").join(&cfg.run.name)),
    );
    let model_dir = resolve(
        &root,
        cfg.run
            .model_dir
            .as_deref()
            .unwrap_or(&PathBuf::from("models").join(&cfg.run.name)),
    );
    let cache_dir = resolve(&root, &cfg.data.cache);

    tch::set_num_threads(cfg.run.threads as i32);
    let device = device_of(&cfg.run.device)?;
    eprintln!("device {device:?}, {} torch threads", cfg.run.threads);

    let cache = open_cache(&cache_dir, &cfg, &args.config)?;
    if let Some(steps) = args.bench_steps {
        return bench_steps(&cfg, &cache, device, steps);
    }

    if !args.eval_only {
        let _lock = DirLock::acquire(&out_dir, "human2nav train")
            .with_context(|| format!("locking the run directory {}", out_dir.display()))?;
        train(&cfg, &cache, &out_dir, &model_dir, device, args.fresh)?;
    }
    let mut model = CfmModel::load(&model_dir, device)
        .with_context(|| format!("loading the exported model from {}", model_dir.display()))?;
    if !(args.eval_only && args.bench) {
        let info = run_evaluation(&cfg, &cache, &model, &root)?;
        model.card_mut().evaluation = Some(info);
    }
    if args.bench {
        let perf = human2nav_flow::perf::measure_latency(&model, cfg.run.threads)?;
        eprintln!(
            "latency ({} threads): velocity b1 {:.3} ms, b16 {:.3} ms; velocity+VJP b1 {:.3} ms, b16 {:.3} ms; \
             condition encoding {:.3} ms",
            perf.threads,
            perf.forward_b1_ms,
            perf.forward_b16_ms,
            perf.vjp_b1_ms,
            perf.vjp_b16_ms,
            perf.encode_condition_ms
        );
        model.card_mut().performance = Some(perf);
    }
    model.card().save(&model_dir.join(CARD_FILE))?;
    eprintln!(
        "model card written to {}",
        model_dir.join(CARD_FILE).display()
    );
    Ok(ExitCode::SUCCESS)
}
