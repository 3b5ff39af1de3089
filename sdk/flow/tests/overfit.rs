//! The trainer can memorise a tiny synthetic set: the CFM loss (Eq. 3) on the training tuples
//! falls by a large factor, the EMA weights follow, and sampling from the trained model lands
//! near the memorised futures. Runs in well under a minute.

use human2nav_core::flow::{FlowCondition, FlowModel};
use human2nav_core::se2::Pose2;
use human2nav_flow::cfm::TimeDistribution;
use human2nav_flow::eval::displacement_errors;
use human2nav_flow::sampler::sample;
use human2nav_flow::train::{Example, TrainOptions, Trainer, evaluate_loss};
use human2nav_flow::{NetConfig, Normalisation};
use rand::SeedableRng;
use tch::Device;

/// Required reduction of the training loss.
const FACTOR: f64 = 20.0;

fn tiny_set() -> Vec<Example> {
    human2nav_data::synthetic::tuples(8, 3)
        .into_iter()
        .map(|t| Example {
            bev: t.bev,
            goal: [t.goal[0] as f64, t.goal[1] as f64],
            velocity: [t.velocity[0] as f64, t.velocity[1] as f64],
            future: t
                .future
                .iter()
                .map(|p| Pose2::new(p[0] as f64, p[1] as f64, p[2] as f64))
                .collect(),
        })
        .collect()
}

#[test]
fn overfits_a_tiny_synthetic_set() {
    tch::set_num_threads(1);
    let data = tiny_set();
    assert_eq!(data.len(), 8);
    let net = NetConfig::default();
    let norm = Normalisation::estimate(&data, 0).unwrap();
    let opts = TrainOptions {
        batch_size: 32,
        steps: 400,
        lr: 3e-3,
        lr_min: 1e-4,
        warmup_steps: 20,
        ema_decay: 0.95,
        ..TrainOptions::default()
    };
    let mut tr = Trainer::new(&net, &norm, &opts, &data, &data, Device::Cpu).unwrap();
    let time = TimeDistribution::default();
    let before = evaluate_loss(tr.model(), &data, &time, 11).unwrap();
    let ade_before = sample_ade(tr.model(), &data);
    while tr.step() < opts.steps {
        tr.train_step().unwrap();
    }
    let after = evaluate_loss(tr.model(), &data, &time, 11).unwrap();
    let after_ema = evaluate_loss(tr.ema_model(), &data, &time, 11).unwrap();
    eprintln!(
        "overfit: loss {before:.4} -> {after:.4} (EMA {after_ema:.4}), factor {:.1}",
        before / after
    );
    assert!(
        before / after > FACTOR,
        "loss fell only from {before} to {after}"
    );
    assert!(
        after_ema < before / 4.0,
        "EMA loss {after_ema} vs initial {before}"
    );

    // Samples of the memorised model reproduce the memorised futures.
    let ade_after = sample_ade(tr.model(), &data);
    eprintln!("overfit: sample ADE {ade_before:.3} m before training, {ade_after:.3} m after");
    assert!(
        ade_after < ade_before / 4.0 && ade_after < 0.3,
        "sample ADE {ade_before} -> {ade_after}"
    );
}

/// Mean ADE of 4 samples (10 Euler steps) per example against its own future.
fn sample_ade<M: FlowModel>(model: &M, data: &[Example]) -> f64 {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
    let mut ade = 0.0;
    for ex in data {
        let cond = FlowCondition {
            bev: ex.bev.clone(),
            goal: ex.goal,
            velocity: ex.velocity,
        };
        let x = sample(model, &cond, 4, 10, &mut rng).expect("sampling");
        for traj in x.chunks_exact(3 * model.horizon()) {
            ade += displacement_errors(traj, &ex.future).0 / (4 * data.len()) as f64;
        }
    }
    ade
}
