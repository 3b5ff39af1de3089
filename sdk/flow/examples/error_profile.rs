//! Displacement error of the best of K sampled futures along the horizon, for a trained model
//! on held-out tuples, at several Euler step counts N.
//!
//! `cargo run --release -p human2nav-flow --example error_profile -- <model dir> <cache dir> [windows]`

use anyhow::Context;
use human2nav_core::flow::{FlowCondition, FlowModel};
use human2nav_data::cache::TupleCache;
use human2nav_data::tuples::Split;
use human2nav_flow::CfmModel;
use human2nav_flow::eval::{displacement_errors, subsample};
use human2nav_flow::sampler::sample;
use rand::SeedableRng;

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let (Some(model_dir), Some(cache_dir)) = (args.get(1), args.get(2)) else {
        anyhow::bail!("usage: error_profile <model dir> <cache dir> [windows]");
    };
    let n_windows: usize = args.get(3).map(|s| s.parse()).transpose()?.unwrap_or(200);
    tch::set_num_threads(1);
    let model = CfmModel::load(model_dir.as_ref(), tch::Device::Cpu)?;
    let cache = TupleCache::open(cache_dir.as_ref()).context("opening the cache")?;
    let mut test = cache.load_compact(Split::Test)?;
    subsample(&mut test, n_windows, 0);
    let spec = cache.manifest().bev;
    let t = model.horizon();
    let k = 20;
    let marks = [0usize, 3, 7, 15, 31];
    for steps in [5usize, 10, 20] {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(0);
        let mut at = [0.0f64; 5];
        let (mut min_ade, mut min_fde) = (0.0, 0.0);
        for c in &test {
            let d = c.to_tuple(&spec);
            let cond = FlowCondition {
                bev: d.bev,
                goal: [d.goal[0] as f64, d.goal[1] as f64],
                velocity: [d.velocity[0] as f64, d.velocity[1] as f64],
            };
            let truth: Vec<human2nav_core::Pose2> = d
                .future
                .iter()
                .map(|p| human2nav_core::Pose2::new(p[0] as f64, p[1] as f64, p[2] as f64))
                .collect();
            let x = sample(&model, &cond, k, steps, &mut rng)?;
            let mut best = (f64::INFINITY, 0usize);
            let mut best_fde = f64::INFINITY;
            for (i, traj) in x.chunks_exact(3 * t).enumerate() {
                let (ade, fde) = displacement_errors(traj, &truth);
                if ade < best.0 {
                    best = (ade, i);
                }
                best_fde = best_fde.min(fde);
            }
            let traj = &x[best.1 * 3 * t..(best.1 + 1) * 3 * t];
            for (m, &j) in marks.iter().enumerate() {
                at[m] += (traj[3 * j] - truth[j].x).hypot(traj[3 * j + 1] - truth[j].y);
            }
            min_ade += best.0;
            min_fde += best_fde;
        }
        let n = test.len() as f64;
        println!(
            "N = {steps:2}: min ADE {:.3} m, min FDE {:.3} m; error of the min-ADE sample at \
             0.1/0.4/0.8/1.6/3.2 s: {:.3} {:.3} {:.3} {:.3} {:.3} m ({} windows, K = {k})",
            min_ade / n,
            min_fde / n,
            at[0] / n,
            at[1] / n,
            at[2] / n,
            at[3] / n,
            at[4] / n,
            test.len()
        );
    }
    Ok(())
}
