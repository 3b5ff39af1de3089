//! `human2nav plan --eval`: guided against unguided plans (the ablation's arms) on many
//! held-out windows per robot, and guidance measured on recorded windows of the validation split.

use super::{PlanArgs, bar, windows};
use anyhow::Context;
use human2nav_core::Planner;
use human2nav_core::ablation::{Arm, ArmSummary, ablation_step};
use human2nav_core::feasibility::Violations;
use human2nav_data::cache::TupleCache;
use human2nav_data::tuples::Split;
use human2nav_experiments::train::cache_windows;
use human2nav_flow::eval::{EvalOptions, guided_windows};
use human2nav_flow::planner::{
    PlannerConfig, PlannerModel, RobotPlanner, load_model, load_profile, robot_phi,
};
use human2nav_sim::episode::Episode;
use human2nav_sim::plan_figure::StepOptions;
use std::path::Path;
use std::process::ExitCode;

pub(super) fn eval(
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
pub(super) fn human_windows(
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
