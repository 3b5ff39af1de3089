//! Latency of one Human2Nav planning call (BEV, K samples, guidance, selection) for the
//! configured planner and the guidance ablation's arms that change its cost (`raw`: no guidance
//! stage; `qp`: shortlist and last-step correction; `alg1+qp`: Algorithm 1's iterations before
//! the correction; the arms without the robot's own motions), with the network run natively and
//! by libtorch (one thread by default): `plan/{configured,raw,qp,alg1+qp}/{native,torch}`.
//! Before the timings it prints each configuration's network operations per call (those the
//! native network counts it did, `NativeCfm::macs`), this machine's single-thread SGEMM rate
//! and the resulting lower bound on a call's time, so the criterion medians can be read as
//! ratios to it.
//!
//! The model is the shipped one (`models/human2nav-cfm`, or `$H2N_MODEL`); without it, a
//! freshly initialised model of the default architecture (same cost per network call, but
//! guidance may stop after a different number of iterations than with trained weights). The
//! scenes are the held-out episodes at `out/data/episodes.json` when present, else synthetic
//! ones; the robot is `robots/diablo/robot.toml` (or `$H2N_ROBOT`); the planner settings are
//! those of `sdk/configs/planner.toml`.
//!
//! `plan_batch/*` times [`BATCH`] planners per iteration planned one by one and as one
//! `Human2Nav::plan_batch` (native backend, the configured planner and the raw arm): plans per
//! second on one thread.
//!
//! Run: `cargo bench -p human2nav-flow --features torch --bench planning` (threads: `H2N_THREADS`,
//! default 1; `H2N_SAMPLES=16` times the calls at K = 16 instead of the configured K).
//! `human2nav plan --bench <calls>` reports p50/p95 and the time split on the same setup.

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use human2nav_core::ablation::Arm;
use human2nav_core::human2nav::{Human2Nav, Human2NavSettings};
use human2nav_core::{Observation, Planner};
use human2nav_data::{EpisodeSuite, ScenarioClass};
use human2nav_flow::perf::{episode_start, start_scenes};
use human2nav_flow::planner::{
    Backend, DEFAULT_MODEL_DIR, PlannerConfig, PlannerModel, RobotPlanner, load_model,
    load_profile, robot_model, robot_phi,
};
use human2nav_flow::{CfmModel, NetConfig, Normalisation};
use std::hint::black_box;
use std::path::{Path, PathBuf};
use tch::Device;

/// What is timed, in table order: the configured planner, then the guidance ablation's arms
/// that change the cost (each without the robot's own motions).
fn modes(base: &Human2NavSettings) -> Vec<(String, Human2NavSettings)> {
    std::iter::once(("configured".to_string(), *base))
        .chain([Arm::Raw, Arm::Qp, Arm::Both].map(|a| (a.key().to_string(), a.settings(base))))
        .collect()
}

fn workspace() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

fn env_path(var: &str, default: &str) -> PathBuf {
    std::env::var_os(var).map_or_else(|| workspace().join(default), PathBuf::from)
}

fn scenes() -> Vec<Observation> {
    let path = workspace().join("out/data/episodes.json");
    match EpisodeSuite::load(&path) {
        Ok(suite) => start_scenes(&suite.episodes, 20),
        Err(_) => {
            let episodes: Vec<_> = ScenarioClass::ALL
                .iter()
                .flat_map(|c| human2nav_data::synthetic::episodes(*c, 5, 1))
                .collect();
            episodes.iter().map(episode_start).collect()
        }
    }
}

fn model_dir() -> PathBuf {
    let dir = env_path("H2N_MODEL", DEFAULT_MODEL_DIR);
    if dir.join("model.toml").is_file() {
        return dir;
    }
    eprintln!(
        "no model at {}: benchmarking a fresh default-architecture model",
        dir.display()
    );
    tch::manual_seed(0);
    let norm = Normalisation {
        position_scale: 2.2,
        velocity_std: [1.4, 1.1, 1.1],
        goal_scale: 5.5,
        speed_scale: 1.3,
        goal_conditioned: true,
        velocity_conditioned: true,
    };
    let model = CfmModel::new(&NetConfig::default(), &norm, Device::Cpu).expect("default config");
    let tmp = std::env::temp_dir().join(format!("h2n-planning-bench-{}", std::process::id()));
    model.save(&tmp).expect("saving the fresh model");
    tmp
}

fn bench_planning(c: &mut Criterion) {
    let threads = std::env::var("H2N_THREADS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(1);
    tch::set_num_threads(threads);
    let robot = env_path("H2N_ROBOT", "robots/diablo/robot.toml");
    let profile = load_profile(&robot).expect("robot profile");
    let dir = model_dir();
    let obs = scenes();
    // The shipped planner settings (sdk/configs/planner.toml), else the built-in defaults.
    let mut base: Human2NavSettings =
        PlannerConfig::load(&workspace().join("sdk/configs/planner.toml"))
            .map(|c| c.human2nav)
            .unwrap_or_default();
    // `H2N_SAMPLES`: another K, as `plan --bench --samples K` (the guided call is timed at 16).
    if let Some(k) = std::env::var("H2N_SAMPLES")
        .ok()
        .and_then(|s| s.parse().ok())
    {
        base.samples = k;
    }
    let peak = human2nav_flow::native::sgemm_gflops(512, 21);
    for (mode, settings) in modes(&base) {
        let model = load_model(&dir, Backend::Native).expect("model");
        let bev = human2nav_flow::planner::bev_spec(model.card()).0;
        let phi = robot_phi(&profile).expect("robot terms");
        let mut p =
            Human2Nav::new(model, robot_model(&profile, phi), bev, settings).expect("planner");
        // The products the native network counts it did (`NativeCfm::macs`).
        let macs = |p: &Human2Nav<PlannerModel>| p.model().macs().unwrap_or(0);
        let before = macs(&p);
        for o in &obs {
            p.reset();
            p.plan(o).expect("plan");
        }
        let flops = 2.0 * (macs(&p) - before) as f64 / obs.len() as f64;
        eprintln!(
            "plan/{mode}: {:.0} MFLOP of network per call; single-thread SGEMM {peak:.1} GFLOP/s; limit {:.2} ms",
            flops / 1e6,
            flops / (peak * 1e9) * 1e3
        );
    }
    let mut group = c.benchmark_group("plan");
    group
        .sample_size(20)
        .measurement_time(std::time::Duration::from_secs(10));
    for (mode, settings) in modes(&base) {
        for backend in [Backend::Native, Backend::Torch] {
            let model = load_model(&dir, backend).expect("model");
            let mut rp = RobotPlanner::new(profile.clone(), model, settings).expect("planner");
            let mut i = 0usize;
            let name = format!("{mode}/{backend}");
            group.bench_function(name, |b| {
                b.iter(|| {
                    rp.planner.reset();
                    i = (i + 1) % obs.len();
                    black_box(rp.planner.plan(black_box(&obs[i])).expect("plan"))
                })
            });
        }
    }
    group.finish();
}

/// Planners planned per batch in `plan_batch/*`.
const BATCH: usize = 16;

/// Throughput of [`Human2Nav::plan_batch`] against the same planners planned one by one:
/// `plan_batch/{configured,raw}/{one_by_one,batched}`, [`BATCH`] planners (clones of one native
/// model) per iteration, planner `i` of iteration `r` on scene `r·BATCH + i` (a planner that
/// saw the same scene again would find its forward passes kept); criterion reports plans per
/// second.
fn bench_batch(c: &mut Criterion) {
    let robot = env_path("H2N_ROBOT", "robots/diablo/robot.toml");
    let profile = load_profile(&robot).expect("robot profile");
    let model = human2nav_flow::NativeCfm::load(&model_dir()).expect("model");
    let scenes = scenes();
    let round = |r: usize| -> Vec<Observation> {
        (0..BATCH)
            .map(|i| scenes[(r * BATCH + i) % scenes.len()].clone())
            .collect()
    };
    let base: Human2NavSettings =
        PlannerConfig::load(&workspace().join("sdk/configs/planner.toml"))
            .map(|c| c.human2nav)
            .unwrap_or_default();
    let mut group = c.benchmark_group("plan_batch");
    group
        .sample_size(10)
        .measurement_time(std::time::Duration::from_secs(10))
        .throughput(Throughput::Elements(BATCH as u64));
    for (mode, settings) in modes(&base).into_iter().take(2) {
        let mut planners: Vec<RobotPlanner> = (0..BATCH)
            .map(|_| RobotPlanner::new(profile.clone(), model.clone(), settings).expect("planner"))
            .collect();
        let mut r = 0;
        group.bench_function(format!("{mode}/one_by_one"), |b| {
            b.iter(|| {
                r += 1;
                for (p, o) in planners.iter_mut().zip(&round(r)) {
                    p.planner.reset();
                    black_box(p.planner.plan(o).expect("plan"));
                }
            })
        });
        group.bench_function(format!("{mode}/batched"), |b| {
            b.iter(|| {
                r += 1;
                let mut refs: Vec<_> = planners
                    .iter_mut()
                    .map(|p| {
                        p.planner.reset();
                        &mut p.planner
                    })
                    .collect();
                black_box(Human2Nav::plan_batch(&mut refs, &round(r)).expect("batch"))
            })
        });
    }
    group.finish();
}

criterion_group!(benches, bench_planning, bench_batch);
criterion_main!(benches);
