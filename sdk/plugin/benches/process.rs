//! What running a plugin in its own process costs per call: the same plugin in the host process
//! without a deadline (called on this thread), in the host process with the default 1000 ms
//! deadline (handed to its worker thread) and in a helper process (`isolation = "process"`, the
//! default: encoded, written to the helper's stdin, answered on its stdout and read back by the
//! proxy's reader thread), for
//!
//! * a planner `plan` call: the fixture `straight` planner (32 poses, 8 pedestrians with 8
//!   history points: almost no work of its own, so the time is the boundary's);
//! * a constraint `evaluate` call: `personal_space` on 4 × 32 poses (the guided shortlist of a
//!   planning call), 8 pedestrians;
//! * embodiment calls: `skid_steer` (the tracked robot's) `step`, and the three calls the
//!   simulator makes per step (`track` of a 33-pose plan, `saturate`, `step`);
//! * starting and stopping an instance (a benchmark creates one planner per episode): the
//!   fixture planner created and dropped.
//!
//! `cargo bench -p human2nav-plugin --bench process`. Besides criterion's groups it prints the
//! median time per call of each variant over rounds that call each variant once in turn (robust
//! to the load drifting on a shared machine), and the median of the per-round differences.

use criterion::{Criterion, criterion_group, criterion_main};
use human2nav_core::constraint::{ConstraintContext, ConstraintTerm, TrajBatch};
use human2nav_core::embodiment::{Embodiment, RobotState};
use human2nav_core::{
    ControllerGains, Limits, Observation, Plan, PlanInfo, Planner, Pose2, Twist2,
};
use human2nav_plugin::deadline::DEFAULT_DEADLINE;
use human2nav_plugin::{PluginHost, PluginIsolation, RobotContext};
use std::hint::black_box;
use std::time::{Duration, Instant};

mod common;
use common::{HORIZON, Paired, agents, library, limits, trajectories};

const ROUNDS: usize = 3000;

/// The three ways an instance runs, in the order the variants are passed around.
const VARIANTS: [(&str, Option<Duration>, PluginIsolation); 3] = [
    ("in_process_no_deadline", None, PluginIsolation::InProcess),
    (
        "in_process_deadline",
        Some(DEFAULT_DEADLINE),
        PluginIsolation::InProcess,
    ),
    ("process", Some(DEFAULT_DEADLINE), PluginIsolation::Process),
];

/// Medians over `n` rounds that call each of `calls` once, in turn (µs): each one's time per
/// call, then the per-round difference of the last (the helper process) minus each other.
fn rounds(n: usize, calls: &mut [&mut dyn FnMut()]) -> (Vec<f64>, Vec<f64>) {
    let k = calls.len();
    let mut times = vec![Vec::with_capacity(n); k];
    let mut diffs = vec![Vec::with_capacity(n); k - 1];
    let mut round = vec![0.0; k];
    for _ in 0..n {
        for (call, t) in calls.iter_mut().zip(round.iter_mut()) {
            let t0 = Instant::now();
            call();
            *t = t0.elapsed().as_secs_f64() * 1e6;
        }
        for (i, t) in round.iter().enumerate() {
            times[i].push(*t);
        }
        for (i, d) in diffs.iter_mut().enumerate() {
            d.push(round[k - 1] - round[i]);
        }
    }
    let median = |mut v: Vec<f64>| {
        v.sort_by(f64::total_cmp);
        Paired::at(&v, 1, 2)
    };
    (
        times.into_iter().map(median).collect(),
        diffs.into_iter().map(median).collect(),
    )
}

/// One line of medians: `what: in process a µs (no deadline), b µs (deadline), process c µs;
/// process adds c−a / c−b µs`.
fn report(what: &str, n: usize, (t, d): (Vec<f64>, Vec<f64>)) {
    println!(
        "{what}: in process {:.1} µs without a deadline, {:.1} µs with one; in a helper process \
         {:.1} µs; the helper adds {:.1} µs to the first, {:.1} µs to the second (medians of {n} \
         rounds)",
        t[0], t[1], t[2], d[0], d[1]
    );
}

fn host() -> PluginHost {
    PluginHost::new().with_process_helper(env!("CARGO_BIN_EXE_human2nav-plugin-host"))
}

fn planner(c: &mut Criterion) {
    let host = host();
    let lib = library("human2nav_fixture_test_plugin");
    let mut p = VARIANTS.map(|(_, deadline, isolation)| {
        host.planner_with_options(&lib, "straight", "horizon = 32", None, deadline, isolation)
            .unwrap_or_else(|e| panic!("{e}"))
    });
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
    let [a, b, x] = &mut p;
    assert_eq!(run(a), run(x));
    assert_eq!(run(b), run(x));
    let mut group = c.benchmark_group("planner_straight_32_poses_8_agents");
    group.measurement_time(Duration::from_secs(3));
    for ((name, ..), p) in VARIANTS.iter().zip(p.iter_mut()) {
        group.bench_function(*name, |bench| bench.iter(|| run(p)));
    }
    group.finish();
    let [a, b, x] = &mut p;
    let r = rounds(
        ROUNDS,
        &mut [&mut || _ = run(a), &mut || _ = run(b), &mut || _ = run(x)],
    );
    report("planner `straight` plan, 32 poses, 8 agents", ROUNDS, r);
}

fn constraint(c: &mut Criterion) {
    let host = host();
    let lib = library("human2nav_personal_space");
    let terms = VARIANTS.map(|(_, deadline, isolation)| {
        host.constraint_with_options(
            &lib,
            "personal_space",
            "robot_radius = 0.3",
            None,
            deadline,
            isolation,
        )
        .unwrap_or_else(|e| panic!("{e}"))
    });
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
    for t in &terms[..2] {
        assert_eq!(run(t).to_bits(), run(&terms[2]).to_bits());
    }
    let mut group = c.benchmark_group("personal_space_4x32_8_agents");
    group.measurement_time(Duration::from_secs(3));
    for ((name, ..), t) in VARIANTS.iter().zip(&terms) {
        group.bench_function(*name, |bench| bench.iter(|| run(t)));
    }
    group.finish();
    let [a, b, x] = &terms;
    let r = rounds(
        ROUNDS,
        &mut [&mut || _ = run(a), &mut || _ = run(b), &mut || _ = run(x)],
    );
    report(
        "constraint `personal_space` evaluate, 4 x 32 poses, 8 agents",
        ROUNDS,
        r,
    );
}

/// The tracked robot of `robots/tracked`, as its profile gives it to its embodiment.
fn tracked() -> RobotContext {
    RobotContext {
        limits: Limits {
            v_max: 1.2,
            v_reverse_max: 0.6,
            a_max: 0.8,
            omega_max: 1.2,
            kappa_max: None,
            lateral_speed_max: 0.05,
            coupled: None,
        },
        gains: ControllerGains {
            k_x: 1.5,
            k_y: 4.0,
            k_theta: 3.0,
            k_d: 0.2,
            lookahead: 0.05,
        },
        footprint_radius: 0.4,
    }
}

fn embodiment(c: &mut Criterion) {
    let host = host();
    let lib = library("human2nav_skid_steer");
    let config = "track_width = 0.46\nskid_factor = 1.5\ntrack_speed_max = 1.4";
    let robot = tracked();
    let e = VARIANTS.map(|(_, deadline, isolation)| {
        host.embodiment_with_options(&lib, "skid_steer", config, &robot, deadline, isolation)
            .unwrap_or_else(|e| panic!("{e}"))
    });
    let state = RobotState {
        pose: Pose2::new(0.5, 0.1, 0.05),
        velocity: Twist2::new(0.8, 0.0, 0.1),
    };
    let plan = Plan {
        t0: 0.0,
        dt: 0.1,
        poses: (0..33)
            .map(|k| Pose2::new(0.5 + 0.08 * k as f64, 0.1 + 0.002 * k as f64, 0.05))
            .collect(),
        info: PlanInfo::default(),
    };
    let dt = 0.05;
    let step =
        |e: &dyn Embodiment| black_box(e.step(black_box(&state), Twist2::new(0.9, 0.0, 0.1), dt));
    // What the simulator does at each of its steps.
    let sim_step = |e: &dyn Embodiment| {
        let raw = e.track(black_box(&state), &plan, 0.05);
        let cmd = e.saturate(&state, raw, dt);
        black_box(e.step(&state, cmd, dt))
    };
    for x in &e[..2] {
        assert_eq!(sim_step(x), sim_step(&e[2]));
        assert_eq!(step(x), step(&e[2]));
    }
    let mut group = c.benchmark_group("skid_steer_step");
    group.measurement_time(Duration::from_secs(3));
    for ((name, ..), x) in VARIANTS.iter().zip(&e) {
        group.bench_function(*name, |bench| bench.iter(|| step(x)));
    }
    group.finish();
    let mut group = c.benchmark_group("skid_steer_track_saturate_step");
    group.measurement_time(Duration::from_secs(3));
    for ((name, ..), x) in VARIANTS.iter().zip(&e) {
        group.bench_function(*name, |bench| bench.iter(|| sim_step(x)));
    }
    group.finish();
    let [a, b, x] = &e;
    let r = rounds(
        ROUNDS,
        &mut [&mut || _ = step(a), &mut || _ = step(b), &mut || {
            _ = step(x)
        }],
    );
    report("embodiment `skid_steer` step", ROUNDS, r);
    let r = rounds(
        ROUNDS,
        &mut [
            &mut || _ = sim_step(a),
            &mut || _ = sim_step(b),
            &mut || _ = sim_step(x),
        ],
    );
    report(
        "embodiment `skid_steer` track + saturate + step (one simulator step)",
        ROUNDS,
        r,
    );
    assert!(host.failures().is_empty());
}

fn start(c: &mut Criterion) {
    let host = host();
    let lib = library("human2nav_fixture_test_plugin");
    let make = |(_, deadline, isolation): (&str, Option<Duration>, PluginIsolation)| {
        let p = host
            .planner_with_options(&lib, "straight", "horizon = 32", None, deadline, isolation)
            .unwrap_or_else(|e| panic!("{e}"));
        black_box(p.name().len())
    };
    let mut group = c.benchmark_group("planner_start_and_stop");
    group.sample_size(20);
    group.measurement_time(Duration::from_secs(5));
    for v in VARIANTS {
        group.bench_function(v.0, |bench| bench.iter(|| make(v)));
    }
    group.finish();
    let n = 200;
    let [a, b, x] = VARIANTS;
    let r = rounds(
        n,
        &mut [&mut || _ = make(a), &mut || _ = make(b), &mut || {
            _ = make(x)
        }],
    );
    report("planner `straight` created and dropped", n, r);
}

criterion_group!(benches, planner, constraint, embodiment, start);
criterion_main!(benches);
