//! Latency of the default architecture's trait calls (randomly initialised weights cost the
//! same as trained ones), for the libtorch model (`velocity_b*`, `velocity_vjp_b*`) and the
//! native one on the same weights (`native/…`): velocity and velocity + VJP at batch 1, 4, 16
//! and 32 with the condition cached, one condition encoding, and one training step of batch 64.
//!
//! Run: `cargo bench -p human2nav-flow --bench flow` (set threads with `H2N_THREADS`, default 1).

use criterion::{Criterion, criterion_group, criterion_main};
use human2nav_core::FlowModel;
use human2nav_core::se2::Pose2;
use human2nav_flow::cfm::sample_source;
use human2nav_flow::perf::bench_condition;
use human2nav_flow::train::{Example, TrainOptions, Trainer};
use human2nav_flow::{CfmModel, NativeCfm, NetConfig, Normalisation};
use rand::SeedableRng;
use std::hint::black_box;
use tch::Device;

fn threads() -> i32 {
    std::env::var("H2N_THREADS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(1)
}

fn bench_model(c: &mut Criterion) {
    tch::set_num_threads(threads());
    tch::manual_seed(0);
    let net = NetConfig::default();
    let norm = Normalisation {
        position_scale: 2.0,
        ..Normalisation::default()
    };
    let model = CfmModel::new(&net, &norm, Device::Cpu).expect("default config is valid");
    let cond = bench_condition(net.bev_cells);
    let native = NativeCfm::from_model(&model).expect("same weights");
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(0);
    for k in [1usize, 4, 16, 32] {
        let x = sample_source(k, net.horizon, model.source_std(), &mut rng);
        let cot = vec![0.1; x.len()];
        let mut out = vec![0.0; x.len()];
        let mut vjp = vec![0.0; x.len()];
        c.bench_function(&format!("velocity_b{k}"), |b| {
            b.iter(|| {
                model
                    .velocity(black_box(&x), 0.5, &cond, &mut out)
                    .expect("velocity")
            })
        });
        c.bench_function(&format!("velocity_vjp_b{k}"), |b| {
            b.iter(|| {
                model
                    .velocity_vjp(black_box(&x), 0.5, &cond, &cot, &mut out, &mut vjp)
                    .expect("vjp")
            })
        });
        // The native model keeps recent forward passes for a VJP at the same input, so every
        // iteration perturbs the input to measure fresh calls.
        let mut xs = x.clone();
        let mut step = 0u64;
        let mut fresh = move || {
            step += 1;
            xs[0] = x[0] + 1e-9 * step as f64;
            xs.clone()
        };
        c.bench_function(&format!("native/velocity_b{k}"), |b| {
            b.iter_batched(
                &mut fresh,
                |xi| {
                    native
                        .velocity(&xi, 0.5, &cond, &mut out)
                        .expect("velocity")
                },
                criterion::BatchSize::SmallInput,
            )
        });
        c.bench_function(&format!("native/velocity_vjp_b{k}"), |b| {
            b.iter_batched(
                &mut fresh,
                |xi| {
                    native
                        .velocity_vjp(&xi, 0.5, &cond, &cot, &mut out, &mut vjp)
                        .expect("vjp")
                },
                criterion::BatchSize::SmallInput,
            )
        });
        // Algorithm 1's pattern: the rollout's forward pass, then the VJP at the same point.
        c.bench_function(&format!("native/velocity_then_vjp_b{k}"), |b| {
            b.iter_batched(
                &mut fresh,
                |xi| {
                    native
                        .velocity(&xi, 0.5, &cond, &mut out)
                        .expect("velocity");
                    native
                        .velocity_vjp(&xi, 0.5, &cond, &cot, &mut out, &mut vjp)
                        .expect("vjp")
                },
                criterion::BatchSize::SmallInput,
            )
        });
    }
    c.bench_function("encode_condition", |b| {
        b.iter(|| {
            model.invalidate_cache();
            model.condition_embedding(&cond).expect("encode")
        })
    });
}

fn bench_train_step(c: &mut Criterion) {
    tch::set_num_threads(threads());
    let net = NetConfig::default();
    let cond = bench_condition(net.bev_cells);
    let data: Vec<Example> = (0..256)
        .map(|i| Example {
            bev: cond.bev.clone(),
            goal: [4.0, 0.1 * (i % 7) as f64],
            velocity: [1.2, 0.0],
            future: (1..=net.horizon)
                .map(|j| Pose2::new(0.12 * j as f64, 0.0, 0.0))
                .collect(),
        })
        .collect();
    let norm = Normalisation::estimate(&data, 0).expect("normalisation");
    let opts = TrainOptions {
        batch_size: 64,
        steps: 1_000_000,
        ..TrainOptions::default()
    };
    let mut tr = Trainer::new(&net, &norm, &opts, &data, &[], Device::Cpu).expect("trainer");
    let mut group = c.benchmark_group("train");
    group.sample_size(20);
    group.bench_function("train_step_b64", |b| {
        b.iter(|| tr.train_step().expect("step"))
    });
    group.finish();
}

criterion_group!(benches, bench_model, bench_train_step);
criterion_main!(benches);
