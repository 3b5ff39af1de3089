//! Agreement of the native network with the libtorch one: forward values and vector-Jacobian
//! products to 1e-5 relative error (`‖a − b‖∞ / ‖b‖∞`) on random inputs, for the default
//! architecture, a small one with more blocks per level and Mish, and both with the crowd
//! pathway.

use super::*;
use crate::config::{Activation, NetConfig, Normalisation};
use crate::net::CROWD_FEATURES;
use tch::Device;

fn norm() -> Normalisation {
    Normalisation {
        position_scale: 1.7,
        velocity_std: [0.9, 0.6, 1.3],
        goal_scale: 5.0,
        speed_scale: 1.2,
        goal_conditioned: true,
        velocity_conditioned: true,
    }
}

fn small() -> NetConfig {
    NetConfig {
        horizon: 8,
        bev_cells: 8,
        down_dims: vec![8, 16, 16],
        n_groups: 4,
        bev_channels: [4, 8, 8],
        time_embed_dim: 8,
        bev_embed_dim: 8,
        goal_embed_dim: 8,
        kernel_size: 3,
        blocks_per_level: 2,
        mid_blocks: 2,
        activation: Activation::Mish,
        crowd: None,
    }
}

/// A model whose every parameter is drawn from [`noise`] at `seed` and the parameter's name,
/// not from torch's generator: that generator is global, and other tests of this crate seed
/// and draw from it in parallel, so weights drawn from it changed from run to run and an
/// agreement close to the tolerance passed or failed by chance.
///
/// Matrices and kernels are uniform in `±1/√fan_in` (torch's default bound), normalisation
/// scales `1 ± 0.2`, and every bias is drawn too, in `±0.3` (libtorch starts convolution biases
/// at zero; a trained model's are not zero, and a bias applied twice or not at all showed only
/// with the trained weights).
fn seeded_model(cfg: &NetConfig, seed: u64) -> CfmModel {
    let model = CfmModel::new(cfg, &norm(), Device::Cpu).expect("valid config");
    tch::no_grad(|| {
        for (name, mut v) in model.var_store().variables() {
            let shape = v.size();
            let numel: i64 = shape.iter().product();
            let key = human2nav_core::input::fnv1a64(name.as_bytes()) ^ seed;
            let u = noise(key, usize::try_from(numel).expect("tensor size"));
            let values: Vec<f64> = if name.ends_with(".bias") {
                u.iter().map(|x| 0.3 * x).collect()
            } else if shape.len() >= 2 {
                let bound = 1.0 / ((numel / shape[0]) as f64).sqrt();
                u.iter().map(|x| bound * x).collect()
            } else {
                u.iter().map(|x| 1.0 + 0.2 * x).collect()
            };
            let t = tch::Tensor::from_slice(&values)
                .to_kind(v.kind())
                .reshape(&shape);
            v.copy_(&t);
        }
    });
    model
}

/// A deterministic pseudo-random stream in [-1, 1).
fn noise(seed: u64, n: usize) -> Vec<f64> {
    let mut s = seed
        .wrapping_mul(6364136223846793005)
        .wrapping_add(1442695040888963407);
    (0..n)
        .map(|_| {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((s >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0
        })
        .collect()
}

fn condition(cfg: &NetConfig, seed: u64) -> FlowCondition {
    let n = cfg.bev_len();
    let bev = noise(seed, n)
        .into_iter()
        .enumerate()
        .map(|(i, v)| {
            if i < n / 3 {
                (v > 0.6) as u8 as f32
            } else {
                v as f32
            }
        })
        .collect();
    FlowCondition {
        bev,
        goal: [3.0, -1.0],
        velocity: [1.1, 0.2],
    }
}

/// Poses of `k` trajectories spread like source samples and half-integrated ones.
fn poses(k: usize, t: usize, seed: u64) -> Vec<f64> {
    noise(seed, k * t * 3)
        .into_iter()
        .enumerate()
        .map(|(i, v)| match i % 3 {
            2 => 3.0 * v,
            _ => 4.0 * v,
        })
        .collect()
}

fn rel_err(a: &[f64], b: &[f64]) -> f64 {
    let scale = b.iter().fold(0f64, |m, v| m.max(v.abs()));
    let diff = a.iter().zip(b).fold(0f64, |m, (x, y)| m.max((x - y).abs()));
    diff / scale.max(1e-12)
}

fn check_agreement(cfg: &NetConfig, seed: u64) {
    let torch = seeded_model(cfg, seed);
    let native = NativeCfm::from_model(&torch).expect("same architecture");
    let h = cfg.horizon;
    for (k, case) in [(1usize, 1u64), (4, 2), (16, 3)] {
        let cond = condition(cfg, case);
        let x = poses(k, h, case + 10);
        let cot: Vec<f64> = noise(case + 20, x.len());
        for t in [0.0, 0.4, 0.8] {
            let (mut a, mut b) = (vec![0.0; x.len()], vec![0.0; x.len()]);
            torch.velocity(&x, t, &cond, &mut a).expect("torch forward");
            native
                .velocity(&x, t, &cond, &mut b)
                .expect("native forward");
            let e = rel_err(&b, &a);
            assert!(e < 1e-5, "{cfg:?} K={k} t={t}: forward relative error {e}");
            let (mut va, mut vb) = (vec![0.0; x.len()], vec![0.0; x.len()]);
            torch
                .velocity_vjp(&x, t, &cond, &cot, &mut a, &mut va)
                .expect("torch vjp");
            native
                .velocity_vjp(&x, t, &cond, &cot, &mut b, &mut vb)
                .expect("native vjp");
            let e = rel_err(&vb, &va);
            assert!(e < 1e-5, "{cfg:?} K={k} t={t}: VJP relative error {e}");
            assert!(
                va.iter().any(|v| v.abs() > 1e-6),
                "the VJP is not trivially zero"
            );
        }
    }
}

#[test]
fn agrees_with_torch_on_the_shipped_architecture() {
    check_agreement(&NetConfig::default(), 7);
}

#[test]
fn agrees_with_torch_on_deeper_levels_more_blocks_and_mish() {
    check_agreement(&small(), 8);
}

/// A crowd pathway of `points` points and MLP width `width`.
fn crowd(points: usize, width: usize) -> Option<crate::config::CrowdConfig> {
    Some(crate::config::CrowdConfig {
        points,
        width,
        ..Default::default()
    })
}

#[test]
fn agrees_with_torch_with_the_crowd_pathway() {
    check_agreement(
        &NetConfig {
            crowd: crowd(40, 32),
            ..NetConfig::default()
        },
        9,
    );
    // Fewer points than occupied cells, and Mish.
    check_agreement(
        &NetConfig {
            crowd: crowd(6, 8),
            ..small()
        },
        10,
    );
}

#[test]
fn rows_are_independent_and_the_condition_cache_is_exact() {
    let cfg = small();
    let torch = seeded_model(&cfg, 3);
    let native = NativeCfm::from_model(&torch).expect("same architecture");
    let h = cfg.horizon;
    let x = poses(3, h, 5);
    let cond = condition(&cfg, 1);
    let mut all = vec![0.0; x.len()];
    native.velocity(&x, 0.5, &cond, &mut all).expect("forward");
    let n = 3 * h;
    let mut one = vec![0.0; n];
    native
        .velocity(&x[n..2 * n], 0.5, &cond, &mut one)
        .expect("forward");
    assert!(rel_err(&one, &all[n..2 * n]) < 1e-6);
    let other = condition(&cfg, 2);
    let mut o = vec![0.0; x.len()];
    native.velocity(&x, 0.5, &other, &mut o).expect("forward");
    assert!(
        rel_err(&o, &all) > 1e-4,
        "a new condition must not hit the cache"
    );
    let mut again = vec![0.0; x.len()];
    native
        .velocity(&x, 0.5, &cond, &mut again)
        .expect("forward");
    assert_eq!(all, again);
}

#[test]
fn load_reads_the_folder_and_rejects_mismatched_weights() {
    let dir = std::env::temp_dir().join(format!("h2n-native-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let cfg = small();
    let torch = seeded_model(&cfg, 4);
    torch.save(&dir).expect("save");
    let native = NativeCfm::load(&dir).expect("load");
    let cond = condition(&cfg, 9);
    let x = poses(2, cfg.horizon, 9);
    let (mut a, mut b) = (vec![0.0; x.len()], vec![0.0; x.len()]);
    torch.velocity(&x, 0.3, &cond, &mut a).expect("torch");
    native.velocity(&x, 0.3, &cond, &mut b).expect("native");
    assert!(rel_err(&b, &a) < 1e-5);

    // Shapes and names are checked as in the libtorch loader.
    let card_path = dir.join(CARD_FILE);
    let mut card = ModelCard::load(&card_path).expect("card");
    card.net.down_dims = vec![8, 24, 16];
    card.save(&card_path).expect("save card");
    let err = NativeCfm::load(&dir).expect_err("shape mismatch");
    assert!(matches!(err, CfmError::TensorShape { .. }), "{err}");
    card.net.down_dims = vec![8, 16, 16, 16];
    card.save(&card_path).expect("save card");
    let err = NativeCfm::load(&dir).expect_err("missing tensor");
    assert!(matches!(err, CfmError::MissingTensor { .. }), "{err}");
    card.net.down_dims = vec![8, 16, 16];
    card.weights_fnv64 = None;
    card.save(&card_path).expect("save card");
    let mut named = torch.named_tensors("");
    named.push((
        "extra.weight".into(),
        tch::Tensor::zeros([2], (tch::Kind::Float, Device::Cpu)),
    ));
    crate::model::write_safetensors(&dir.join(&torch.card().weights), &named).expect("write");
    let err = NativeCfm::load(&dir).expect_err("a tensor the architecture lacks");
    assert!(matches!(err, CfmError::UnexpectedTensor { .. }), "{err}");

    // A truncated weights file is corrupt, not a crash.
    torch.save(&dir).expect("save");
    let w = dir.join(&torch.card().weights);
    let bytes = std::fs::read(&w).expect("read");
    std::fs::write(&w, &bytes[..bytes.len() / 2]).expect("write");
    let err = NativeCfm::load(&dir).expect_err("truncated");
    assert!(matches!(err, CfmError::WeightsChecksum { .. }), "{err}");
    torch
        .card()
        .save(&card_path)
        .expect("a card without a checksum");
    let err = NativeCfm::load(&dir).expect_err("truncated");
    assert!(matches!(err, CfmError::Corrupt { .. }), "{err}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn shape_errors_are_reported() {
    let cfg = small();
    let torch = seeded_model(&cfg, 5);
    let native = NativeCfm::from_model(&torch).expect("same architecture");
    let cond = condition(&cfg, 1);
    let mut out = vec![0.0; 5];
    assert!(matches!(
        native.velocity(&[0.0; 5], 0.1, &cond, &mut out),
        Err(FlowError::Shape(_))
    ));
    let bad = FlowCondition {
        bev: vec![0.0; 10],
        ..cond
    };
    let x = poses(1, cfg.horizon, 1);
    let mut out = vec![0.0; x.len()];
    assert!(matches!(
        native.velocity(&x, 0.1, &bad, &mut out),
        Err(FlowError::Shape(_))
    ));
}

/// The shipped weights (trained: biases and scales far from their initial values) on both
/// backends, at planning conditions with people in the raster and without.
#[test]
fn agrees_with_torch_on_the_shipped_weights() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../models/human2nav-cfm");
    let torch = CfmModel::load(&dir, Device::Cpu).expect("shipped model");
    let native = NativeCfm::load(&dir).expect("shipped model, native");
    let cfg = &torch.card().net;
    let crowded = crate::perf::bench_condition(cfg.bev_cells);
    let empty = FlowCondition {
        bev: vec![0.0; crowded.bev.len()],
        ..crowded.clone()
    };
    for (case, cond) in [(1u64, &crowded), (2, &empty)] {
        let x = poses(16, cfg.horizon, case);
        let cot = noise(case + 20, x.len());
        for t in [0.0, 0.6] {
            let (mut a, mut b) = (vec![0.0; x.len()], vec![0.0; x.len()]);
            let (mut va, mut vb) = (vec![0.0; x.len()], vec![0.0; x.len()]);
            torch
                .velocity_vjp(&x, t, cond, &cot, &mut a, &mut va)
                .expect("torch");
            native
                .velocity_vjp(&x, t, cond, &cot, &mut b, &mut vb)
                .expect("native");
            let (e, ev) = (rel_err(&b, &a), rel_err(&vb, &va));
            assert!(
                e < 1e-5 && ev < 1e-5,
                "case {case} t={t}: forward {e}, VJP {ev}"
            );
        }
    }
}

/// [`NativeCfm::macs`] counts what each pass computed: a forward pass its convolutions and
/// the crowd pathway at the present points alone, a kept pass reused (the same input, or rows
/// of it) nothing, and a VJP on a kept pass the transposed products and the picked pairs.
#[test]
fn macs_count_the_products_each_pass_computed() {
    let cfg = NetConfig {
        crowd: crowd(40, 32),
        ..NetConfig::default()
    };
    let native = NativeCfm::from_model(&seeded_model(&cfg, 11)).expect("same architecture");
    let work = Complexity::of(&cfg);
    let (h, k) = (cfg.horizon as u64, 4u64);
    let (cond, x) = (condition(&cfg, 4), poses(4, cfg.horizon, 12));
    let mut out = vec![0.0; x.len()];
    assert_eq!(native.macs(), 0);
    native.velocity(&x, 0.4, &cond, &mut out).expect("forward");
    let present = native
        .lock()
        .expect("state")
        .encoded
        .points
        .chunks_exact(CROWD_FEATURES as usize)
        .filter(|p| p[4] > 0.5)
        .count() as u64;
    assert!(present > 0, "the condition places people");
    let forward = k * work.conv_macs + k * h * present * work.crowd_pair_macs;
    assert_eq!(native.macs(), forward);
    assert!(forward < k * work.unet_macs || present == 40);
    native.velocity(&x, 0.4, &cond, &mut out).expect("kept");
    let rows = 3 * cfg.horizon;
    native
        .velocity(&x[rows..3 * rows], 0.4, &cond, &mut out[..2 * rows])
        .expect("rows of a kept pass");
    assert_eq!(native.macs(), forward, "a kept pass costs nothing");
    let (cot, mut vjp) = (noise(13, x.len()), vec![0.0; x.len()]);
    native
        .velocity_vjp(&x, 0.4, &cond, &cot, &mut out, &mut vjp)
        .expect("vjp");
    let backward = native.macs() - forward;
    // Every waypoint's outputs pick between one point and as many as there are outputs; each
    // pick is the first layer again and both layers transposed (the pair's MLP and 32 · 5).
    let picks = |per_waypoint: u64| k * h * per_waypoint * (work.crowd_pair_macs + 32 * 5);
    let (least, most) = (picks(1), picks(present.min(32)));
    assert!(
        (k * work.conv_macs + least..=k * work.conv_macs + most).contains(&backward),
        "{backward} outside the transposed products plus {least}..={most}"
    );
}
