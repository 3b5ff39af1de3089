//! `human2nav baseline ...`: training of the learned baselines. SARL is trained in the
//! circle-crossing environment of its own crate (`human2nav-sarl`): imitation on ORCA
//! demonstrations, then TD learning; checkpoints every `run.checkpoint_every` episodes,
//! `--resume` continues exactly; the trained network is evaluated on held-out seeds and
//! exported with its model card and training curve. `eval-sarl` runs a trained model in that
//! environment with the robot, the crowd size and the crowd's reaction changed one at a time,
//! to see which departure from its training regime costs it how much.

use anyhow::Context;
use clap::{Args, Subcommand};
use human2nav_core::lock::DirLock;
use human2nav_flow::planner::load_profile;
use human2nav_sarl::SarlModel;
use human2nav_sarl::action::ActionSpace;
use human2nav_sarl::env::EnvConfig;
use human2nav_sarl::eval::{Policy, SeedStream, evaluate};
use human2nav_sarl::train::{IlConfig, Observer, TrainConfig, Trainer};
use indicatif::{ProgressBar, ProgressStyle};
use std::path::{Path, PathBuf};
use std::process::ExitCode;

/// Subcommands of `human2nav baseline`.
#[derive(Debug, Subcommand)]
pub enum BaselineCommand {
    /// Train SARL (imitation on ORCA demonstrations, then TD learning) and export
    /// `models/sarl` (weights, model card, training curve).
    TrainSarl(TrainSarlArgs),
    /// Evaluate a trained SARL model in circle crossing, in its training regime and with the
    /// benchmark robots' radius and speed, more humans, or humans that see the robot: which
    /// departure from the regime it was trained in costs it how much.
    EvalSarl(EvalSarlArgs),
}

/// Arguments of `human2nav baseline eval-sarl`.
#[derive(Debug, Args)]
pub struct EvalSarlArgs {
    /// The model folder (`model.toml` + `model.safetensors`).
    #[arg(long, default_value = "models/sarl")]
    model: PathBuf,
    /// Robot profiles whose footprint radius and `v_max` replace the trained robot's radius
    /// and preferred speed (as the benchmark passes them to SARL); the trained robot is always
    /// evaluated too.
    #[arg(long = "robot")]
    robots: Vec<PathBuf>,
    /// Numbers of humans (comma-separated; default: the trained number).
    #[arg(long, value_delimiter = ',')]
    humans: Vec<usize>,
    /// Also run each setting with humans whose ORCA sees the robot (trained: it does not).
    #[arg(long)]
    visible: bool,
    /// Episodes per setting, from the held-out test stream of the training seed (the card's
    /// evaluation uses the first 500).
    #[arg(long, default_value_t = 500)]
    episodes: usize,
    /// Also write the table to this Markdown file.
    #[arg(long)]
    out: Option<PathBuf>,
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
        BaselineCommand::EvalSarl(args) => eval_sarl(args),
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

/// One row of `eval-sarl`: whose radius and speed the robot has, and the whole environment.
struct Setting {
    robot: String,
    env: EnvConfig,
}

fn eval_sarl(args: EvalSarlArgs) -> anyhow::Result<ExitCode> {
    let root = workspace_root();
    let dir = resolve(&root, &args.model);
    let model = SarlModel::load_dir(&dir)
        .with_context(|| format!("loading the SARL model {}", dir.display()))?;
    if args.episodes == 0 {
        anyhow::bail!("--episodes must be at least 1");
    }
    let trained = model.card.env.clone();
    let mut robots = vec![(
        "trained".to_string(),
        trained.robot_radius,
        trained.robot_v_pref,
    )];
    for path in &args.robots {
        let profile = load_profile(&resolve(&root, path))?;
        robots.push((
            profile.name.clone(),
            profile.footprint_radius,
            profile.limits.v_max,
        ));
    }
    let humans = if args.humans.is_empty() {
        vec![trained.human_num]
    } else {
        args.humans.clone()
    };
    let visibility: &[bool] = if args.visible {
        &[trained.robot_visible, !trained.robot_visible]
    } else {
        &[trained.robot_visible]
    };
    let mut settings = Vec::new();
    for (name, radius, v_pref) in &robots {
        for &n in &humans {
            for &visible in visibility {
                let env = EnvConfig {
                    robot_radius: *radius,
                    robot_v_pref: *v_pref,
                    human_num: n,
                    robot_visible: visible,
                    ..trained.clone()
                };
                env.validate().with_context(|| {
                    format!("the circle-crossing setting for {name} with {n} humans")
                })?;
                settings.push(Setting {
                    robot: name.clone(),
                    env,
                });
            }
        }
    }

    // One libtorch thread, as in training and in the benchmark's planner.
    human2nav_flow::tch::set_num_threads(1);
    let seed = model.card.training.seed;
    let la = &model.card.lookahead;
    let orca = Policy::Orca {
        safety_space: IlConfig::default().safety_space,
    };
    let n = args.episodes;
    let bar = ProgressBar::new((2 * n * settings.len()) as u64).with_style(
        ProgressStyle::with_template(
            "{prefix:>10} [{bar:32}] {pos}/{len} {elapsed_precise} ETA {eta_precise}  {msg}",
        )
        .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    bar.set_prefix("episodes");
    let mut table = String::from(
        "| robot | radius (m) | v_pref (m/s) | humans | humans see the robot | SARL success | collision | timeout | ORCA success |\n\
         |---|---|---|---|---|---|---|---|---|\n",
    );
    for (k, st) in settings.iter().enumerate() {
        let env = &st.env;
        let actions =
            ActionSpace::holonomic(env.robot_v_pref, la.speed_samples, la.rotation_samples);
        let sarl = Policy::Sarl {
            net: &model.net,
            actions: &actions,
            lookahead: model.lookahead(),
            epsilon: 0.0,
        };
        bar.set_message(format!(
            "{}, {} humans{}",
            st.robot,
            env.human_num,
            if env.robot_visible { ", visible" } else { "" }
        ));
        let base = (2 * n * k) as u64;
        let s = evaluate(env, &sarl, seed, SeedStream::Test, n, &mut |i| {
            bar.set_position(base + i as u64)
        })?;
        let o = evaluate(env, &orca, seed, SeedStream::Test, n, &mut |i| {
            bar.set_position(base + (n + i) as u64)
        })?;
        let pct = |x: f64| format!("{:.1} %", 100.0 * x);
        table.push_str(&format!(
            "| {} | {:.2} | {:.2} | {} | {} | {} | {} | {} | {} |\n",
            st.robot,
            env.robot_radius,
            env.robot_v_pref,
            env.human_num,
            if env.robot_visible { "yes" } else { "no" },
            pct(s.success_rate),
            pct(s.collision_rate),
            pct(s.timeout_rate),
            pct(o.success_rate),
        ));
    }
    bar.finish_and_clear();
    println!(
        "SARL ({}) in circle crossing, {n} held-out episodes per row (test stream of seed {seed}); ORCA: the imitation demonstrator on the same episodes\n",
        dir.display()
    );
    print!("{table}");
    if let Some(out) = &args.out {
        let path = resolve(&root, out);
        if let Some(parent) = path.parent() {
            std::fs::create_dir_all(parent)
                .with_context(|| format!("creating {}", parent.display()))?;
        }
        std::fs::write(&path, &table).with_context(|| format!("writing {}", path.display()))?;
        println!("\ntable: {}", path.display());
    }
    Ok(ExitCode::SUCCESS)
}
