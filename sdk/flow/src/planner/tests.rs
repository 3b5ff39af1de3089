//! Tests of the planner: configuration, the model card's raster and pose spacing, latency
//! statistics, and planners built from a profile and a model folder.

use super::card::resolution_from_record;
use super::*;
use crate::card::{ModelCard, TrainingInfo};
#[cfg(feature = "torch")]
use crate::model::CfmModel;
use approx::assert_relative_eq;
#[cfg(feature = "torch")]
use human2nav_core::Pose2;
#[cfg(feature = "torch")]
use human2nav_core::ablation::{Arm, ablation_step};
use human2nav_core::bev::BevSpec;
#[cfg(feature = "torch")]
use human2nav_core::forecast::FlowPredictorSettings;
#[cfg(feature = "torch")]
use human2nav_core::human2nav::Human2Nav;
use human2nav_core::human2nav::Human2NavSettings;
#[cfg(feature = "torch")]
use human2nav_core::{Observation, Planner};
use std::path::{Path, PathBuf};

#[test]
fn a_planner_dt_other_than_the_training_one_is_refused() {
    let mut card = ModelCard::default();
    let at = |dt| Human2NavSettings {
        dt,
        ..Human2NavSettings::default()
    };
    assert_relative_eq!(trained_dt(&card), TRAINING_DT);
    assert!(check_dt(&card, &at(0.1)).is_ok());
    let err = check_dt(&card, &at(0.4)).unwrap_err().to_string();
    assert!(
        err.contains("human2nav.dt") && err.contains("0.4 s") && err.contains("0.1 s apart"),
        "{err}"
    );
    card.training = Some(TrainingInfo {
        data: "tuple cache, BEV 32×32 cells of 0.3 m, 32 poses at 0.2 s".into(),
        ..TrainingInfo::default()
    });
    assert_relative_eq!(trained_dt(&card), 0.2);
    assert!(check_dt(&card, &at(0.2)).is_ok());
}

#[test]
fn bev_raster_comes_from_the_card_table_or_the_training_record() {
    let mut card = ModelCard::default();
    card.net.bev_cells = 24;
    let (spec, origin) = bev_spec(&card);
    assert_eq!(origin, BevOrigin::Default);
    assert_eq!(spec.cells, 24);
    assert_relative_eq!(spec.resolution, BevSpec::default().resolution);

    card.training = Some(TrainingInfo {
        data: "tuple cache `out/data/cache` (real data: eth, sdd), BEV 24×24 cells of 0.25 m, \
               32 poses at 0.1 s"
            .into(),
        ..TrainingInfo::default()
    });
    let (spec, origin) = bev_spec(&card);
    assert_eq!(origin, BevOrigin::Record);
    assert_eq!(spec.cells, 24);
    assert_relative_eq!(spec.resolution, 0.25, epsilon = 1e-15);

    // The card's [bev] table wins over the record.
    card.bev = Some(BevSpec {
        cells: 24,
        resolution: 0.4,
    });
    assert_eq!(bev_spec(&card), (card.bev.unwrap(), BevOrigin::Card));

    // A record without a usable length falls back to the default.
    for data in ["BEV cells of x m", "cells of -1 m", "no raster here"] {
        assert_eq!(resolution_from_record(data), None, "{data}");
    }
}

#[test]
fn config_defaults_round_trip_and_reject_unknown_keys() {
    let path = Path::new("planner.toml");
    let cfg = PlannerConfig::from_toml_str("", path).unwrap();
    assert_eq!(cfg, PlannerConfig::default());
    let cfg = PlannerConfig::from_toml_str(
        "threads = 2\n[human2nav]\nsamples = 8\n[human2nav.guidance]\niterations_m = 3\n",
        path,
    )
    .unwrap();
    assert_eq!(cfg.threads, 2);
    assert_eq!(cfg.human2nav.samples, 8);
    assert_eq!(cfg.human2nav.guidance.iterations_m, 3);
    let err = PlannerConfig::from_toml_str("[human2nav]\nsamplez = 8\n", path).unwrap_err();
    assert!(err.to_string().contains("samplez"), "{err}");
    for bad in ["threads = 0\n", "threads = 100000\n"] {
        let err = PlannerConfig::from_toml_str(bad, path).unwrap_err();
        assert!(matches!(err, PlannerError::Setting { ref field, .. } if field == "threads"));
    }
    let err =
        PlannerConfig::from_toml_str("[human2nav]\nsamples = 0\nmotions = 0\n", path).unwrap_err();
    assert!(err.to_string().contains("samples"), "{err}");
    assert_eq!(
        cfg.model_dir(Path::new("/ws")),
        Path::new("/ws").join(DEFAULT_MODEL_DIR)
    );
}

#[test]
fn latency_percentiles_are_nearest_rank() {
    let ms: Vec<f64> = (1..=20).map(f64::from).collect();
    let s = LatencyStats::of(&ms);
    assert_eq!(s.calls, 20);
    assert_relative_eq!(s.p50_ms, 10.0);
    assert_relative_eq!(s.p95_ms, 19.0);
    assert_relative_eq!(s.mean_ms, 10.5);
    assert_relative_eq!(s.max_ms, 20.0);
    let one = LatencyStats::of(&[3.0]);
    assert_relative_eq!(one.p50_ms, 3.0);
    assert_relative_eq!(one.p95_ms, 3.0);
    assert!(LatencyStats::of(&[]).p50_ms.is_nan());
}

fn workspace() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// A small freshly initialised model saved to a temporary folder.
#[cfg(feature = "torch")]
fn small_model_dir(tag: &str) -> PathBuf {
    small_model_dir_with(tag, true)
}

/// A small untrained model folder; `goal_conditioned: false` makes it a predictor's.
#[cfg(feature = "torch")]
fn small_model_dir_with(tag: &str, goal_conditioned: bool) -> PathBuf {
    use crate::config::{NetConfig, Normalisation};
    tch::manual_seed(11);
    let net = NetConfig {
        horizon: 16,
        bev_cells: 16,
        down_dims: vec![8, 16],
        n_groups: 4,
        bev_channels: [4, 8, 8],
        time_embed_dim: 8,
        bev_embed_dim: 8,
        goal_embed_dim: 8,
        ..NetConfig::default()
    };
    let norm = Normalisation {
        position_scale: 1.5,
        velocity_std: [0.8, 0.3, 0.5],
        goal_scale: 4.0,
        speed_scale: 1.0,
        goal_conditioned,
        velocity_conditioned: true,
    };
    let dir = std::env::temp_dir().join(format!("h2n-planner-{tag}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    CfmModel::new(&net, &norm, tch::Device::Cpu)
        .unwrap()
        .save(&dir)
        .unwrap();
    dir
}

#[cfg(feature = "torch")]
fn observation() -> Observation {
    Observation {
        time: 1.5,
        ego: Pose2::new(2.0, -1.0, 0.4),
        ego_velocity: human2nav_core::Twist2::new(0.6, 0.0, 0.0),
        goal: [7.0, 1.0],
        agents: vec![human2nav_core::AgentState {
            id: 3,
            position: [3.5, -0.2],
            velocity: [-0.8, 0.1],
            radius: 0.3,
            history: vec![[3.7, -0.25], [3.6, -0.22]],
        }],
        ..Default::default()
    }
}

/// Profile + model folder → planner; guidance never raises Φ of the kept sample, the plan
/// starts at the robot, and guided and unguided planners with one seed share their samples.
#[test]
#[cfg(feature = "torch")]
fn planner_from_profile_and_model_folder() {
    let dir = small_model_dir("e2e");
    let robot = workspace().join("robots/diablo/robot.toml");
    // Algorithm 1's iterations on (the shipped planner runs none), so that its plumbing
    // and call counts are exercised; only the samples on offer (no slowed copies, stop or
    // goal candidates), so that the plan is a guided sample whatever Φ makes of braking.
    let settings = Arm::Both.settings(&Human2NavSettings {
        samples: 6,
        slowdown: 1.0,
        stop_candidate: false,
        goal_approach: 0.0,
        ..Human2NavSettings::default()
    });
    assert!(settings.guidance.iterations_m > 0);
    let mut guided = RobotPlanner::load(&robot, &dir, settings).unwrap();
    assert_eq!(guided.profile.name, "diablo");
    assert_eq!(guided.bev.cells, 16);
    assert_eq!(guided.bev_origin, BevOrigin::Default);
    let off = Arm::Raw.settings(&settings);
    let mut unguided = RobotPlanner::load(&robot, &dir, off).unwrap();
    assert_eq!(unguided.planner.name(), "human2nav");

    let obs = observation();
    let limits = *guided.limits();
    let plan = guided.planner.plan(&obs).unwrap();
    assert!(plan.is_finite());
    assert!(!plan.info.fallback, "{:?}", plan.info.notes);
    assert_eq!(plan.poses.len(), 17);
    assert_eq!(plan.poses[0], obs.ego);
    let (before, after) = (plan.info.phi_before.unwrap(), plan.info.phi_after.unwrap());
    assert!(after <= before + 1e-12, "Φ {before} → {after}");

    let m = settings.guidance.iterations_m;
    assert!(
        plan.info.guidance_iterations.is_some_and(|i| i <= m),
        "{:?}",
        plan.info
    );
    // Both planners drew the same source samples: identical pre-guidance candidates, and
    // the ablation's arms plan from them.
    guided.planner.reset();
    unguided.planner.reset();
    let g = guided.planner.plan(&obs).unwrap();
    let u = unguided.planner.plan(&obs).unwrap();
    assert_eq!(g.info.candidates, u.info.candidates);
    let footprint = guided.profile.footprint_shapes.clone();
    let mut arms: [(Arm, &mut dyn Planner); 2] = [
        (Arm::Raw, &mut unguided.planner),
        (Arm::Both, &mut guided.planner),
    ];
    let steps = ablation_step(&mut arms, &obs, &limits, &footprint).unwrap();
    assert!(steps[0].contact_samples.is_some());
    assert_eq!(steps[0].displacement, 0.0);
    assert_eq!(steps[0].iterations, None);
    assert!((0.0..=1.0).contains(&steps[1].tfs));
    assert_eq!(steps[1].phi_after, plan.info.phi_after);

    // The timing wrapper counts the calls Algorithm 1 documents: N for the first rollout,
    // then N per iteration forward and N − 1 VJPs backward.
    let model = load_model(&dir, Backend::Native).unwrap();
    let timed = TimedModel::new(model);
    let stats = timed.stats();
    let (bev, _) = bev_spec(timed.inner.card());
    let mut p = Human2Nav::new(
        timed,
        robot_model(&guided.profile, robot_phi(&guided.profile).unwrap()),
        bev,
        settings,
    )
    .unwrap();
    let lat = measure_latency(&mut p, std::slice::from_ref(&obs), 0, 1, || ()).unwrap();
    assert_eq!(lat.calls, 1);
    let s = *stats.lock().unwrap();
    let n = settings.guidance.steps_n as u64;
    assert!(s.velocity_calls >= n && s.velocity_calls % n == 0, "{s:?}");
    let iterations = s.velocity_calls / n - 1;
    assert_eq!(s.vjp_calls, iterations * (n - 1), "{s:?}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
#[cfg(feature = "torch")]
fn a_prediction_model_is_goal_free_and_predicts_for_the_planner() {
    let ws = Path::new("/ws");
    let with_model = |dir: &Path| PlannerConfig {
        prediction: PredictionConfig {
            model: Some(dir.to_path_buf()),
            flow: FlowPredictorSettings::default(),
        },
        ..PlannerConfig::default()
    };
    // No [prediction] model: nothing is loaded.
    assert!(
        PredictionModel::load(&PlannerConfig::default(), ws)
            .unwrap()
            .is_none()
    );
    // A missing folder is named with the workspace it was resolved against.
    let err = PredictionModel::load(&with_model(Path::new("no/such/predictor")), ws)
        .unwrap_err()
        .to_string();
    assert!(err.contains("/ws/no/such/predictor"), "{err}");
    // A planner's model (conditioned on goals) is refused by field.
    let planner_dir = small_model_dir_with("pred-goal", true);
    let err = PredictionModel::load(&with_model(&planner_dir), ws).unwrap_err();
    assert!(
        matches!(err, PlannerError::Setting { ref field, ref message }
            if field == "prediction.model" && message.contains("goal-free")),
        "{err}"
    );
    // A goal-free one predicts: the planner's plan is made against its forecast.
    let dir = small_model_dir_with("pred-free", false);
    let robot = workspace().join("robots/diablo/robot.toml");
    let rp = RobotPlanner::load(&robot, &planner_dir, Human2NavSettings::default())
        .unwrap()
        .with_prediction(&with_model(&dir), ws)
        .unwrap();
    let mut planner = rp.planner;
    assert_eq!(planner.predictor().map(|p| p.name()), Some("flow"));
    let plan = planner.plan(&observation()).unwrap();
    assert!(plan.is_finite() && !plan.info.fallback, "{:?}", plan.info);
    assert!(
        !plan.info.notes.iter().any(|n| n.contains("predictor")),
        "{:?}",
        plan.info.notes
    );
    // The table's keys are checked by name.
    let path = Path::new("planner.toml");
    let err = PlannerConfig::from_toml_str("[prediction]\nmodle = \"m\"\n", path).unwrap_err();
    assert!(err.to_string().contains("modle"), "{err}");
    let err = PlannerConfig::from_toml_str(
        "[prediction]\nmodel = \"m\"\n[prediction.flow]\nsamples = 0\n",
        path,
    )
    .unwrap_err();
    assert!(
        err.to_string().contains("`prediction.flow.samples`"),
        "{err}"
    );
    let _ = std::fs::remove_dir_all(&dir);
    let _ = std::fs::remove_dir_all(&planner_dir);
}

#[test]
fn missing_model_and_profile_are_named() {
    let backends: &[Backend] = if cfg!(feature = "torch") {
        &[Backend::Native, Backend::Torch]
    } else {
        &[Backend::Native]
    };
    for &backend in backends {
        let err = load_model(Path::new("no/such/model"), backend).unwrap_err();
        assert!(err.to_string().contains("no/such/model"), "{err}");
    }
    let err = load_profile(Path::new("no/such/robot.toml")).unwrap_err();
    assert!(matches!(err, PlannerError::Profile { .. }), "{err}");
}

/// Without the `torch` feature, asking for the torch backend (in the file or when loading)
/// is an error on `backend` that says how to get a build with it.
#[test]
#[cfg(not(feature = "torch"))]
fn the_torch_backend_without_libtorch_says_how_to_get_it() {
    let err =
        PlannerConfig::from_toml_str("backend = \"torch\"\n", Path::new("p.toml")).unwrap_err();
    assert!(
        matches!(err, PlannerError::Setting { ref field, ref message }
            if field == "backend" && message.contains("--features torch")),
        "{err}"
    );
    for backend in [Backend::Torch, Backend::Cuda] {
        let err = load_model(&workspace().join("models/human2nav-cfm"), backend).unwrap_err();
        assert!(err.to_string().contains("`torch` cargo feature"), "{err}");
    }
    assert!(load_model(&workspace().join("models/human2nav-cfm"), Backend::Native).is_ok());
}

/// The GPU path: the shipped model on the first CUDA device computes what the native backend
/// computes (velocity and VJP of 16 samples; CUDA convolutions may run in TF32, hence the
/// tolerance), and a guided planner on it returns a plan from the robot. Without a CUDA
/// device, asking for one is an error on `backend`, and the comparison is skipped. The batch
/// API is checked there too: one pass for two conditions, and two GPU planners planned at once.
#[test]
#[cfg(feature = "torch")]
fn the_cuda_backend_agrees_with_the_native_one_where_a_gpu_is_present() {
    use human2nav_core::flow::{FlowModel, FlowQuery};
    let dir = workspace().join("models/human2nav-cfm");
    if !tch::Cuda::is_available() {
        let err = load_model(&dir, Backend::Cuda).unwrap_err();
        assert!(
            matches!(err, PlannerError::Setting { ref field, ref message }
                if field == "backend" && message.contains("no CUDA device")),
            "{err}"
        );
        eprintln!("no CUDA device: the GPU comparison is skipped");
        return;
    }
    let gpu = load_model(&dir, Backend::Cuda).expect("model on the GPU");
    let cpu = load_model(&dir, Backend::Native).expect("native model");
    let h = cpu.horizon();
    let cond = crate::perf::bench_condition(cpu.card().net.bev_cells);
    let mut rng = <rand_chacha::ChaCha8Rng as rand::SeedableRng>::seed_from_u64(5);
    let x = crate::cfm::sample_source(16, h, cpu.source_std(), &mut rng);
    let cot: Vec<f64> = (0..x.len()).map(|i| ((i % 7) as f64 - 3.0) * 0.1).collect();
    let n = x.len();
    let (mut va, mut vb, mut ja, mut jb) = (vec![0.0; n], vec![0.0; n], vec![0.0; n], vec![0.0; n]);
    for t in [0.0, 0.6] {
        gpu.velocity_vjp(&x, t, &cond, &cot, &mut va, &mut ja)
            .expect("GPU VJP");
        cpu.velocity_vjp(&x, t, &cond, &cot, &mut vb, &mut jb)
            .expect("native VJP");
        for (what, a, b) in [("velocity", &va, &vb), ("VJP", &ja, &jb)] {
            let scale = b.iter().fold(0f64, |m, v| m.max(v.abs()));
            let diff = a.iter().zip(b).fold(0f64, |m, (p, q)| m.max((p - q).abs()));
            assert!(
                diff <= 1e-2 * scale,
                "{what} at t = {t}: {diff} against {scale}"
            );
        }
    }
    // The batch API on the GPU: one pass for two conditions agrees with the native calls.
    let empty = human2nav_core::flow::FlowCondition {
        bev: vec![0.0; cond.bev.len()],
        ..cond.clone()
    };
    let queries = [(&cond, 0.2), (&empty, 0.8)].map(|(cond, t)| FlowQuery { x: &x, t, cond });
    let mut batched = vec![0.0; 2 * n];
    gpu.velocity_batch(&queries, &mut batched)
        .expect("GPU batch");
    for (q, b) in queries.iter().zip(batched.chunks_exact(n)) {
        cpu.velocity(q.x, q.t, q.cond, &mut vb)
            .expect("native velocity");
        let scale = vb.iter().fold(0f64, |m, v| m.max(v.abs()));
        let diff = b
            .iter()
            .zip(&vb)
            .fold(0f64, |m, (p, q)| m.max((p - q).abs()));
        assert!(diff <= 1e-2 * scale, "batched at t = {}: {diff}", q.t);
    }
    let profile = load_profile(&workspace().join("robots/diablo/robot.toml")).expect("profile");
    let settings = Arm::Both.settings(&Human2NavSettings::default());
    let mut rp = RobotPlanner::new(profile.clone(), gpu, settings).expect("planner on the GPU");
    let obs = observation();
    let plan = rp.planner.plan(&obs).expect("plan");
    assert!(!plan.poses.is_empty());
    assert!(
        plan.poses
            .iter()
            .all(|p| p.x.is_finite() && p.y.is_finite())
    );
    // Two GPU planners loaded from one folder plan as a batch.
    let second = load_model(&dir, Backend::Cuda).expect("second GPU model");
    let mut other = RobotPlanner::new(profile, second, settings).expect("second planner");
    let mut both = [&mut rp.planner, &mut other.planner];
    for plan in Human2Nav::plan_batch(&mut both, &[obs.clone(), obs]).expect("batch") {
        let plan = plan.expect("plan");
        assert!(!plan.info.fallback && plan.is_finite());
    }
}
