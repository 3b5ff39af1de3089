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
use human2nav_core::{AgentState, Limits, Observation, Planner, Pose2, Twist2};
use human2nav_plugin::{PluginHost, deadline::DEFAULT_DEADLINE};
use std::hint::black_box;
use std::path::PathBuf;
use std::time::Instant;

const HORIZON: usize = 32;

/// A cdylib of this benchmark's dev-dependencies (see the module docs).
fn library(name: &str) -> PathBuf {
    let deps = std::env::current_exe()
        .ok()
        .and_then(|exe| exe.parent().map(PathBuf::from))
        .unwrap_or_else(|| PathBuf::from("target/release/deps"));
    let here = deps.join(name);
    if human2nav_plugin::resolve::resolve_library_path(&here).is_ok() {
        return here;
    }
    deps.parent().unwrap_or(&deps).join(name)
}

fn agents() -> Vec<AgentState> {
    (0..8)
        .map(|j| {
            let a = j as f64 * 0.785;
            AgentState {
                id: j,
                position: [2.0 + 1.5 * a.cos(), 1.5 * a.sin()],
                velocity: [-0.8 * a.cos(), 0.6 * a.sin()],
                radius: 0.3,
                history: vec![[0.0, 0.0]; 8],
            }
        })
        .collect()
}

fn trajectories(batch: usize) -> Vec<f64> {
    let mut data = Vec::with_capacity(batch * HORIZON * 3);
    for b in 0..batch {
        let bend = (b as f64 - batch as f64 / 2.0) * 0.02;
        for k in 0..HORIZON {
            let s = k as f64 * 0.1;
            data.extend_from_slice(&[1.2 * s, bend * s * s, 2.0 * bend * s]);
        }
    }
    data
}

/// Median over `n` alternating pairs of (time of `b`) − (time of `a`), in µs.
fn paired_difference(n: usize, mut a: impl FnMut(), mut b: impl FnMut()) -> (f64, f64, f64) {
    let mut d: Vec<f64> = (0..n)
        .map(|_| {
            let t0 = Instant::now();
            a();
            let t1 = Instant::now();
            b();
            let t2 = Instant::now();
            ((t2 - t1).as_secs_f64() - (t1 - t0).as_secs_f64()) * 1e6
        })
        .collect();
    d.sort_by(f64::total_cmp);
    (d[n / 2], d[n / 4], d[3 * n / 4])
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
    let limits = Limits {
        v_max: 1.2,
        v_reverse_max: 0.4,
        a_max: 1.0,
        omega_max: 1.5,
        kappa_max: None,
        lateral_speed_max: 0.05,
    };
    let agents = agents();
    let ctx = ConstraintContext {
        dt: 0.1,
        limits: &limits,
        initial_velocity: Twist2::ZERO,
        agents: &agents,
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
