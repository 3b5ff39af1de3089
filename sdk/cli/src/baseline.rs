//! `human2nav baseline ...`: training of the learned baselines. SARL is trained in the
//! circle-crossing environment of its own crate (`human2nav-sarl`): imitation on ORCA
//! demonstrations, then TD learning; checkpoints every `run.checkpoint_every` episodes,
//! `--resume` continues exactly; the trained network is evaluated on held-out seeds and
//! exported with its model card and training curve.

use anyhow::Context;
use clap::{Args, Subcommand};
use human2nav_core::lock::DirLock;
use human2nav_sarl::train::{Observer, TrainConfig, Trainer};
use indicatif::{ProgressBar, ProgressStyle};
use std::path::{Path, PathBuf};
use std::process::ExitCode;

/// Subcommands of `human2nav baseline`.
#[derive(Debug, Subcommand)]
pub enum BaselineCommand {
    /// Train SARL (imitation on ORCA demonstrations, then TD learning) and export
    /// `models/sarl` (weights, model card, training curve).
    TrainSarl(TrainSarlArgs),
}

/// Arguments of `human2nav baseline train-sarl`.
#[derive(Debug, Args)]
pub struct TrainSarlArgs {
    /// Training configuration (TOML), e.g. sdk/configs/sarl.toml.
    #[arg(long)]
    config: PathBuf,
    /// Run directory for checkpoints (overrides `run.out_dir`).
    #[arg(long)]
    out: Option<PathBuf>,
    /// Where to export the model (overrides `run.model_dir`).
    #[arg(long)]
    model_dir: Option<PathBuf>,
    /// Continue from the checkpoint in the run directory (else start afresh).
    #[arg(long)]
    resume: bool,
}

/// Runs `human2nav baseline ...`.
pub fn run(cmd: BaselineCommand) -> anyhow::Result<ExitCode> {
    match cmd {
        BaselineCommand::TrainSarl(args) => train_sarl(args),
    }
}

/// The workspace root above the current directory (else the current directory).
fn workspace_root() -> PathBuf {
    let cwd = std::env::current_dir().unwrap_or_else(|_| PathBuf::from("."));
    human2nav_data::paths::find_workspace_root(&cwd).unwrap_or(cwd)
}

fn resolve(root: &Path, p: &Path) -> PathBuf {
    if p.is_absolute() {
        p.to_path_buf()
    } else {
        root.join(p)
    }
}

/// Progress bars for the trainer's stages.
struct Bars {
    bar: Option<ProgressBar>,
}

impl Observer for Bars {
    fn stage(&mut self, name: &str, total: u64, done: u64) {
        if let Some(b) = self.bar.take() {
            b.finish();
        }
        let bar = ProgressBar::new(total).with_style(
            ProgressStyle::with_template(
                "{prefix:>20} [{bar:32}] {pos}/{len} {elapsed_precise} ETA {eta_precise}  {msg}",
            )
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
        );
        bar.set_prefix(name.to_string());
        bar.set_position(done);
        self.bar = Some(bar);
    }

    fn tick(&mut self, done: u64, message: &str) {
        if let Some(b) = &self.bar {
            b.set_position(done);
            b.set_message(message.to_string());
        }
    }

    fn note(&mut self, line: &str) {
        match &self.bar {
            Some(b) if !b.is_hidden() => b.println(line),
            _ => eprintln!("{line}"),
        }
    }
}

fn train_sarl(args: TrainSarlArgs) -> anyhow::Result<ExitCode> {
    let cfg = TrainConfig::load(&args.config)?;
    let root = workspace_root();
    let out_dir = resolve(&root, args.out.as_deref().unwrap_or(&cfg.run.out_dir));
    let model_dir = resolve(
        &root,
        args.model_dir.as_deref().unwrap_or(&cfg.run.model_dir),
    );
    let _lock = DirLock::acquire(&out_dir, "human2nav baseline train-sarl")
        .with_context(|| format!("locking the run directory {}", out_dir.display()))?;
    let mut trainer = if args.resume {
        match Trainer::resume(cfg.clone(), out_dir.clone())? {
            Some(t) => {
                let p = t.progress();
                eprintln!(
                    "resuming {}: demonstrations {}, {} imitation epochs, {} TD episodes done",
                    out_dir.display(),
                    if p.demos_done { "done" } else { "pending" },
                    p.il_epochs_done,
                    p.rl_episodes_done
                );
                t
            }
            None => {
                eprintln!("no checkpoint in {}: starting afresh", out_dir.display());
                Trainer::new(cfg.clone(), out_dir.clone())?
            }
        }
    } else {
        Trainer::new(cfg.clone(), out_dir.clone())?
    };
    eprintln!(
        "SARL: {} demonstrations × {} imitation epochs, {} TD episodes ({} batches each), {} libtorch thread(s); checkpoints in {}",
        cfg.il.episodes,
        cfg.il.epochs,
        cfg.rl.episodes,
        cfg.rl.batches_per_episode,
        cfg.threads,
        out_dir.display()
    );
    let mut bars = Bars { bar: None };
    trainer.run(&mut bars)?;
    if let Some(b) = bars.bar.take() {
        b.finish();
    }
    let n = cfg.run.test_episodes as u64;
    bars.stage("held-out evaluation", 3 * n, 0);
    let card = {
        let bar = bars.bar.clone();
        let mut offset = |policy: &str, i: usize| {
            let k = match policy {
                "sarl" => 0,
                "straight" => 1,
                _ => 2,
            };
            if let Some(b) = &bar {
                b.set_position(k * n + i as u64);
                b.set_message(policy.to_string());
            }
        };
        trainer
            .export(&model_dir, &mut offset)
            .with_context(|| format!("exporting the model to {}", model_dir.display()))?
    };
    if let Some(b) = bars.bar.take() {
        b.finish();
    }
    let e = &card.evaluation;
    println!(
        "held-out circle crossing ({} episodes): SARL success {:.3}, collision {:.3}, timeout {:.3}, mean time {:.2} s; straight success {:.3}; ORCA success {:.3}",
        e.episodes,
        e.success_rate,
        e.collision_rate,
        e.timeout_rate,
        e.mean_success_time,
        e.straight_success_rate,
        e.orca_success_rate
    );
    println!(
        "wrote {} (wall time {:.0} s)",
        model_dir.display(),
        card.training.wall_seconds
    );
    Ok(ExitCode::SUCCESS)
}
