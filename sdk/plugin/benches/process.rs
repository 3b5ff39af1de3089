//! What running a plugin in its own process costs per call: the same plugin in the host process
//! (with the default 1000 ms deadline: handed to its worker thread) and in a helper process
//! (`isolation = "process"`: encoded, written to the helper's stdin, answered on its stdout and
//! read back by the proxy's reader thread), for
//!
//! * a planner: the fixture `straight` planner (32 poses, 8 pedestrians with 8 history points:
//!   almost no work of its own, so the time is the boundary's);
//! * a constraint term: `personal_space` on 4 × 32 poses (the guided shortlist of a planning
//!   call), 8 pedestrians.
//!
//! `cargo bench -p human2nav-plugin --bench process`. Besides criterion's groups it prints the
//! median time per call of each variant over alternating calls (robust to the load drifting on
//! a shared machine).

use criterion::{Criterion, criterion_group, criterion_main};
use human2nav_core::constraint::{ConstraintContext, ConstraintTerm, TrajBatch};
use human2nav_core::{Observation, Planner, Pose2, Twist2};
use human2nav_plugin::deadline::DEFAULT_DEADLINE;
use human2nav_plugin::{PluginHost, PluginIsolation};
use std::hint::black_box;
use std::time::Duration;

mod common;
use common::{HORIZON, Paired, agents, library, limits, trajectories};

/// Medians (µs) of `a`'s and `b`'s time per call over `n` alternating calls, and the median
/// of their per-pair difference.
fn paired(n: usize, a: impl FnMut(), b: impl FnMut()) -> (f64, f64, f64) {
    let p = Paired::run(n, a, b);
    (
        Paired::at(&p.a, 1, 2),
        Paired::at(&p.b, 1, 2),
        Paired::at(&p.diff, 1, 2),
    )
}

const PAIRS: usize = 3000;

fn host() -> PluginHost {
    PluginHost::new().with_process_helper(env!("CARGO_BIN_EXE_human2nav-plugin-host"))
}

fn planner(c: &mut Criterion) {
    let host = host();
    let lib = library("human2nav_fixture_test_plugin");
    let make = |isolation| {
        host.planner_with_options(
            &lib,
            "straight",
            "horizon = 32",
            None,
            Some(DEFAULT_DEADLINE),
            isolation,
        )
        .unwrap_or_else(|e| panic!("{e}"))
    };
    let mut inside = make(PluginIsolation::InProcess);
    let mut outside = make(PluginIsolation::Process);
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
    assert_eq!(run(&mut inside), run(&mut outside));
    let mut group = c.benchmark_group("planner_straight_32_poses_8_agents");
    group.measurement_time(Duration::from_secs(3));
    group.bench_function("in_process", |b| b.iter(|| run(&mut inside)));
    group.bench_function("process", |b| b.iter(|| run(&mut outside)));
    group.finish();
    let (a, b, d) = paired(
        PAIRS,
        || {
            run(&mut inside);
        },
        || {
            run(&mut outside);
        },
    );
    println!(
        "planner straight 32 poses, 8 agents: in-process {a:.1} µs, process {b:.1} µs per call, \
         process adds {d:.1} µs (medians of {PAIRS} alternating calls)"
    );
}

fn constraint(c: &mut Criterion) {
    let host = host();
    let lib = library("human2nav_personal_space");
    let make = |isolation| {
        host.constraint_with_options(
            &lib,
            "personal_space",
            "robot_radius = 0.3",
            None,
            Some(DEFAULT_DEADLINE),
            isolation,
        )
        .unwrap_or_else(|e| panic!("{e}"))
    };
    let (inside, outside) = (
        make(PluginIsolation::InProcess),
        make(PluginIsolation::Process),
    );
    let limits = limits();
    let agents = agents();
    let ctx = ConstraintContext {
        dt: 0.1,
        limits: &limits,
        initial_velocity: Twist2::ZERO,
        agents: &agents,
        scene: Default::default(),
    };
    let batch = 4;
    let data = trajectories(batch);
    let buffers = std::cell::RefCell::new((vec![0.0; batch], vec![0.0; data.len()]));
    let run = |term: &dyn ConstraintTerm| {
        let (cost, grad) = &mut *buffers.borrow_mut();
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
    assert_eq!(run(&inside).to_bits(), run(&outside).to_bits());
    let mut group = c.benchmark_group("personal_space_4x32_8_agents");
    group.measurement_time(Duration::from_secs(3));
    group.bench_function("in_process", |b| b.iter(|| run(&inside)));
    group.bench_function("process", |b| b.iter(|| run(&outside)));
    group.finish();
    let (a, b, d) = paired(
        PAIRS,
        || {
            run(&inside);
        },
        || {
            run(&outside);
        },
    );
    println!(
        "constraint personal_space 4x32, 8 agents: in-process {a:.1} µs, process {b:.1} µs per \
         call, process adds {d:.1} µs (medians of {PAIRS} alternating calls)"
    );
}

criterion_group!(benches, planner, constraint);
criterion_main!(benches);
