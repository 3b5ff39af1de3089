//! Tests of [`CfmModel`]: tensor features against the Rust ones, the VJP against finite
//! differences, batching and its cache, shape errors, saving and loading.

use super::*;
use crate::config::CrowdConfig;
use crate::model::trajectory_features;
use approx::assert_relative_eq;

fn small() -> NetConfig {
    NetConfig {
        horizon: 8,
        bev_cells: 8,
        down_dims: vec![8, 16],
        n_groups: 4,
        bev_channels: [4, 8, 8],
        time_embed_dim: 8,
        bev_embed_dim: 8,
        goal_embed_dim: 8,
        kernel_size: 3,
        blocks_per_level: 2,
        mid_blocks: 2,
        activation: crate::config::Activation::Mish,
        crowd: None,
    }
}

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

fn condition(cfg: &NetConfig, seed: u32) -> FlowCondition {
    let n = cfg.bev_len();
    let bev = (0..n)
        .map(|i| {
            ((((i as u32) ^ seed.wrapping_mul(7919)).wrapping_mul(2654435761) >> 16) % 7) as f32
                / 7.0
        })
        .collect();
    FlowCondition {
        bev,
        goal: [3.0, -1.0],
        velocity: [1.1, 0.2],
    }
}

fn poses(k: usize, t: usize) -> Vec<f64> {
    (0..k * t * 3)
        .map(|i| match i % 3 {
            0 => 0.1 * (i / 3) as f64 % 3.0,
            1 => 0.3 * ((i as f64) * 0.37).sin(),
            _ => 2.9 * ((i as f64) * 0.11).cos(),
        })
        .collect()
}

#[test]
fn tensor_features_match_rust_features() {
    tch::manual_seed(0);
    let cfg = small();
    let model = CfmModel::new(&cfg, &norm(), Device::Cpu).unwrap();
    let x = poses(2, cfg.horizon);
    let (f, k) = model.feature_tensor(&x).unwrap();
    assert_eq!(k, 2);
    let f = f.contiguous();
    let mut rust = vec![0f32; 5 * cfg.horizon];
    let s = norm().position_scale;
    for k in 0..2 {
        let mut p: Vec<f64> = x[k * cfg.horizon * 3..(k + 1) * cfg.horizon * 3].to_vec();
        for c in p.chunks_exact_mut(3) {
            c[0] /= s;
            c[1] /= s;
        }
        trajectory_features(&p, &mut rust);
        let mut got = vec![0f32; 5 * cfg.horizon];
        f.get(k as i64).copy_data(&mut got, 5 * cfg.horizon);
        for (a, b) in got.iter().zip(&rust) {
            assert_relative_eq!(*a, *b, epsilon = 1e-6);
        }
    }
}

/// The autograd VJP equals central finite differences of `cotangent · f(x)` (float64),
/// with and without the crowd pathway.
#[test]
fn vjp_matches_finite_differences() {
    let crowd = NetConfig {
        crowd: Some(CrowdConfig {
            points: 6,
            width: 8,
            ..CrowdConfig::default()
        }),
        ..small()
    };
    for cfg in [small(), crowd] {
        vjp_matches_finite_differences_for(&cfg);
    }
}

fn vjp_matches_finite_differences_for(cfg: &NetConfig) {
    tch::manual_seed(1);
    let cfg = cfg.clone();
    let mut model = CfmModel::new(&cfg, &norm(), Device::Cpu).unwrap();
    model.to_double();
    let cond = condition(&cfg, 3);
    let k = 2;
    let x = poses(k, cfg.horizon);
    let cot: Vec<f64> = (0..x.len())
        .map(|i| ((i * 7 % 11) as f64 - 5.0) / 5.0)
        .collect();
    let mut out = vec![0.0; x.len()];
    let mut vjp = vec![0.0; x.len()];
    model
        .velocity_vjp(&x, 0.37, &cond, &cot, &mut out, &mut vjp)
        .unwrap();
    let mut out2 = vec![0.0; x.len()];
    model.velocity(&x, 0.37, &cond, &mut out2).unwrap();
    for (a, b) in out.iter().zip(&out2) {
        assert_relative_eq!(*a, *b, epsilon = 1e-12);
    }
    let f = |x: &[f64]| -> f64 {
        let mut o = vec![0.0; x.len()];
        model.velocity(x, 0.37, &cond, &mut o).unwrap();
        o.iter().zip(&cot).map(|(a, b)| a * b).sum()
    };
    let h = 1e-6;
    let mut max_err = 0f64;
    for i in 0..x.len() {
        let mut xp = x.clone();
        let mut xm = x.clone();
        xp[i] += h;
        xm[i] -= h;
        let fd = (f(&xp) - f(&xm)) / (2.0 * h);
        max_err = max_err.max((fd - vjp[i]).abs() / (1.0 + vjp[i].abs()));
    }
    assert!(max_err < 1e-6, "max relative VJP error {max_err}");
    // The VJP is not trivially zero.
    assert!(vjp.iter().map(|v| v.abs()).sum::<f64>() > 1e-3);
}

#[test]
fn batch_rows_are_independent_and_cache_is_exact() {
    tch::manual_seed(2);
    let cfg = small();
    let model = CfmModel::new(&cfg, &norm(), Device::Cpu).unwrap();
    let cond = condition(&cfg, 1);
    let x = poses(3, cfg.horizon);
    let mut out = vec![0.0; x.len()];
    model.velocity(&x, 0.5, &cond, &mut out).unwrap();
    let n = cfg.horizon * 3;
    let mut single = vec![0.0; n];
    model
        .velocity(&x[n..2 * n], 0.5, &cond, &mut single)
        .unwrap();
    for (a, b) in single.iter().zip(&out[n..2 * n]) {
        assert_relative_eq!(*a, *b, epsilon = 1e-5, max_relative = 1e-5);
    }
    // A different condition must not hit the cache.
    let other = condition(&cfg, 99);
    let mut out_other = vec![0.0; x.len()];
    model.velocity(&x, 0.5, &other, &mut out_other).unwrap();
    assert!(
        out.iter()
            .zip(&out_other)
            .any(|(a, b)| (a - b).abs() > 1e-6)
    );
    // And going back reproduces the first result.
    let mut again = vec![0.0; x.len()];
    model.velocity(&x, 0.5, &cond, &mut again).unwrap();
    assert_eq!(out, again);
}

#[test]
fn shape_errors_are_reported() {
    let cfg = small();
    let model = CfmModel::new(&cfg, &norm(), Device::Cpu).unwrap();
    let cond = condition(&cfg, 1);
    let mut out = vec![0.0; 5];
    assert!(matches!(
        model.velocity(&[0.0; 5], 0.1, &cond, &mut out),
        Err(FlowError::Shape(_))
    ));
    let bad = FlowCondition {
        bev: vec![0.0; 10],
        ..cond
    };
    let x = poses(1, cfg.horizon);
    let mut out = vec![0.0; x.len()];
    assert!(matches!(
        model.velocity(&x, 0.1, &bad, &mut out),
        Err(FlowError::Shape(_))
    ));
}

#[test]
fn save_load_round_trip_and_validation() {
    tch::manual_seed(3);
    let dir = std::env::temp_dir().join(format!("h2n-flow-ckpt-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let cfg = small();
    let model = CfmModel::new(&cfg, &norm(), Device::Cpu).unwrap();
    model.save(&dir).unwrap();
    let loaded = CfmModel::load(&dir, Device::Cpu).unwrap();
    // The written card records the weights' checksum; otherwise it is the model's card.
    let weights = std::fs::read(dir.join(WEIGHTS_FILE)).unwrap();
    let mut expected = model.card().clone();
    expected.weights_fnv64 = Some(ModelCard::checksum(&weights));
    assert_eq!(loaded.card(), &expected);
    let cond = condition(&cfg, 5);
    let x = poses(2, cfg.horizon);
    let (mut a, mut b) = (vec![0.0; x.len()], vec![0.0; x.len()]);
    model.velocity(&x, 0.2, &cond, &mut a).unwrap();
    loaded.velocity(&x, 0.2, &cond, &mut b).unwrap();
    assert_eq!(a, b);

    // The weights file records the raster it was trained on; a card naming another one is
    // refused by both backends, even with its two raster fields in agreement (the
    // convolutional encoder's shapes do not show the raster) and the right checksum.
    let (_, header) = safetensors::SafeTensors::read_metadata(&weights).unwrap();
    let recorded = header.metadata().clone().unwrap();
    assert_eq!(recorded.get("bev_cells"), Some(&cfg.bev_cells.to_string()));
    assert_eq!(recorded.get("horizon"), Some(&cfg.horizon.to_string()));
    let mut other = expected.clone();
    other.net.bev_cells = 16;
    if let Some(bev) = other.bev.as_mut() {
        bev.cells = 16;
    }
    other.save(&dir.join(CARD_FILE)).unwrap();
    for load in [
        |d: &Path| CfmModel::load(d, Device::Cpu).map(|_| ()),
        |d: &Path| crate::NativeCfm::load(d).map(|_| ()),
    ] {
        let err = load(&dir).unwrap_err();
        assert!(matches!(err, CfmError::WeightsTrainedOn { .. }), "{err}");
        let msg = err.to_string();
        assert!(
            msg.contains("bev_cells = 8") && msg.contains("says 16"),
            "{msg}"
        );
    }
    expected.save(&dir.join(CARD_FILE)).unwrap();

    // A card whose architecture differs from the weights: shape mismatch.
    let mut card = ModelCard::load(&dir.join(CARD_FILE)).unwrap();
    card.net.down_dims = vec![8, 24];
    card.save(&dir.join(CARD_FILE)).unwrap();
    let err = CfmModel::load(&dir, Device::Cpu).unwrap_err();
    assert!(matches!(err, CfmError::TensorShape { .. }), "{err}");

    // A card with an extra level: missing tensors.
    card.net.down_dims = vec![8, 16, 16];
    card.save(&dir.join(CARD_FILE)).unwrap();
    let err = CfmModel::load(&dir, Device::Cpu).unwrap_err();
    assert!(matches!(err, CfmError::MissingTensor { .. }), "{err}");

    // Weights with a tensor the architecture lacks: unexpected.
    card.net.down_dims = vec![8, 16];
    card.save(&dir.join(CARD_FILE)).unwrap();
    let mut named = model.named_tensors("");
    named.push((
        "extra.weight".into(),
        Tensor::zeros([2], (Kind::Float, Device::Cpu)),
    ));
    write_safetensors(&dir.join(WEIGHTS_FILE), &named).unwrap();
    // Other weights than the card was written with: refused by the checksum, naming both.
    for load in [
        |d: &Path| CfmModel::load(d, Device::Cpu).map(|_| ()),
        |d: &Path| crate::NativeCfm::load(d).map(|_| ()),
    ] {
        let err = load(&dir).unwrap_err();
        assert!(matches!(err, CfmError::WeightsChecksum { .. }), "{err}");
        assert!(err.to_string().contains("weights_fnv64"), "{err}");
    }
    card.weights_fnv64 = None;
    card.save(&dir.join(CARD_FILE)).unwrap();
    let err = CfmModel::load(&dir, Device::Cpu).unwrap_err();
    assert!(matches!(err, CfmError::UnexpectedTensor { .. }), "{err}");

    // A truncated file: refused by the checksum, and corrupt when the card has none.
    model.save(&dir).unwrap();
    let bytes = std::fs::read(dir.join(WEIGHTS_FILE)).unwrap();
    std::fs::write(dir.join(WEIGHTS_FILE), &bytes[..bytes.len() / 2]).unwrap();
    let err = CfmModel::load(&dir, Device::Cpu).unwrap_err();
    assert!(matches!(err, CfmError::WeightsChecksum { .. }), "{err}");
    model.card().save(&dir.join(CARD_FILE)).unwrap();
    let err = CfmModel::load(&dir, Device::Cpu).unwrap_err();
    assert!(matches!(err, CfmError::Corrupt { .. }), "{err}");

    // An unknown card field: a TOML error naming the file.
    model.save(&dir).unwrap();
    let text = std::fs::read_to_string(dir.join(CARD_FILE)).unwrap();
    std::fs::write(dir.join(CARD_FILE), format!("bogus = 1\n{text}")).unwrap();
    let err = CfmModel::load(&dir, Device::Cpu).unwrap_err();
    assert!(matches!(err, CfmError::Toml { .. }), "{err}");

    // A [bev] table that disagrees with the network's input size.
    model.save(&dir).unwrap();
    let mut card = ModelCard::load(&dir.join(CARD_FILE)).unwrap();
    card.bev = Some(human2nav_core::bev::BevSpec {
        cells: cfg.bev_cells + 2,
        resolution: 0.3,
    });
    card.save(&dir.join(CARD_FILE)).unwrap();
    let err = CfmModel::load(&dir, Device::Cpu).unwrap_err().to_string();
    assert!(
        err.contains("[bev] cells") && err.contains("net.bev_cells"),
        "{err}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// The one-pass batch (`velocity_batch` on a GPU) runs all groups together, each row under its
/// group's condition, time and crowd points: the same values as one call per group, to float
/// rounding; on the CPU `velocity_batch` is one call per group.
#[test]
fn a_batch_of_conditions_agrees_with_calls_one_by_one() {
    tch::manual_seed(4);
    let cfg = NetConfig {
        crowd: Some(CrowdConfig::default()),
        ..small()
    };
    let model = CfmModel::new(&cfg, &norm(), Device::Cpu).unwrap();
    let conds: Vec<FlowCondition> = (0..3).map(|s| condition(&cfg, 10 + s)).collect();
    let xs: Vec<Vec<f64>> = [2, 1, 3].iter().map(|&k| poses(k, cfg.horizon)).collect();
    let queries: Vec<FlowQuery<'_>> = [(0, 0.0), (1, 0.4), (2, 0.8)]
        .iter()
        .zip(&xs)
        .map(|(&(c, t), x)| FlowQuery {
            x,
            t,
            cond: &conds[c],
        })
        .collect();
    let mut batched = vec![0.0; xs.iter().map(Vec::len).sum()];
    let mut each = batched.clone();
    model.velocity_batch(&queries, &mut each).unwrap();
    // Twice: the second pass reuses the encodings.
    for _ in 0..2 {
        model.batched_velocity(&queries, &mut batched).unwrap();
    }
    let mut at = 0;
    for q in &queries {
        let mut alone = vec![0.0; q.x.len()];
        model.velocity(q.x, q.t, q.cond, &mut alone).unwrap();
        assert_eq!(alone, each[at..at + q.x.len()]);
        for (a, b) in alone.iter().zip(&batched[at..]) {
            assert_relative_eq!(*a, *b, epsilon = 1e-5, max_relative = 1e-5);
        }
        at += q.x.len();
    }
}

/// Models loaded from one weights file report one network; a fresh model, or one whose
/// variables were handed out, reports none.
#[test]
fn loaded_models_of_one_file_share_a_network_id() {
    tch::manual_seed(5);
    let dir = std::env::temp_dir().join(format!("h2n-flow-netid-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let model = CfmModel::new(&small(), &norm(), Device::Cpu).unwrap();
    assert_eq!(model.network_id(), None);
    model.save(&dir).unwrap();
    let (a, b) = (
        CfmModel::load(&dir, Device::Cpu).unwrap(),
        CfmModel::load(&dir, Device::Cpu).unwrap(),
    );
    assert!(a.network_id().is_some());
    assert_eq!(a.network_id(), b.network_id());
    let _ = a.var_store();
    assert_eq!(a.network_id(), None);
    assert!(b.network_id().is_some());
    let _ = std::fs::remove_dir_all(&dir);
}
