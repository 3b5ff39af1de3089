//! `human2nav plan`: one Human2Nav planning step on an episode, drawn like the paper's Fig. 4;
//! with `--bench`, the latency of a planning call; with `--eval`, guided vs unguided plans on
//! many held-out windows per robot.
//!
//! A *window* is one planning step set up from one episode by
//! `human2nav_sim::plan_figure::observation_at`: the robot at the episode's start pose (facing
//! the goal), moving at `--speed`, the replayed crowd at `--time`.

use anyhow::{Context, bail};
use clap::Args;
use human2nav_core::ablation::Arm;
use human2nav_core::{Observation, Planner, Stages};
use human2nav_data::ScenarioClass;
use human2nav_data::paths::find_workspace_root;
use human2nav_flow::planner::{
    Backend, BevOrigin, PlannerConfig, PredictionModel, RobotPlanner, load_model,
};
use human2nav_sim::episode::{Episode, ScenarioTitle};
use human2nav_sim::plan_figure::{
    PlanFigure, StepOptions, draw_plan_figure, load_episodes, observation_at, select_episode,
};
use indicatif::{ProgressBar, ProgressStyle};
use std::path::{Path, PathBuf};
use std::process::ExitCode;

mod batch;
mod bench;
mod eval;

use bench::bench;
use eval::{eval, human_windows};

/// Arguments of `human2nav plan`.
#[derive(Debug, Args)]
pub struct PlanArgs {
    /// Robot profile(s) (`robot.toml`). Planning and `--bench` use the first; `--eval` runs
    /// every one.
    #[arg(long, required = true)]
    pub robot: Vec<PathBuf>,
    /// Episode file: a suite from `human2nav data episodes` or one episode (JSON). Without it,
    /// synthetic episodes (one per scenario class, `--synthetic-seed`) are used.
    #[arg(long)]
    pub episode: Option<PathBuf>,
    /// Index of the episode in the file.
    #[arg(long, default_value_t = 0)]
    pub index: usize,
    /// Identifier of the episode in the file (overrides `--index`).
    #[arg(long)]
    pub id: Option<String>,
    /// Episode time of the crowd (s).
    #[arg(long, default_value_t = 0.0)]
    pub time: f64,
    /// The robot's forward speed at the planning instant (m/s; an episode starts at rest).
    #[arg(long, default_value_t = 0.0)]
    pub speed: f64,
    /// Planner configuration [default: sdk/configs/planner.toml under the workspace root,
    /// built-in defaults when absent].
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Model folder (overrides the configuration's `model`).
    #[arg(long)]
    pub model: Option<PathBuf>,
    /// Run Algorithm 1 (feasibility guidance through the network) on the shortlisted samples;
    /// the shipped planner does not.
    #[arg(long, conflicts_with = "arm")]
    pub guidance: bool,
    /// Plan as one arm of the guidance ablation instead of the configured planner: `raw` (the
    /// model's samples as they come), `alg1` (Algorithm 1, no correction), `qp` (the
    /// correction: the shipped planner without its own motions) or `alg1+qp`.
    #[arg(long)]
    pub arm: Option<Arm>,
    /// Seed of the planner's source noise (overrides the configuration).
    #[arg(long)]
    pub seed: Option<u64>,
    /// Number of sampled candidates `K` (overrides the configuration).
    #[arg(long)]
    pub samples: Option<usize>,
    /// libtorch threads (overrides the configuration).
    #[arg(long)]
    pub threads: Option<usize>,
    /// What runs the network: native, torch (libtorch on the CPU) or cuda (libtorch on a GPU)
    /// (overrides the configuration; `--bench` measures native and torch when this is not
    /// given).
    #[arg(long)]
    pub backend: Option<Backend>,
    /// Output PNG [default: out/plan/<robot>-<episode index>.png under the workspace root].
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Also write the planning call as an MCAP file that Foxglove opens: the robot and its
    /// footprint, the people with their recent positions, obstacles, goal, the plan and the
    /// candidates (`human2nav_sim::record`).
    #[arg(long, value_name = "MCAP", conflicts_with_all = ["bench", "eval"])]
    pub record: Option<PathBuf>,
    /// Measure planning latency: this many timed calls of the configured planner and of the
    /// guidance-ablation arms raw, qp and alg1+qp, over the first windows of the episode file
    /// (p50/p95 and where the time goes).
    #[arg(long, value_name = "CALLS")]
    pub bench: Option<usize>,
    /// With `--bench`: also measure the throughput of this many planners planned at once
    /// (`Human2Nav::plan_batch`, the network batched across them) against the same planners
    /// one by one, on one and on two threads (native backend; about CALLS plans per row).
    #[arg(long, value_name = "PLANNERS", requires = "bench")]
    pub batch: Option<usize>,
    /// Planning budget of a call in milliseconds (overrides the configuration's `budget_ms`):
    /// the call returns the best plan found by then. With `--bench`, also reports how late the
    /// calls return and how far each stage got.
    #[arg(long, value_name = "MS")]
    pub budget_ms: Option<f64>,
    /// Compare guided and unguided plans on `--windows` windows per robot and print a table.
    #[arg(long)]
    pub eval: bool,
    /// Windows per robot for `--eval`, spread evenly over the episode file.
    #[arg(long, default_value_t = 50)]
    pub windows: usize,
    /// With `--eval`: also run Algorithm 1 (every sample guided, no correction) on this many
    /// recorded human windows of the validation split of the tuple cache, and report TFS and
    /// the ADE to the recorded future before and after guidance.
    #[arg(long, value_name = "WINDOWS")]
    pub human: Option<usize>,
    /// Tuple cache for `--human` [default: out/data/cache under the workspace root].
    #[arg(long)]
    pub cache: Option<PathBuf>,
    /// Seed of the synthetic episodes used without `--episode`.
    #[arg(long, default_value_t = 1)]
    pub synthetic_seed: u64,
}

/// Runs `human2nav plan`.
pub fn run(args: PlanArgs) -> anyhow::Result<ExitCode> {
    // A summary over nothing is a table of NaN, not a result.
    if args.eval && args.windows == 0 {
        bail!("--windows 0: `plan --eval` needs at least one window per robot");
    }
    if args.bench == Some(0) {
        bail!("--bench 0: `plan --bench` needs at least one timed call");
    }
    if args.batch == Some(0) {
        bail!("--batch 0: a batch needs at least one planner");
    }
    if args.human == Some(0) {
        bail!("--human 0: give at least one recorded window, or leave --human out");
    }
    let cwd = std::env::current_dir().context("reading the current directory")?;
    let workspace = find_workspace_root(&cwd).unwrap_or(cwd);
    let mut cfg = match &args.config {
        Some(p) => PlannerConfig::load(p)?,
        None => {
            let p = workspace.join("sdk/configs/planner.toml");
            if p.is_file() {
                PlannerConfig::load(&p)?
            } else {
                PlannerConfig::default()
            }
        }
    };
    if let Some(s) = args.seed {
        cfg.human2nav.seed = s;
    }
    if let Some(k) = args.samples {
        cfg.human2nav.samples = k;
    }
    if let Some(t) = args.threads {
        cfg.threads = t;
    }
    if let Some(b) = args.backend {
        cfg.backend = b;
    }
    if args.guidance {
        cfg.human2nav.guidance.enabled = true;
    }
    if let Some(arm) = args.arm {
        cfg.human2nav = arm.settings(&cfg.human2nav);
    }
    if let Some(b) = args.budget_ms {
        cfg.human2nav.budget_ms = b;
    }
    cfg.validate()?;
    let model_dir = args
        .model
        .clone()
        .unwrap_or_else(|| cfg.model_dir(&workspace));
    if !model_dir.exists() {
        bail!(
            "no model at {} (train one with `human2nav train`, or pass --model <folder>)",
            model_dir.display()
        );
    }
    human2nav_flow::tch::set_num_threads(i32::try_from(cfg.threads).unwrap_or(1));

    let episodes = match &args.episode {
        Some(p) => load_episodes(p)?,
        None => ScenarioClass::ALL
            .iter()
            .flat_map(|c| human2nav_data::synthetic::episodes(*c, 1, args.synthetic_seed))
            .collect(),
    };
    if episodes.is_empty() {
        bail!("no episodes to plan on");
    }
    let step = StepOptions {
        time: args.time,
        ego_speed: args.speed,
        ..StepOptions::default()
    };

    if args.eval {
        let model = load_model(&model_dir, cfg.backend)?;
        if let Some(n) = args.human {
            let cache = args
                .cache
                .clone()
                .unwrap_or_else(|| workspace.join("out/data/cache"));
            human_windows(&args, &cfg, &model, &cache, n)?;
        }
        return eval(&args, &cfg, &model, &model_dir, &episodes, &step);
    }
    let prediction = PredictionModel::load(&cfg, &workspace)?;
    if let Some(calls) = args.bench {
        return bench(
            &args,
            &cfg,
            &model_dir,
            prediction.as_ref(),
            &episodes,
            &step,
            calls,
        );
    }
    plan_one(
        &args,
        &cfg,
        &model_dir,
        prediction.as_ref(),
        &workspace,
        &episodes,
        &step,
    )
}

fn plan_one(
    args: &PlanArgs,
    cfg: &PlannerConfig,
    model_dir: &Path,
    prediction: Option<&PredictionModel>,
    workspace: &Path,
    episodes: &[Episode],
    step: &StepOptions,
) -> anyhow::Result<ExitCode> {
    let robot_path = &args.robot[0];
    let mut rp = RobotPlanner::load_with(robot_path, model_dir, cfg.backend, cfg.human2nav)?;
    if let Some(p) = prediction {
        rp = rp.with_predictor(p.predictor()?);
    }
    let ep = select_episode(episodes, args.index, args.id.as_deref())?;
    let obs = observation_at(ep, step).with_context(|| format!("--time {}", step.time))?;
    let plan = rp.planner.plan(&obs)?;
    // The predictor's forecast for the figure: the same observation, so the same scenes the
    // selection scored against (a forecast depends on its observation only).
    let forecast = match prediction {
        Some(p) => Some(
            p.predictor()?
                .forecast(&obs, plan.poses.len().saturating_sub(1), plan.dt)
                .map_err(|e| anyhow::anyhow!("predicting the pedestrians: {e}"))?,
        ),
        None => None,
    };
    let guidance = cfg.human2nav.guidance.enabled;

    println!(
        "robot {} ({}), footprint {:.2} m; model {}",
        rp.profile.name,
        rp.profile.embodiment.kind_name(),
        rp.profile.footprint_radius,
        model_dir.display()
    );
    println!("BEV {}", describe_bev(&rp));
    println!(
        "episode {} ({}, {} data), t = {:.1} s, {} pedestrians observed, goal {:.1} m away",
        ep.id,
        ep.scenario.title(),
        ep.source,
        obs.time,
        obs.agents.len(),
        (ep.goal[0] - obs.ego.x).hypot(ep.goal[1] - obs.ego.y)
    );
    let fig = PlanFigure {
        robot: &rp.profile.name,
        label: &ep.id,
        guidance,
        observation: &obs,
        start: Some(ep.start),
        plan: &plan,
        limits: rp.limits(),
        footprint_radius: rp.profile.footprint_radius,
        bev: rp.bev,
        forecast: forecast.as_ref(),
    };
    let out = args.out.clone().unwrap_or_else(|| {
        workspace.join(format!(
            "out/plan/{}-{}{}.png",
            rp.profile.name,
            args.id.as_deref().map_or(args.index.to_string(), sanitize),
            args.arm
                .map_or(String::new(), |a| format!("-{}", a.key().replace('+', "")))
        ))
    });
    let numbers = draw_plan_figure(&out, &fig)?;
    println!(
        "plan: {} poses at {} s, guidance {}, {}",
        plan.poses.len(),
        plan.dt,
        if guidance { "on" } else { "off" },
        match plan.info.selected {
            Some(i) if i < plan.info.candidates.len() =>
                format!("sample {} of {}", i, plan.info.candidates.len()),
            Some(_) => "kept the previous plan".into(),
            None => "no selection".into(),
        }
    );
    if plan.info.fallback {
        println!("FALLBACK (stop in place): {}", plan.info.notes.join("; "));
    }
    for w in &plan.info.warnings {
        eprintln!("warning: {w}");
    }
    if let Some(stages) = &plan.info.stages {
        println!("stages: {}", describe_stages(stages));
    }
    println!(
        "TFS {:.3} ({} of {} waypoints feasible){}; Φ {} → {}",
        numbers.tfs,
        numbers.feasible,
        numbers.waypoints,
        numbers
            .tfs_before
            .map_or(String::new(), |t| format!(", before guidance {t:.3}")),
        fmt_opt(plan.info.phi_before),
        fmt_opt(plan.info.phi_after)
    );
    let mask = human2nav_core::feasibility::feasibility_mask(
        &plan.poses,
        plan.dt,
        rp.limits(),
        obs.ego_velocity,
    );
    println!("   t [s]    x [m]    y [m]  θ [rad]  v [m/s]  feasible");
    for (k, p) in plan.poses.iter().enumerate() {
        if k % 4 != 0 && k + 1 != plan.poses.len() {
            continue;
        }
        let v = if k == 0 {
            obs.ego_velocity.vx
        } else {
            let q = plan.poses[k - 1];
            (p.x - q.x).hypot(p.y - q.y) / plan.dt
        };
        println!(
            "{:8.1} {:8.3} {:8.3} {:8.3} {:8.3}  {}",
            plan.t0 + k as f64 * plan.dt,
            p.x,
            p.y,
            p.theta,
            v,
            if k == 0 {
                "(now)"
            } else if mask.get(k).copied().unwrap_or(false) {
                "yes"
            } else {
                "NO"
            }
        );
    }
    println!("figure: {}", out.display());
    if let Some(path) = &args.record {
        human2nav_sim::record::record_plan(
            path,
            &obs,
            &plan,
            &rp.profile.footprint_shapes,
            &rp.profile.name,
        )?;
        println!("recording: {}", path.display());
    }
    Ok(ExitCode::SUCCESS)
}

fn describe_bev(rp: &RobotPlanner) -> String {
    format!(
        "{}×{} cells of {} m ({})",
        rp.bev.cells,
        rp.bev.cells,
        rp.bev.resolution,
        match rp.bev_origin {
            BevOrigin::Card => "from the model card",
            BevOrigin::Record => "from the model card's training record",
            BevOrigin::Default =>
                "cell size not recorded in the model card: the data pipeline's default",
        }
    )
}

fn sanitize(s: &str) -> String {
    s.chars()
        .map(|c| if c.is_ascii_alphanumeric() { c } else { '_' })
        .collect()
}

fn fmt_opt(v: Option<f64>) -> String {
    v.map_or_else(|| "–".into(), |x| format!("{x:.4}"))
}

/// `n` indices spread evenly over `0..len` (all of them when `n ≥ len`).
fn spread(len: usize, n: usize) -> Vec<usize> {
    if n >= len {
        return (0..len).collect();
    }
    (0..n).map(|i| i * len / n).collect()
}

fn windows(
    episodes: &[Episode],
    n: usize,
    step: &StepOptions,
) -> anyhow::Result<Vec<(String, Observation)>> {
    spread(episodes.len(), n)
        .into_iter()
        .map(|i| {
            let ep = &episodes[i];
            let obs = observation_at(ep, step).with_context(|| format!("--time {}", step.time))?;
            Ok((ep.id.clone(), obs))
        })
        .collect()
}

fn bar(len: usize, what: &str) -> ProgressBar {
    ProgressBar::new(len as u64).with_style(
        ProgressStyle::with_template(&format!(
            "{{elapsed_precise}} [{{bar:40}}] {{pos}}/{{len}} {what}, ETA {{eta}}"
        ))
        .unwrap_or_else(|_| ProgressStyle::default_bar())
        .progress_chars("=> "),
    )
}

/// One line on how far each stage of a planning call got.
fn describe_stages(s: &Stages) -> String {
    format!(
        "sampling {}/{} steps, guidance {}/{} iterations, correction {}/{} candidates; {}",
        s.sampling.done,
        s.sampling.planned,
        s.guidance.done,
        s.guidance.planned,
        s.correction.done,
        s.correction.planned,
        s.cut_short
            .map_or("no stage cut short".into(), |st| format!(
                "the deadline cut {st} short"
            ))
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spread_covers_the_list_evenly() {
        assert_eq!(spread(10, 3), vec![0, 3, 6]);
        assert_eq!(spread(4, 10), vec![0, 1, 2, 3]);
        assert_eq!(spread(200, 4), vec![0, 50, 100, 150]);
        assert!(spread(0, 5).is_empty());
    }

    #[test]
    fn file_names_are_sanitized() {
        assert_eq!(sanitize("eth/eth#12"), "eth_eth_12");
    }
}
