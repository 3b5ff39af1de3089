//! Writes what `sdk/flow/reference/torch_planning_call.py` reads: for up to 20 windows of an
//! episode file (each episode's start, [`start_scenes`]), the flow condition the planner builds
//! (BEV raster, goal, velocity), K source samples, the native backend's velocity of them at
//! flow time 0, and its samples after N
//! Euler steps, at the settings of `sdk/configs/planner.toml` with K = 16 and Algorithm 1's
//! M = 3 (as `plan --bench --samples 16` times them).
//!
//! ```sh
//! cargo run --release -p human2nav-flow --example planning_reference -- \
//!     models/human2nav-cfm out/data/episodes-interaction-val.json \
//!     target/torch_reference/planning.safetensors
//! ```

use anyhow::{Context, bail};
use human2nav_core::ablation::Arm;
use human2nav_core::flow::{FlowModel, draw_source};
use human2nav_data::EpisodeSuite;
use human2nav_flow::perf::start_scenes;
use human2nav_flow::planner::{PlannerConfig, RobotPlanner};
use human2nav_flow::sampler::integrate;
use rand::SeedableRng;
use safetensors::{Dtype, tensor::TensorView};
use std::path::Path;

/// Samples per window (the guided comparison's K).
const SAMPLES: usize = 16;

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let [_, model_dir, episodes, out] = args.as_slice() else {
        bail!("usage: planning_reference <model folder> <episodes.json> <out.safetensors>");
    };
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    let config = PlannerConfig::load(&root.join("sdk/configs/planner.toml"))?;
    let settings = Arm::Both.settings(&config.human2nav);
    let robot = root.join("robots/diablo/robot.toml");
    let mut rp = RobotPlanner::load(&robot, Path::new(model_dir), settings)?;
    let suite = EpisodeSuite::load(Path::new(episodes)).context("reading the episodes")?;
    let scenes = start_scenes(&suite.episodes, 20);
    let horizon = rp.planner.model().horizon();
    let std = rp.planner.model().source_std();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(0);
    let (mut bev, mut goal, mut velocity, mut x0, mut v0, mut x1) = (
        Vec::new(),
        Vec::new(),
        Vec::new(),
        Vec::new(),
        Vec::new(),
        Vec::new(),
    );
    for obs in &scenes {
        let (cond, _) = rp.planner.condition(obs);
        let source = draw_source(std, SAMPLES, horizon, &mut rng);
        let mut v = vec![0.0; source.len()];
        rp.planner.model().velocity(&source, 0.0, &cond, &mut v)?;
        v0.extend(v);
        let mut x = source.clone();
        integrate(rp.planner.model(), &mut x, &cond, settings.guidance.steps_n)?;
        bev.extend_from_slice(&cond.bev);
        goal.extend_from_slice(&cond.goal);
        velocity.extend_from_slice(&cond.velocity);
        x0.extend(source);
        x1.extend(x);
    }
    let w = scenes.len();
    let cells = rp.bev.cells;
    let settings_values = [
        ("settings.steps_n", settings.guidance.steps_n),
        ("settings.iterations_m", settings.guidance.iterations_m),
        ("settings.guided", settings.guided_samples),
    ]
    .map(|(name, v)| (name, (v as i64).to_le_bytes()));
    let bytes = |v: &[f64]| -> Vec<u8> { v.iter().flat_map(|a| a.to_le_bytes()).collect() };
    let bev_bytes: Vec<u8> = bev.iter().flat_map(|a| a.to_le_bytes()).collect();
    let f64s = [
        ("goal", bytes(&goal), vec![w, 2]),
        ("velocity", bytes(&velocity), vec![w, 2]),
        ("x0", bytes(&x0), vec![w, SAMPLES, horizon, 3]),
        ("v0", bytes(&v0), vec![w, SAMPLES, horizon, 3]),
        ("x1", bytes(&x1), vec![w, SAMPLES, horizon, 3]),
    ];
    let mut views = vec![(
        "bev".to_string(),
        TensorView::new(Dtype::F32, vec![w, 3, cells, cells], &bev_bytes)?,
    )];
    for (name, data, shape) in &f64s {
        views.push((
            name.to_string(),
            TensorView::new(Dtype::F64, shape.clone(), data)?,
        ));
    }
    for (name, data) in &settings_values {
        views.push((
            name.to_string(),
            TensorView::new(Dtype::I64, vec![1], data)?,
        ));
    }
    if let Some(dir) = Path::new(out).parent() {
        std::fs::create_dir_all(dir)?;
    }
    safetensors::serialize_to_file(views, None, Path::new(out))?;
    println!(
        "wrote {out}: {w} windows, {SAMPLES} samples each, native samples after {} steps",
        settings.guidance.steps_n
    );
    Ok(())
}
