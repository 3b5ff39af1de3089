//! Cost of the plugin boundary: the `personal_space` constraint on 64 trajectories × 32 poses
//! with 8 pedestrians, called directly (the Rust type) and through the host proxy (the cdylib
//! loaded with libloading). Both compute the same numbers; the ratio of the two times is the
//! boundary overhead (target: under 5 %). The proxy runs without a deadline here (calls on the
//! caller's thread); `--bench deadline` measures what the deadline adds.
//!
//! `cargo bench -p human2nav-plugin --bench boundary`. The cdylib is the one cargo built for
//! this benchmark as a dev-dependency (`target/release/deps/`), else the workspace-built one
//! (`target/release/`).

use criterion::{Criterion, criterion_group, criterion_main};
use human2nav_core::Twist2;
use human2nav_core::constraint::{ConstraintContext, ConstraintTerm, TrajBatch};
use human2nav_personal_space::{PersonalSpace, PersonalSpaceConfig};
use human2nav_plugin::PluginHost;
use std::hint::black_box;
use std::time::Instant;

mod common;
use common::{HORIZON, agents, library, limits, trajectories};

const BATCH: usize = 64;

fn boundary(c: &mut Criterion) {
    let limits = limits();
    let agents = agents();
    let ctx = ConstraintContext {
        dt: 0.1,
        limits: &limits,
        initial_velocity: Twist2::ZERO,
        agents: &agents,
        scene: Default::default(),
    };
    let data = trajectories(BATCH);
    let direct = match PersonalSpace::new(&PersonalSpaceConfig::default(), Some(0.3)) {
        Ok(t) => t,
        Err(e) => panic!("default config must be valid: {e}"),
    };
    let host = PluginHost::new();
    let library = library("human2nav_personal_space");
    // Without a deadline: the call runs on this thread, as the direct one does (the deadline's
    // hand-off to a worker is measured by the `deadline` benchmark).
    let plugin = match host.constraint_with_deadline(
        &library,
        "personal_space",
        "robot_radius = 0.3",
        None,
        None,
    ) {
        Ok(t) => t,
        Err(e) => panic!("{e} (build it with `cargo build --release -p human2nav-personal-space`)"),
    };
    let mut cost = vec![0.0; BATCH];
    let mut grad = vec![0.0; data.len()];
    let run = |term: &dyn ConstraintTerm, cost: &mut [f64], grad: &mut [f64]| {
        cost.fill(0.0);
        grad.fill(0.0);
        let batch = TrajBatch {
            data: black_box(&data),
            batch: BATCH,
            horizon: HORIZON,
        };
        if let Err(e) = term.evaluate(batch, &ctx, cost, grad) {
            panic!("evaluation failed: {e}");
        }
    };
    // Same numbers either way.
    let (mut c2, mut g2) = (vec![0.0; BATCH], vec![0.0; data.len()]);
    run(&direct, &mut cost, &mut grad);
    run(&plugin, &mut c2, &mut g2);
    assert!(
        cost.iter()
            .zip(&c2)
            .all(|(a, b)| (a - b).abs() <= 1e-12 * a.abs().max(1e-300))
    );
    assert!(
        cost.iter().all(|c| *c > 0.0),
        "the batch must pass near the agents"
    );

    let mut group = c.benchmark_group("personal_space_64x32_8_agents");
    group.bench_function("direct", |b| b.iter(|| run(&direct, &mut cost, &mut grad)));
    group.bench_function("plugin", |b| b.iter(|| run(&plugin, &mut cost, &mut grad)));
    group.finish();

    // On a shared machine the load drifts between criterion's two measurements; alternating the
    // two calls and taking the median of the per-pair ratio cancels the drift.
    let mut ratios: Vec<f64> = (0..2000)
        .map(|_| {
            let t0 = Instant::now();
            run(&direct, &mut cost, &mut grad);
            let t1 = Instant::now();
            run(&plugin, &mut cost, &mut grad);
            let t2 = Instant::now();
            (t2 - t1).as_secs_f64() / (t1 - t0).as_secs_f64()
        })
        .collect();
    ratios.sort_by(f64::total_cmp);
    println!(
        "boundary ratio plugin/direct, 2000 alternating pairs: median {:.4} (quartiles {:.4} .. {:.4})",
        ratios[1000], ratios[500], ratios[1500]
    );

    // The fixed cost of one call through the boundary: one pose, no agents.
    let one = [0.0, 0.0, 0.0];
    let empty = ConstraintContext { agents: &[], ..ctx };
    let mut group = c.benchmark_group("personal_space_1x1_no_agents");
    for (name, term) in [
        ("direct", &direct as &dyn ConstraintTerm),
        ("plugin", &plugin),
    ] {
        group.bench_function(name, |b| {
            b.iter(|| {
                let (mut c1, mut g1) = ([0.0], [0.0; 3]);
                let batch = TrajBatch {
                    data: black_box(&one),
                    batch: 1,
                    horizon: 1,
                };
                if let Err(e) = term.evaluate(batch, &empty, &mut c1, &mut g1) {
                    panic!("evaluation failed: {e}");
                }
                black_box(c1[0])
            })
        });
    }
    group.finish();
}

criterion_group!(benches, boundary);
criterion_main!(benches);
