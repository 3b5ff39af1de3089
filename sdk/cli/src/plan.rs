//! `human2nav plan`: one Human2Nav planning step on an episode, drawn like the paper's Fig. 4;
//! with `--bench`, the latency of a planning call; with `--eval`, guided vs unguided plans on
//! many held-out windows per robot.
//!
//! A *window* is one planning step set up from one episode by
//! `human2nav_sim::plan_figure::observation_at`: the robot at the episode's start pose (facing
//! the goal), moving at `--speed`, the replayed crowd at `--time`.

use anyhow::{Context, bail};
use clap::Args;
use human2nav_core::ablation::{Arm, ArmSummary, ablation_step};
use human2nav_core::human2nav::{Human2Nav, Human2NavSettings};
use human2nav_core::tfs::{self, Violations};
use human2nav_core::{Observation, Planner, Stage, Stages};
use human2nav_data::ScenarioClass;
use human2nav_data::cache::TupleCache;
use human2nav_data::paths::find_workspace_root;
use human2nav_data::tuples::Split;
use human2nav_experiments::train::cache_windows;
use human2nav_flow::eval::{EvalOptions, guided_windows};
use human2nav_flow::net::Complexity;
use human2nav_flow::planner::{
    Backend, BevOrigin, FlowCallStats, LatencyStats, PlannerConfig, PlannerModel, PredictionModel,
    RobotPlanner, TimedModel, bev_spec, load_model, load_profile, measure_latency, robot_model,
    robot_phi,
};
use human2nav_sim::episode::{Episode, ScenarioTitle};
use human2nav_sim::plan_figure::{
    PlanFigure, StepOptions, draw_plan_figure, load_episodes, observation_at, select_episode,
};
use indicatif::{ProgressBar, ProgressStyle};
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::{Arc, Mutex};

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
    /// What runs the network: native or torch (overrides the configuration; `--bench` measures
    /// both when this is not given).
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
    let mask =
        human2nav_core::tfs::feasibility_mask(&plan.poses, plan.dt, rp.limits(), obs.ego_velocity);
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

fn eval(
    args: &PlanArgs,
    cfg: &PlannerConfig,
    model: &PlannerModel,
    model_dir: &Path,
    episodes: &[Episode],
    step: &StepOptions,
) -> anyhow::Result<ExitCode> {
    let wins = windows(episodes, args.windows, step)?;
    println!(
        "held-out windows: {} of {} episodes ({}), t = {:.1} s, robot speed {:.2} m/s, K = {}, seed {}, \
         guidance {} (N = {}, M ≤ {})",
        wins.len(),
        episodes.len(),
        args.episode
            .as_ref()
            .map_or("synthetic".to_string(), |p| p.display().to_string()),
        step.time,
        step.ego_speed,
        cfg.human2nav.samples,
        cfg.human2nav.seed,
        cfg.human2nav.guidance.variant.name(),
        cfg.human2nav.guidance.steps_n,
        cfg.human2nav.guidance.iterations_m,
    );
    let mut rows = Vec::new();
    for robot in &args.robot {
        let profile = load_profile(robot)?;
        let mut planners = Arm::ALL
            .iter()
            .map(|&arm| {
                // Native weights are read once and shared; libtorch loads its own copy.
                let model = match model.try_share() {
                    Some(m) => m,
                    None => load_model(model_dir, cfg.backend)?,
                };
                RobotPlanner::new(profile.clone(), model, arm.settings(&cfg.human2nav))
                    .map(|p| (arm, p))
            })
            .collect::<Result<Vec<_>, _>>()?;
        let limits = profile.limits;
        let pb = bar(wins.len(), &format!("windows ({})", profile.name));
        let mut steps = Vec::with_capacity(wins.len() * Arm::ALL.len());
        for (id, obs) in &wins {
            let mut arms: Vec<(Arm, &mut dyn Planner)> = planners
                .iter_mut()
                .map(|(arm, p)| (*arm, &mut p.planner as &mut dyn Planner))
                .collect();
            steps.extend(
                ablation_step(&mut arms, obs, &limits, &profile.footprint_shapes)
                    .with_context(|| format!("planning window {id} for {}", profile.name))?,
            );
            pb.inc(1);
        }
        pb.finish_and_clear();
        rows.extend(Arm::ALL.map(|arm| (profile.name.clone(), ArmSummary::of(arm, &steps))));
    }
    println!();
    println!(
        "| robot | arm | windows | TFS | all-feasible | Φ before | Φ after | samples in contact before | after Algorithm 1 | plan in contact | displacement vs raw (m) | displacement vs sample (m) | iterations | ms p50 | fallbacks |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|");
    for (name, s) in &rows {
        println!(
            "| {name} | {} | {} | {:.3} | {:.2} | {} | {} | {} | {} | {:.3} | {:.3} | {} | {} | {:.1} | {} |",
            s.arm.label(),
            s.windows,
            s.tfs,
            s.all_feasible,
            fmt_nan(s.phi_before, 3),
            fmt_nan(s.phi_after, 3),
            fmt_nan(s.contact_samples, 3),
            fmt_nan(s.contact_guided, 3),
            s.plan_contact,
            s.displacement,
            fmt_nan(s.sample_displacement, 3),
            fmt_nan(s.iterations, 1),
            s.millis_p50,
            s.fallbacks
        );
    }
    println!();
    println!("| robot | arm | {} |", Violations::NAMES.join(" | "));
    println!("|---|---|{}", "---|".repeat(Violations::NAMES.len()));
    for (name, s) in &rows {
        let shares: Vec<String> = s.violations.iter().map(|v| format!("{v:.3}")).collect();
        println!("| {name} | {} | {} |", s.arm.label(), shares.join(" | "));
    }
    println!();
    println!(
        "Arms: raw samples (no Algorithm 1, no correction, no extra candidates), Algorithm 1 only, \
         QP only (the correction of the same candidates), Algorithm 1 + QP (the configured planner); every arm \
         draws the same source samples. TFS: mean plan TFS (pose 0 = the robot at rest/--speed); \
         all-feasible: share of windows with TFS = 1; Φ before/after: the kept sample before and \
         after Algorithm 1; samples in contact before / after Algorithm 1: share of the model's \
         samples whose footprint touches someone walking on at constant velocity, before and \
         after guidance; plan in contact: share of windows whose plan does; displacement vs raw: mean distance to the raw arm's plan at equal \
         times; vs sample: to the kept sample before guidance and correction; iterations: \
         Algorithm 1 iterations run (mean); ms p50: wall time of a planning call. Second table: \
         share of waypoints violating each limit."
    );
    Ok(ExitCode::SUCCESS)
}

/// Algorithm 1 on recorded human windows (`--human`), per robot.
fn human_windows(
    args: &PlanArgs,
    cfg: &PlannerConfig,
    model: &PlannerModel,
    cache_dir: &Path,
    n: usize,
) -> anyhow::Result<()> {
    let cache = TupleCache::open(cache_dir).with_context(|| {
        format!(
            "opening the tuple cache {} (build it with `human2nav data build`)",
            cache_dir.display()
        )
    })?;
    let seed = cfg.human2nav.seed;
    let windows = cache_windows(&cache, Split::Val, n, seed)?;
    let mut guidance = cfg.human2nav.guidance;
    guidance.enabled = true;
    let opts = EvalOptions {
        samples: cfg.human2nav.samples,
        steps: guidance.steps_n,
        dt: cfg.human2nav.dt,
        seed,
        ..EvalOptions::default()
    };
    println!(
        "recorded human windows: {} of the validation split ({}), K = {} all guided, guidance {} \
         (N = {}, M ≤ {}), no correction",
        windows.len(),
        cache_dir.display(),
        opts.samples,
        guidance.variant.name(),
        guidance.steps_n,
        guidance.iterations_m
    );
    let mut rows = Vec::new();
    for robot in &args.robot {
        let profile = load_profile(robot)?;
        let phi = robot_phi(&profile)?;
        let pb = bar(windows.len(), &format!("human windows ({})", profile.name));
        let m = guided_windows(
            model,
            &windows,
            &phi,
            &profile.limits,
            &guidance,
            &opts,
            |_| pb.inc(1),
        )
        .with_context(|| format!("guiding the human windows for {}", profile.name))?;
        pb.finish_and_clear();
        rows.push((profile.name, m));
    }
    println!();
    println!(
        "| robot | windows | TFS human | TFS raw | TFS guided | ADE raw (m) | ADE guided (m) | min ADE raw (m) | min ADE guided (m) | displacement (m) | Φ raw | Φ guided | iterations |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|---|---|---|");
    for (name, m) in &rows {
        println!(
            "| {name} | {} | {:.3} | {:.3} | {:.3} | {:.3} | {:.3} | {:.3} | {:.3} | {:.3} | {:.3} | {:.3} | {:.1} |",
            m.windows,
            m.tfs_human,
            m.tfs_raw,
            m.tfs_guided,
            m.ade_raw,
            m.ade_guided,
            m.min_ade_raw,
            m.min_ade_guided,
            m.displacement,
            m.phi_raw,
            m.phi_guided,
            m.iterations
        );
    }
    println!();
    println!(
        "TFS human: the recorded futures against the robot's limits (starting at the recorded \
         velocity); raw/guided: mean over the K samples before/after Algorithm 1; ADE: mean over \
         samples of the distance to the recorded future; min ADE: best of K; displacement: \
         guided vs the same raw sample."
    );
    println!();
    Ok(())
}

fn fmt_nan(v: f64, decimals: usize) -> String {
    if v.is_nan() {
        "–".into()
    } else {
        format!("{v:.decimals$}")
    }
}

type TimedPlanner = Human2Nav<TimedModel<PlannerModel>>;

fn timed_planner(
    robot: &Path,
    model_dir: &Path,
    backend: Backend,
    settings: Human2NavSettings,
) -> anyhow::Result<(TimedPlanner, Arc<Mutex<FlowCallStats>>)> {
    let profile = load_profile(robot)?;
    let model = load_model(model_dir, backend)?;
    human2nav_flow::planner::check_dt(model.card(), &settings)?;
    let (bev, _) = bev_spec(model.card());
    let timed = TimedModel::new(model);
    let stats = timed.stats();
    let phi = robot_phi(&profile)?;
    let planner = Human2Nav::new(timed, robot_model(&profile, phi), bev, settings)?;
    Ok((planner, stats))
}

fn bench(
    args: &PlanArgs,
    cfg: &PlannerConfig,
    model_dir: &Path,
    prediction: Option<&PredictionModel>,
    episodes: &[Episode],
    step: &StepOptions,
    calls: usize,
) -> anyhow::Result<ExitCode> {
    let wins: Vec<Observation> = windows(episodes, 20, step)?
        .into_iter()
        .map(|(_, o)| o)
        .collect();
    let robot = &args.robot[0];
    let backends = match args.backend {
        Some(b) => vec![b],
        None => vec![Backend::Torch, Backend::Native],
    };
    println!(
        "planning latency: {} ({} windows), model {}, one thread, K = {}, N = {}, M ≤ {} (alg1+qp: {}), guided samples {}",
        robot.display(),
        wins.len(),
        model_dir.display(),
        cfg.human2nav.samples,
        cfg.human2nav.guidance.steps_n,
        cfg.human2nav.guidance.iterations_m,
        Arm::Both.settings(&cfg.human2nav).guidance.iterations_m,
        cfg.human2nav.guided_samples
    );
    let card = human2nav_flow::ModelCard::load(&model_dir.join(human2nav_flow::model::CARD_FILE))?;
    let unet_macs = Complexity::of(&card.net).unet_macs;
    // The machine's single-thread matrix-multiply rate, measured now (the limit a call is
    // compared with): the native kernel and libtorch's, the faster of the two counts.
    let native_rate = human2nav_flow::native::sgemm_gflops(512, 21);
    let torch_rate = torch_sgemm_gflops(512, 21);
    let peak = native_rate.max(torch_rate);
    println!(
        "single-thread SGEMM 512³: native kernel {native_rate:.1} GFLOP/s, libtorch {torch_rate:.1} GFLOP/s; limit = {peak:.1} GFLOP/s"
    );
    println!(
        "| mode | backend | calls | p50 (ms) | p95 (ms) | mean (ms) | network calls (fwd + VJP) | network (ms) | rest (ms) | MFLOP/call | limit (ms) | p50 / limit |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|---|---|");
    // The configured planner, then the ablation's arms that change the call's cost: no
    // guidance stage, the correction alone and Algorithm 1 + correction (its M = 3 when the
    // configuration runs no iterations), each without the robot's own motions.
    let modes = std::iter::once(("configured".to_string(), cfg.human2nav)).chain(
        [Arm::Raw, Arm::Qp, Arm::Both]
            .map(|arm| (arm.key().to_string(), arm.settings(&cfg.human2nav))),
    );
    for (mode, settings) in modes {
        for &backend in &backends {
            let (mut planner, stats) = timed_planner(robot, model_dir, backend, settings)?;
            // The configured planner predicts people as configured; the arms' rows time the
            // planner's own stages, at constant velocity.
            if let (Some(p), "configured") = (prediction, mode.as_str()) {
                planner = planner.with_predictor(p.predictor()?);
            }
            let pb = bar(calls, &format!("{mode} calls ({backend})"));
            let lock = || {
                stats
                    .lock()
                    .map(|s| *s)
                    .map_err(|_| anyhow::anyhow!("stats lock poisoned"))
            };
            // Warm-up calls are timed by the wrapper too: measure them separately and subtract.
            measure_latency(&mut planner, &wins, 5.min(calls), 0, || ())?;
            let before = lock()?;
            let lat: LatencyStats = measure_latency(&mut planner, &wins, 0, calls, || pb.inc(1))?;
            pb.finish_and_clear();
            let d = lock()?.since(&before);
            let n = lat.calls.max(1) as f64;
            let net_ms = (d.velocity_s + d.vjp_s) * 1e3 / n;
            let mflop = d.network_flops(unet_macs) / n / 1e6;
            // MFLOP / (GFLOP/s) = ms.
            let limit_ms = mflop / peak;
            println!(
                "| {mode} | {} | {} | {:.2} | {:.2} | {:.2} | {:.1} + {:.1} | {:.2} | {:.2} | {:.0} | {:.2} | {:.1} |",
                backend,
                lat.calls,
                lat.p50_ms,
                lat.p95_ms,
                lat.mean_ms,
                d.velocity_calls as f64 / n,
                d.vjp_calls as f64 / n,
                net_ms,
                lat.mean_ms - net_ms,
                mflop,
                limit_ms,
                lat.p50_ms / limit_ms
            );
        }
    }
    println!(
        "modes: the configured planner, and the guidance ablation's arms without the robot's own motions (raw = no \
         guidance stage; qp = shortlist, slowed and stop candidates and the last-step correction; alg1+qp = \
         Algorithm 1's iterations before it). \
         per call: network = flow-network calls (the condition encoding included in the first); rest = everything \
         else (BEV, sampling arithmetic, Φ, adjoint, last-step correction QPs, selection). MFLOP/call counts the \
         network's convolutions (a VJP is its forward pass plus the transposed products); limit = MFLOP/call at \
         the SGEMM rate above, so p50 / limit is how far a call is from the machine's arithmetic bound."
    );
    if cfg.human2nav.budget_ms > 0.0 {
        let mut settings = cfg.human2nav;
        settings.guidance.enabled = true;
        budget_table(robot, model_dir, &backends, settings, &wins, calls)?;
    }
    Ok(ExitCode::SUCCESS)
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

/// `plan --bench` with a budget: per guided call, how long after the deadline it returned and
/// which stage the deadline cut, and the TFS of the plans (the anytime planner must still
/// return feasible plans).
fn budget_table(
    robot: &Path,
    model_dir: &Path,
    backends: &[Backend],
    settings: Human2NavSettings,
    wins: &[Observation],
    calls: usize,
) -> anyhow::Result<()> {
    let budget = settings.budget_ms;
    let limits = load_profile(robot)?.limits;
    println!();
    println!("guided calls under a budget of {budget} ms (overshoot = call time − budget):");
    println!(
        "| backend | calls | p50 (ms) | max (ms) | overshoot p50 / p95 / max (ms) | cut in sampling / guidance / correction | fallbacks | mean TFS |"
    );
    println!("|---|---|---|---|---|---|---|---|");
    for &backend in backends {
        let (mut planner, _) = timed_planner(robot, model_dir, backend, settings)?;
        let pb = bar(calls, &format!("calls under {budget} ms ({backend})"));
        let (mut ms, mut cut, mut fallbacks, mut tfs_sum) = (Vec::new(), [0usize; 3], 0, 0.0);
        for obs in wins.iter().cycle().take(calls) {
            planner.reset();
            let start = std::time::Instant::now();
            let plan = planner.plan(obs)?;
            ms.push(start.elapsed().as_secs_f64() * 1e3);
            let stage = plan.info.stages.and_then(|s| s.cut_short);
            for (slot, st) in
                cut.iter_mut()
                    .zip([Stage::Sampling, Stage::Guidance, Stage::Correction])
            {
                *slot += usize::from(stage == Some(st));
            }
            fallbacks += usize::from(plan.info.fallback);
            let ego: Vec<_> = plan.poses.iter().map(|p| obs.ego.between(*p)).collect();
            tfs_sum += tfs::tfs_plan(&ego, plan.dt, &limits, obs.ego_velocity);
            pb.inc(1);
        }
        pb.finish_and_clear();
        let lat = LatencyStats::of(&ms);
        let over: Vec<f64> = ms.iter().map(|m| m - budget).collect();
        let over = LatencyStats::of(&over);
        let share = |c: usize| 100.0 * c as f64 / ms.len().max(1) as f64;
        println!(
            "| {backend} | {} | {:.2} | {:.2} | {:.2} / {:.2} / {:.2} | {:.0} / {:.0} / {:.0} % | {fallbacks} | {:.3} |",
            lat.calls,
            lat.p50_ms,
            lat.max_ms,
            over.p50_ms,
            over.p95_ms,
            over.max_ms,
            share(cut[0]),
            share(cut[1]),
            share(cut[2]),
            tfs_sum / ms.len().max(1) as f64
        );
    }
    Ok(())
}

/// libtorch's single-thread SGEMM rate on `n × n` matrices (median of `repeats`), GFLOP/s.
fn torch_sgemm_gflops(n: i64, repeats: usize) -> f64 {
    use human2nav_flow::tch::{Device, Kind, Tensor};
    let threads = human2nav_flow::tch::get_num_threads();
    human2nav_flow::tch::set_num_threads(1);
    let a = Tensor::randn([n, n], (Kind::Float, Device::Cpu));
    let b = Tensor::randn([n, n], (Kind::Float, Device::Cpu));
    let _ = a.matmul(&b);
    let mut secs: Vec<f64> = (0..repeats.max(1))
        .map(|_| {
            let start = std::time::Instant::now();
            let _ = std::hint::black_box(a.matmul(&b));
            start.elapsed().as_secs_f64()
        })
        .collect();
    human2nav_flow::tch::set_num_threads(threads);
    secs.sort_by(f64::total_cmp);
    2.0 * (n * n * n) as f64 / secs[secs.len() / 2] / 1e9
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
