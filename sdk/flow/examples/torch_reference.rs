//! Inputs, output, loss and gradients of the network of a trained model on a batch of real
//! training tuples, for the agreement check of the PyTorch reference
//! (`sdk/flow/reference/torch_train_step.py --check`).
//!
//! The batch is built by the trainer's own recipe (`train::batch_from_draws`; mirror and path
//! noise off, as shipped) with the model card's normalisation: tuples of the cache's training
//! split at fixed indices, flow times from the default time distribution and unit-normal
//! source twists from a seeded generator. Everything goes into one safetensors
//! file: the indices, twists and times (so the reference rebuilds the batch itself), the
//! network inputs, its output, the MSE loss and the gradient of every weight.
//!
//! `cargo run --release -p human2nav-flow --example torch_reference -- <model dir> <cache dir> <out.safetensors> [rows]`

use anyhow::Context;
use human2nav_core::se2::Twist2;
use human2nav_data::cache::TupleCache;
use human2nav_data::tuples::Split;
use human2nav_flow::CfmModel;
use human2nav_flow::cfm::TimeDistribution;
use human2nav_flow::train::{Batch, BatchDraws, batch_from_draws};
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
    anyhow::ensure!(
        rows > 0 && !compact.is_empty(),
        "need at least one row and a non-empty training split (rows = {rows}, {} tuples)",
        compact.len()
    );
    let spec = cache.manifest().bev;
    let net = &model.card().net;
    let norm = &model.card().normalisation;
    let t_len = net.horizon;

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

    // The trainer's own batch recipe on these draws (no mirroring, no path noise, as shipped).
    let tuples: Vec<_> = idx.iter().map(|&i| compact[i].to_tuple(&spec)).collect();
    let rows_idx: Vec<usize> = (0..rows).collect();
    let draws = BatchDraws {
        flip: vec![false; rows],
        t: ts.clone(),
        source: xi0
            .chunks_exact(3)
            .map(|c| Twist2::new(c[0], c[1], c[2]))
            .collect(),
        path: Vec::new(),
        counterfactual: Vec::new(),
    };
    let Batch {
        x,
        t: tt,
        bev,
        goal_vel: gv,
        points,
        target,
        ..
    } = batch_from_draws(
        &tuples,
        &rows_idx,
        net,
        norm,
        &draws,
        None,
        None,
        tch::Device::Cpu,
    );
    let (b, t) = (rows as i64, t_len as i64);

    // The trainer's loss: condition encoding, FiLM, U-Net, MSE; then its gradients.
    let cond = model.net().encode_condition(&bev, &gv);
    let pred = model.net().forward(&x, &tt, &cond, &points);
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
