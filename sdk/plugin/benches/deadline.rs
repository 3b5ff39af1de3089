//! What the call deadline costs per call: the same plugin instance called without a deadline
//! (on this thread) and with one (handed to its worker thread and back, with the call's
//! buffers copied), for
//!
//! * a planner: the fixture `straight` planner (32 poses, 8 pedestrians with 8 history points:
//!   almost no work of its own, so the difference is the deadline's overhead);
//! * a constraint term: `personal_space` on 4 × 32 poses (the guided shortlist of a planning
//!   call) and on 64 × 32 poses, 8 pedestrians.
//!
//! `cargo bench -p human2nav-plugin --bench deadline`. The libraries are the cdylibs cargo
//! built for this benchmark as dev-dependencies (`target/release/deps/`), else the
//! workspace-built ones (`target/release/`). Besides criterion's groups it prints the median
//! per-call difference over alternating pairs (robust to the load drifting on a shared machine).

use criterion::{Criterion, criterion_group, criterion_main};
use human2nav_core::constraint::{ConstraintContext, ConstraintTerm, TrajBatch};
use human2nav_core::{Observation, Planner, Pose2, Twist2};
use human2nav_plugin::{PluginHost, deadline::DEFAULT_DEADLINE};
use std::hint::black_box;

mod common;
use common::{HORIZON, Paired, agents, library, limits, trajectories};

/// Median and quartiles over `n` alternating pairs of (time of `b`) − (time of `a`), in µs.
fn paired_difference(n: usize, a: impl FnMut(), b: impl FnMut()) -> (f64, f64, f64) {
    let d = Paired::run(n, a, b).diff;
    (
        Paired::at(&d, 1, 2),
        Paired::at(&d, 1, 4),
        Paired::at(&d, 3, 4),
    )
}

fn planner(c: &mut Criterion) {
    let host = PluginHost::new();
    let lib = library("human2nav_fixture_test_plugin");
    let make = |deadline| match host.planner_with_deadline(
        &lib,
        "straight",
        "horizon = 32",
        None,
        deadline,
    ) {
        Ok(p) => p,
        Err(e) => {
            panic!("{e} (build it with `cargo build --release -p human2nav-fixture-test-plugin`)")
        }
    };
    let (mut direct, mut guarded) = (make(None), make(Some(DEFAULT_DEADLINE)));
    let obs = Observation {
        time: 0.0,
        ego: Pose2::IDENTITY,
        ego_velocity: Twist2::ZERO,
        goal: [5.0, 1.0],
        agents: agents(),
        ..Default::default()
    };
    let run = |p: &mut dyn Planner| match p.plan(black_box(&obs)) {
        Ok(plan) => black_box(plan.poses.len()),
        Err(e) => panic!("planning failed: {e}"),
    };
    assert_eq!(run(&mut direct), run(&mut guarded));
    let mut group = c.benchmark_group("planner_straight_32_poses_8_agents");
    group.bench_function("no_deadline", |b| b.iter(|| run(&mut direct)));
    group.bench_function("deadline", |b| b.iter(|| run(&mut guarded)));
    group.finish();
    let (median, q1, q3) = paired_difference(
        5000,
        || {
            run(&mut direct);
        },
        || {
            run(&mut guarded);
        },
    );
    println!(
        "planner: deadline adds {median:.2} µs per call (median of 5000 alternating pairs; \
         quartiles {q1:.2} .. {q3:.2})"
    );
}

fn constraint(c: &mut Criterion) {
    let host = PluginHost::new();
    let lib = library("human2nav_personal_space");
    let make = |deadline| match host.constraint_with_deadline(
        &lib,
        "personal_space",
        "robot_radius = 0.3",
        None,
        deadline,
    ) {
        Ok(t) => t,
        Err(e) => panic!("{e} (build it with `cargo build --release -p human2nav-personal-space`)"),
    };
    let (direct, guarded) = (make(None), make(Some(DEFAULT_DEADLINE)));
    let limits = limits();
    let agents = agents();
    let ctx = ConstraintContext {
        dt: 0.1,
        limits: &limits,
        initial_velocity: Twist2::ZERO,
        agents: &agents,
        scene: Default::default(),
    };
    for batch in [4, 64] {
        let data = trajectories(batch);
        let cost = std::cell::RefCell::new((vec![0.0; batch], vec![0.0; data.len()]));
        let run = |term: &dyn ConstraintTerm| {
            let (cost, grad) = &mut *cost.borrow_mut();
            cost.fill(0.0);
            grad.fill(0.0);
            let b = TrajBatch {
                data: black_box(&data),
                batch,
                horizon: HORIZON,
            };
            if let Err(e) = term.evaluate(b, &ctx, cost, grad) {
                panic!("evaluation failed: {e}");
            }
            black_box(cost[0])
        };
        assert_eq!(run(&direct), run(&guarded));
        let mut group = c.benchmark_group(format!("personal_space_{batch}x32_8_agents"));
        group.bench_function("no_deadline", |b| b.iter(|| run(&direct)));
        group.bench_function("deadline", |b| b.iter(|| run(&guarded)));
        group.finish();
        let (median, q1, q3) = paired_difference(
            5000,
            || {
                run(&direct);
            },
            || {
                run(&guarded);
            },
        );
        println!(
            "constraint {batch}x32: deadline adds {median:.2} µs per call (median of 5000 \
             alternating pairs; quartiles {q1:.2} .. {q3:.2})"
        );
    }
}

criterion_group!(benches, planner, constraint);
criterion_main!(benches);
