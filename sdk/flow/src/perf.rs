//! Latency of a model's trait calls on this machine (what the planner pays per step).

use human2nav_core::flow::{FlowCondition, FlowError};
use human2nav_core::{AgentState, Observation, Pose2, Twist2};
use human2nav_data::Episode;
use std::time::Instant;
#[cfg(feature = "torch")]
use {
    crate::{card::PerformanceInfo, cfm::sample_source, model::CfmModel},
    human2nav_core::flow::FlowModel,
    rand::SeedableRng,
    rand_chacha::ChaCha8Rng,
};

/// Median wall time of `f` over `n` runs after `warm` warm-up runs, milliseconds.
pub fn median_ms(
    warm: usize,
    n: usize,
    mut f: impl FnMut() -> Result<(), FlowError>,
) -> Result<f64, FlowError> {
    for _ in 0..warm {
        f()?;
    }
    let mut t = Vec::with_capacity(n.max(1));
    for _ in 0..n.max(1) {
        let s = Instant::now();
        f()?;
        t.push(s.elapsed().as_secs_f64() * 1e3);
    }
    t.sort_by(f64::total_cmp);
    Ok(t[t.len() / 2])
}

/// A planning scene for benchmarks: the robot at an episode's start facing its goal, at rest,
/// with the pedestrians present at t = 0 within 10 m (velocities from their first step).
pub fn episode_start(ep: &Episode) -> Observation {
    let s = ep.start;
    let theta = (ep.goal[1] - s.y).atan2(ep.goal[0] - s.x);
    let agents = ep
        .agents
        .iter()
        .filter(|a| a.start_step == 0 && a.positions.len() >= 2)
        .map(|a| {
            let (p, q) = (a.positions[0], a.positions[1]);
            AgentState {
                id: a.id,
                position: p,
                velocity: [(q[0] - p[0]) / ep.dt, (q[1] - p[1]) / ep.dt],
                radius: a.radius,
                history: Vec::new(),
            }
        })
        .filter(|a| (a.position[0] - s.x).hypot(a.position[1] - s.y) <= 10.0)
        .collect();
    Observation {
        time: 0.0,
        ego: Pose2::new(s.x, s.y, theta),
        ego_velocity: Twist2::ZERO,
        goal: ep.goal,
        agents,
        ..Default::default()
    }
}

/// [`episode_start`] of at most `n` episodes spread evenly over `episodes`.
pub fn start_scenes(episodes: &[Episode], n: usize) -> Vec<Observation> {
    let step = (episodes.len() / n.max(1)).max(1);
    episodes
        .iter()
        .step_by(step)
        .take(n)
        .map(episode_start)
        .collect()
}

/// A deterministic planning condition for benchmarks: a raster with a few occupied cells.
pub fn bench_condition(cells: usize) -> FlowCondition {
    let mut bev = vec![0f32; 3 * cells * cells];
    let plane = cells * cells;
    for i in 0..plane {
        if i % 37 < 3 {
            bev[i] = 1.0;
            bev[plane + i] = -1.0;
            bev[2 * plane + i] = 0.3;
        }
    }
    FlowCondition {
        bev,
        goal: [4.0, 0.5],
        velocity: [1.2, 0.0],
    }
}

#[cfg(feature = "torch")]
/// Median latency of `velocity` and `velocity_vjp` at batch 1 and 16 (condition cached, as in
/// a planning call) and of one condition encoding, with the current torch thread count
/// (`threads` is recorded, not set).
pub fn measure_latency(model: &CfmModel, threads: usize) -> Result<PerformanceInfo, FlowError> {
    let t = model.horizon();
    let cond = bench_condition(model.card().net.bev_cells);
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    let mut lat = [0.0; 4];
    for (i, &k) in [1usize, 16].iter().enumerate() {
        let x = sample_source(k, t, model.source_std(), &mut rng);
        let cot = vec![0.1; x.len()];
        let mut out = vec![0.0; x.len()];
        let mut vjp = vec![0.0; x.len()];
        lat[i] = median_ms(5, 50, || model.velocity(&x, 0.5, &cond, &mut out))?;
        lat[2 + i] = median_ms(5, 50, || {
            model.velocity_vjp(&x, 0.5, &cond, &cot, &mut out, &mut vjp)
        })?;
    }
    let encode = median_ms(3, 30, || {
        model.invalidate_cache();
        model.condition_embedding(&cond).map(|_| ())
    })?;
    Ok(PerformanceInfo {
        machine: format!(
            "{} logical CPUs, {}",
            std::thread::available_parallelism()
                .map(|n| n.get())
                .unwrap_or(0),
            std::env::consts::ARCH
        ),
        threads,
        forward_b1_ms: lat[0],
        forward_b16_ms: lat[1],
        vjp_b1_ms: lat[2],
        vjp_b16_ms: lat[3],
        encode_condition_ms: encode,
    })
}
