//! `human2nav plan --bench`: the latency of a planning call per backend and guidance arm, where
//! its time goes, and with a budget how the deadline cuts the stages.

use super::{PlanArgs, bar, windows};
use human2nav_core::ablation::Arm;
use human2nav_core::feasibility;
use human2nav_core::human2nav::{Human2Nav, Human2NavSettings};
use human2nav_core::{Observation, Planner, Stage};
use human2nav_flow::net::Complexity;
use human2nav_flow::planner::{
    Backend, FlowCallStats, LatencyStats, PlannerConfig, PlannerModel, PredictionModel, TimedModel,
    bev_spec, load_model, load_profile, measure_latency, robot_model, robot_phi,
};
use human2nav_sim::episode::Episode;
use human2nav_sim::plan_figure::StepOptions;
use std::path::Path;
use std::process::ExitCode;
use std::sync::{Arc, Mutex};

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

pub(super) fn bench(
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
            let macs = |p: &TimedPlanner| p.model().inner().macs();
            let (before, macs_before) = (lock()?, macs(&planner));
            let lat: LatencyStats = measure_latency(&mut planner, &wins, 0, calls, || pb.inc(1))?;
            pb.finish_and_clear();
            let d = lock()?.since(&before);
            let n = lat.calls.max(1) as f64;
            let net_ms = (d.velocity_s + d.vjp_s) * 1e3 / n;
            // The work the native network counted it did; libtorch's by the architecture.
            let flops = match (macs_before, macs(&planner)) {
                (Some(a), Some(b)) => 2.0 * (b - a) as f64,
                _ => d.network_flops(unet_macs),
            };
            let mflop = flops / n / 1e6;
            // MFLOP / (GFLOP/s) = ms.
            let limit_ms = mflop / peak;
            println!(
                "| {mode} | {} | {} | {:.2} | {:.2} | {:.2} | {:.1} + {:.1} | {:.2} | {:.2} | {:.0} | {:.2} | {:.2} |",
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
         else (BEV, sampling arithmetic, Φ, adjoint, last-step correction QPs, selection). MFLOP/call: native, the \
         products the network did (convolutions, and the crowd pathway at its occupied cells; a VJP is the \
         transposed products and the crowd pathway's picked pairs; a kept pass reused counts nothing); libtorch, \
         by the architecture (a VJP is its forward pass plus the transposed products, the crowd pathway at every \
         cell). limit = MFLOP/call at the SGEMM rate above, so p50 / limit is how far a call is from the least \
         time its arithmetic can take on this machine."
    );
    if let Some(batch) = args.batch {
        let shape = (calls, batch);
        super::batch::batch_table(robot, model_dir, &backends, &cfg.human2nav, &wins, shape)?;
    }
    if cfg.human2nav.budget_ms > 0.0 {
        let mut settings = cfg.human2nav;
        settings.guidance.enabled = true;
        budget_table(robot, model_dir, &backends, settings, &wins, calls)?;
    }
    Ok(ExitCode::SUCCESS)
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
            tfs_sum += feasibility::tfs_plan(&ego, plan.dt, &limits, obs.ego_velocity);
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
