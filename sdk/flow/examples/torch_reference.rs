//! Inputs, output, loss and gradients of the network of a trained model on a batch of real
//! training tuples, for the agreement check of the PyTorch reference
//! (`sdk/flow/reference/torch_train_step.py --check`).
//!
//! The batch is built as the trainer builds one (mirror and path noise off, as shipped): tuples
//! of the cache's training split at fixed indices, flow times from the default time
//! distribution and unit-normal source twists from a seeded generator, the geodesic point and
//! target velocity of Eq. 3, trajectory features and normalised conditions through the crate's
//! own functions, with the model card's normalisation. Everything goes into one safetensors
//! file: the indices, twists and times (so the reference rebuilds the batch itself), the
//! network inputs, its output, the MSE loss and the gradient of every weight.
//!
//! `cargo run --release -p human2nav-flow --example torch_reference -- <model dir> <cache dir> <out.safetensors> [rows]`

use anyhow::Context;
use human2nav_core::se2::{Pose2, Twist2};
use human2nav_data::cache::TupleCache;
use human2nav_data::tuples::Split;
use human2nav_flow::CfmModel;
use human2nav_flow::cfm::{TimeDistribution, geodesic_point, target_velocity};
use human2nav_flow::model::{normalise_condition, trajectory_features};
use human2nav_flow::train::TrainingSample;
use rand::SeedableRng;
use rand_distr::{Distribution, StandardNormal};
use tch::{Kind, Tensor};

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let (Some(model_dir), Some(cache_dir), Some(out)) = (args.get(1), args.get(2), args.get(3))
    else {
        anyhow::bail!("usage: torch_reference <model dir> <cache dir> <out.safetensors> [rows]");
    };
    let rows: usize = args.get(4).map(|s| s.parse()).transpose()?.unwrap_or(32);
    tch::set_num_threads(1);
    let model = CfmModel::load(model_dir.as_ref(), tch::Device::Cpu)?;
    let cache = TupleCache::open(cache_dir.as_ref()).context("opening the cache")?;
    let compact = cache.load_compact(Split::Train)?;
    let spec = cache.manifest().bev;
    let net = &model.card().net;
    let norm = &model.card().normalisation;
    let (t_len, cells, bev_len) = (net.horizon, net.bev_cells, net.bev_len());

    // Rows spread over the split; seeded flow times and source twists, the first two times at
    // the ends of the distribution's range.
    let idx: Vec<usize> = (0..rows)
        .map(|r| (r * compact.len() / rows + 7) % compact.len())
        .collect();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(0);
    let sampler = TimeDistribution::default().sampler()?;
    let mut ts: Vec<f64> = (0..rows).map(|_| sampler.sample(&mut rng)).collect();
    ts[0] = 0.0;
    if rows > 1 {
        ts[1] = TimeDistribution::default().s;
    }
    let xi0: Vec<f64> = (0..rows * t_len * 3)
        .map(|_| StandardNormal.sample(&mut rng))
        .collect();

    let s = norm.position_scale;
    let mut x = vec![0f32; rows * 5 * t_len];
    let mut target = vec![0f32; rows * 3 * t_len];
    let mut bev = vec![0f32; rows * bev_len];
    let mut gv = vec![0f32; rows * 4];
    let mut poses = vec![0f64; t_len * 3];
    for (row, &i) in idx.iter().enumerate() {
        let ex = compact[i].to_tuple(&spec);
        let tgt = &mut target[row * 3 * t_len..(row + 1) * 3 * t_len];
        for j in 0..t_len {
            let p = ex.future_pose(j);
            let p1 = Pose2::new(p.x / s, p.y / s, p.theta);
            let k = (row * t_len + j) * 3;
            let x0 = Pose2::exp(Twist2::new(xi0[k], xi0[k + 1], xi0[k + 2]));
            let xi = target_velocity(x0, p1);
            let xt = geodesic_point(x0, xi, ts[row]);
            poses[3 * j..3 * j + 3].copy_from_slice(&xt.to_array());
            let xi = xi.to_array();
            for c in 0..3 {
                tgt[c * t_len + j] = (xi[c] / norm.velocity_std[c]) as f32;
            }
        }
        trajectory_features(&poses, &mut x[row * 5 * t_len..(row + 1) * 5 * t_len]);
        normalise_condition(
            norm,
            ex.bev(),
            ex.goal(),
            ex.velocity(),
            &mut bev[row * bev_len..(row + 1) * bev_len],
            &mut gv[row * 4..row * 4 + 4],
        );
    }
    let (b, t, c) = (rows as i64, t_len as i64, cells as i64);
    let x = Tensor::from_slice(&x).view([b, 5, t]);
    let t32: Vec<f32> = ts.iter().map(|&v| v as f32).collect();
    let tt = Tensor::from_slice(&t32);
    let bev = Tensor::from_slice(&bev).view([b, 3, c, c]);
    let gv = Tensor::from_slice(&gv).view([b, 4]);
    let target = Tensor::from_slice(&target).view([b, 3, t]);

    // The trainer's loss: condition encoding, FiLM, U-Net, MSE; then its gradients.
    let cond = model.net().encode_condition(&bev, &gv);
    let pred = model.net().forward(&x, &tt, &cond);
    let loss = pred.mse_loss(&target, tch::Reduction::Mean);
    loss.backward();

    let idx64: Vec<i64> = idx.iter().map(|&i| i as i64).collect();
    let mut named: Vec<(String, Tensor)> = vec![
        ("idx".into(), Tensor::from_slice(&idx64)),
        ("t64".into(), Tensor::from_slice(&ts)),
        ("xi0".into(), Tensor::from_slice(&xi0).view([b, t, 3])),
        ("x".into(), x),
        ("t".into(), tt),
        ("bev".into(), bev),
        ("goal_vel".into(), gv),
        ("target".into(), target),
        ("cond".into(), cond.detach()),
        ("pred".into(), pred.detach()),
        ("loss".into(), loss.detach().view([1])),
    ];
    let mut vars: Vec<(String, Tensor)> = model.var_store().variables().into_iter().collect();
    vars.sort_by(|a, b| a.0.cmp(&b.0));
    for (name, v) in vars {
        named.push((format!("grad.{name}"), v.grad().to_kind(Kind::Float)));
    }
    let named: Vec<(String, Tensor)> = named
        .into_iter()
        .map(|(n, t)| (n, t.contiguous()))
        .collect();
    if let Some(dir) = std::path::Path::new(out).parent() {
        std::fs::create_dir_all(dir)?;
    }
    Tensor::write_safetensors(&named, out)?;
    println!(
        "wrote {out}: {rows} rows of the training split, loss {:.6}",
        loss.double_value(&[])
    );
    Ok(())
}
