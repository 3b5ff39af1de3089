//! Tests of the trainer: the learning-rate schedule, normalisation, path noise, counterfactual
//! walkers, checkpoints and resumed runs.

use super::*;
use approx::assert_relative_eq;

/// libtorch's generator is global and `Trainer::new` seeds it: tests that train must not
/// interleave, or their weights depend on each other's draws.
static TRAINING: std::sync::Mutex<()> = std::sync::Mutex::new(());

fn tiny_net() -> NetConfig {
    NetConfig {
        horizon: 8,
        bev_cells: 8,
        down_dims: vec![8, 16],
        n_groups: 4,
        bev_channels: [4, 8, 8],
        time_embed_dim: 8,
        bev_embed_dim: 8,
        goal_embed_dim: 8,
        ..NetConfig::default()
    }
}

fn data(n: usize) -> Vec<Example> {
    (0..n)
        .map(|i| {
            let turn = 0.05 * (i as f64 - n as f64 / 2.0);
            let mut p = Pose2::IDENTITY;
            let future = (0..8)
                .map(|_| {
                    p = p.euler_step(Twist2::new(1.2, 0.0, turn * 10.0), 0.1);
                    p
                })
                .collect();
            let mut bev = vec![0.0; 3 * 64];
            bev[i % 64] = 1.0;
            Example {
                bev,
                goal: [5.0, 10.0 * turn],
                velocity: [1.2, 0.0],
                future,
            }
        })
        .collect()
}

#[test]
fn learning_rate_schedule() {
    let o = TrainOptions {
        steps: 1000,
        warmup_steps: 100,
        lr: 1e-3,
        lr_min: 1e-5,
        ..TrainOptions::default()
    };
    assert_relative_eq!(o.lr_at(0), 1e-5, epsilon = 1e-12);
    assert_relative_eq!(o.lr_at(99), 1e-3, epsilon = 1e-12);
    assert_relative_eq!(o.lr_at(100), 1e-3, epsilon = 1e-12);
    // Half-way through the cosine: the mean of lr and lr_min.
    assert_relative_eq!(o.lr_at(550), 0.5 * (1e-3 + 1e-5), epsilon = 1e-12);
    assert_relative_eq!(o.lr_at(1000), 1e-5, epsilon = 1e-12);
    assert_relative_eq!(o.lr_at(5000), 1e-5, epsilon = 1e-12);
}

#[test]
fn normalisation_estimate_matches_closed_forms() {
    let d = data(10);
    let n = Normalisation::estimate(&d, 0).unwrap();
    assert_relative_eq!(n.speed_scale, 1.2, epsilon = 1e-12);
    let g2: f64 = d
        .iter()
        .map(|e| e.goal[0].powi(2) + e.goal[1].powi(2))
        .sum::<f64>()
        / 10.0;
    assert_relative_eq!(n.goal_scale, g2.sqrt(), epsilon = 1e-12);
    assert!(Normalisation::estimate::<Example>(&[], 0).is_err());
}

/// Three steps, a checkpoint, a resume and three more steps give the same weights as six
/// uninterrupted steps (batch order and noise derive from (seed, step); AdamW moments and
/// EMA are checkpointed).
/// Eq. 3's path noise moves the network's input `x_t` and nothing else; `σ = 0` draws no
/// noise, so batches are those of the deterministic path.
#[test]
fn path_noise_moves_the_input_not_the_target() {
    let d = data(6);
    let net = tiny_net();
    let norm = Normalisation::estimate(&d, 0).unwrap();
    let time = TimeDistribution::default().sampler().unwrap();
    let idx = [0, 3, 5];
    let batch = |sigma: f64| {
        let mut rng = ChaCha8Rng::seed_from_u64(4);
        let mut path = PathNoise::new(sigma, 4, 0);
        build_batch(
            &d,
            &idx,
            &net,
            &norm,
            &time,
            false,
            path.as_mut(),
            None,
            None,
            &mut rng,
            Device::Cpu,
        )
    };
    let same = |a: &Tensor, b: &Tensor| (a - b).abs().max().double_value(&[]) == 0.0;
    let (plain, again, noisy) = (batch(0.0), batch(0.0), batch(0.2));
    assert!(same(&plain.x, &again.x));
    assert!(same(&plain.target, &noisy.target));
    assert!(same(&plain.t, &noisy.t));
    assert!(!same(&plain.x, &noisy.x));
    for bad in [-0.1, 1.5, f64::NAN] {
        let opts = TrainOptions {
            path_sigma: bad,
            ..TrainOptions::default()
        };
        assert!(opts.validate().is_err(), "{bad}");
    }
}

/// A checkpoint is a set: a missing or altered file is an error naming it, never a silent
/// restart; a save interrupted between its renames resumes from the previous set.
#[test]
fn incomplete_checkpoints_are_detected() {
    let _serial = TRAINING.lock().unwrap_or_else(|e| e.into_inner());
    let d = data(8);
    let net = tiny_net();
    let norm = Normalisation::estimate(&d, 0).unwrap();
    let opts = TrainOptions {
        batch_size: 4,
        steps: 4,
        warmup_steps: 1,
        ..TrainOptions::default()
    };
    let root = std::env::temp_dir().join(format!("h2n-flow-ckpt-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&root);
    let ckpt = root.join("checkpoint");
    let mut tr = Trainer::new(&net, &norm, &opts, &d, &d[..2], Device::Cpu).unwrap();
    tr.train_step().unwrap();
    tr.save_checkpoint(&ckpt).unwrap();
    tr.train_step().unwrap();
    tr.save_checkpoint(&ckpt).unwrap();
    assert!(
        !fileset::sibling(&ckpt, "old").exists() && !fileset::sibling(&ckpt, "partial").exists()
    );
    let err = |dir: &Path| find_checkpoint(dir).unwrap_err().to_string();

    // A truncated tensor file.
    let tensors = ckpt.join("state.safetensors");
    let bytes = std::fs::read(&tensors).unwrap();
    std::fs::write(&tensors, &bytes[..bytes.len() / 2]).unwrap();
    let e = err(&ckpt);
    assert!(
        e.contains("state.safetensors has") && e.contains("--fresh"),
        "{e}"
    );
    std::fs::write(&tensors, &bytes).unwrap();
    assert_eq!(find_checkpoint(&ckpt).unwrap(), Some(ckpt.clone()));

    // state.toml gone (before, training restarted at step 0 without a word).
    let state = std::fs::read(ckpt.join("state.toml")).unwrap();
    std::fs::remove_file(ckpt.join("state.toml")).unwrap();
    assert!(err(&ckpt).contains("state.toml is missing"));
    std::fs::remove_file(ckpt.join(MANIFEST_FILE)).unwrap();
    assert!(err(&ckpt).contains("state.toml is missing"));
    // Both files without a manifest: nothing checks them, so no resume (and no restart).
    std::fs::write(ckpt.join("state.toml"), &state).unwrap();
    let e = err(&ckpt);
    assert!(
        e.contains("manifest.toml is missing") && e.contains("--fresh"),
        "{e}"
    );

    // Interrupted between the two renames: only `<ckpt>.old` is complete.
    fileset::write_manifest(&ckpt, &CHECKPOINT_FILES, tr.step()).unwrap();
    let old = fileset::sibling(&ckpt, "old");
    std::fs::rename(&ckpt, &old).unwrap();
    std::fs::create_dir_all(&ckpt).unwrap();
    std::fs::write(ckpt.join("state.toml"), "half").unwrap();
    assert_eq!(find_checkpoint(&ckpt).unwrap(), Some(old.clone()));
    let resumed = Trainer::resume(&old, &opts, &d, &d[..2], Device::Cpu).unwrap();
    assert_eq!(resumed.step(), 2);
    // The next save cleans up.
    resumed.save_checkpoint(&ckpt).unwrap();
    assert!(!old.exists());
    assert_eq!(find_checkpoint(&ckpt).unwrap(), Some(ckpt.clone()));
    let _ = std::fs::remove_dir_all(&root);
}

#[test]
fn resume_continues_exactly() {
    let _serial = TRAINING.lock().unwrap_or_else(|e| e.into_inner());
    let d = data(12);
    let net = tiny_net();
    let norm = Normalisation::estimate(&d, 0).unwrap();
    let opts = TrainOptions {
        batch_size: 5,
        steps: 6,
        warmup_steps: 2,
        ..TrainOptions::default()
    };
    let mut straight = Trainer::new(&net, &norm, &opts, &d, &d[..4], Device::Cpu).unwrap();
    for _ in 0..6 {
        straight.train_step().unwrap();
    }
    let dir = std::env::temp_dir().join(format!("h2n-flow-resume-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let mut first = Trainer::new(&net, &norm, &opts, &d, &d[..4], Device::Cpu).unwrap();
    for _ in 0..3 {
        first.train_step().unwrap();
    }
    first.record();
    assert_eq!(find_checkpoint(&dir).unwrap(), None);
    first.save_checkpoint(&dir).unwrap();
    assert_eq!(find_checkpoint(&dir).unwrap(), Some(dir.clone()));
    let mut resumed = Trainer::resume(&dir, &opts, &d, &d[..4], Device::Cpu).unwrap();
    assert_eq!(resumed.step(), 3);
    assert_eq!(resumed.history().len(), 1);
    for _ in 0..3 {
        resumed.train_step().unwrap();
    }
    for (prefix, a, b) in [
        (
            "param",
            straight.model().named_tensors(""),
            resumed.model().named_tensors(""),
        ),
        (
            "ema",
            straight.ema_model().named_tensors(""),
            resumed.ema_model().named_tensors(""),
        ),
    ] {
        for ((na, ta), (nb, tb)) in a.iter().zip(&b) {
            assert_eq!(na, nb);
            let diff = (ta - tb).abs().max().double_value(&[]);
            assert!(diff < 1e-6, "{prefix} {na} differs by {diff}");
        }
    }
    // Options other than `steps` must match the checkpoint.
    let other = TrainOptions {
        lr: 5e-4,
        ..opts.clone()
    };
    assert!(matches!(
        Trainer::resume(&dir, &other, &d, &d[..4], Device::Cpu),
        Err(CfmError::Option { field: "train", .. })
    ));
    let _ = std::fs::remove_dir_all(&dir);
}

/// A walker going straight at its velocity gets no counterfactual person (its future
/// would meet them); one that stopped gets a person where it would have been, clear of
/// its recorded future at every waypoint; the person appears in the batch's raster.
#[test]
fn counterfactual_people_are_clear_of_the_recorded_future() {
    let c = Counterfactual::default();
    let straight: Vec<Pose2> = (1..=32)
        .map(|i| Pose2::new(0.12 * i as f64, 0.0, 0.0))
        .collect();
    for u1 in [0.0, 0.5, 0.99] {
        assert_eq!(c.person(&straight, [1.2, 0.0], [0.1, u1, 0.2, 0.0]), None);
    }
    // It stopped after 1 m.
    let stopped: Vec<Pose2> = (1..=32)
        .map(|i| Pose2::new((0.12 * i as f64).min(1.0), 0.0, 0.0))
        .collect();
    assert_eq!(
        c.person(&stopped, [1.2, 0.0], [0.9, 0.5, 0.2, 0.0]),
        None,
        "u0 ≥ p"
    );
    for u in [
        [0.1, 0.0, 0.2, 0.0],
        [0.1, 0.99, 0.2, 0.0],
        [0.3, 0.5, 0.9, 0.6],
    ] {
        let a = c
            .person(&stopped, [1.2, 0.0], u)
            .expect("a place ahead of the stop");
        for (i, p) in stopped.iter().enumerate() {
            let t = (i + 1) as f64 * c.step;
            let q = [
                a.position[0] + a.velocity[0] * t,
                a.position[1] + a.velocity[1] * t,
            ];
            assert!((p.x - q[0]).hypot(p.y - q[1]) >= c.clearance - 1e-12);
        }
    }
    // In a batch: the row's raster gains the person's disc.
    let ex = Example {
        bev: vec![0.0; 3 * 16 * 16],
        goal: [5.0, 0.0],
        velocity: [1.2, 0.0],
        future: stopped,
    };
    let net = NetConfig {
        horizon: 32,
        bev_cells: 16,
        ..tiny_net()
    };
    let norm = Normalisation::default();
    let draws = BatchDraws {
        flip: vec![false],
        t: vec![0.5],
        source: vec![Twist2::new(0.0, 0.0, 0.0); 32],
        path: Vec::new(),
        counterfactual: vec![[0.1, 0.5, 0.2, 0.0]],
    };
    let data = [ex];
    let occupied = |b: &Batch| b.bev.narrow(1, 0, 1).sum(Kind::Float).double_value(&[]);
    let with = batch_from_draws(
        &data,
        &[0],
        &net,
        &norm,
        &draws,
        Some(&c),
        None,
        Device::Cpu,
    );
    let without = batch_from_draws(&data, &[0], &net, &norm, &draws, None, None, Device::Cpu);
    assert_eq!(occupied(&without), 0.0);
    assert!(occupied(&with) >= 1.0);
    assert_eq!(
        (with.target - without.target).abs().max().double_value(&[]),
        0.0,
        "the recorded future is the target either way"
    );
}

#[test]
fn rejects_mismatched_examples() {
    let mut d = data(3);
    d[1].future.pop();
    let err = check_examples(&tiny_net(), &d).unwrap_err();
    assert!(matches!(err, CfmError::Example { index: 1, .. }), "{err}");
}
