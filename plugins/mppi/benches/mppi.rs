//! Cost of one planning call, beside ORCA's on the same scene: the observation of
//! `orca/plan_10_pedestrians` in `plugins/orca/benches/orca.rs` (the robot at the origin
//! at 1 m/s toward a goal 10 m ahead, 10 pedestrians on a ring of radius 3 m walking toward
//! its centre at 0.5 m/s, radius 0.3 m), planned by each with its default settings and the
//! differential-drive limits of `robots/diablo` (ORCA: its defaults, as there).
//!
//! Run: `cargo bench -p human2nav-mppi --bench mppi`.

use criterion::{Criterion, criterion_group, criterion_main};
use human2nav_core::{AgentState, Limits, Observation, Planner, Pose2, Twist2};
use human2nav_mppi::{MppiConfig, MppiPlanner};
// ORCA without its plugin entry point: two plugin crates in one binary would define it twice.
use human2nav_orca_core::{OrcaConfig, OrcaPlanner};
use std::f64::consts::TAU;
use std::hint::black_box;

/// `orca/plan_10_pedestrians`'s observation.
fn scene() -> Observation {
    let agents = (0..10)
        .map(|i| {
            let a = TAU * i as f64 / 10.0;
            let p = [3.0 * a.cos(), 3.0 * a.sin()];
            AgentState {
                id: i as u64,
                position: p,
                velocity: [-0.5 * p[0] / 3.0, -0.5 * p[1] / 3.0],
                radius: 0.3,
                history: Vec::new(),
            }
        })
        .collect();
    Observation {
        time: 0.0,
        ego: Pose2::new(0.0, 0.0, 0.0),
        ego_velocity: Twist2::new(1.0, 0.0, 0.0),
        goal: [10.0, 0.0],
        agents,
        ..Default::default()
    }
}

fn diablo() -> Limits {
    Limits {
        v_max: 1.5,
        v_reverse_max: 0.5,
        a_max: 1.0,
        omega_max: 2.0,
        kappa_max: None,
        lateral_speed_max: 0.05,
        coupled: None,
    }
}

fn bench(c: &mut Criterion) {
    let obs = scene();
    let mut planner = MppiPlanner::new(MppiConfig::default(), Some((&diablo(), 0.3)))
        .expect("default config is valid");
    c.bench_function("mppi/plan_10_pedestrians", |b| {
        b.iter(|| planner.plan(black_box(&obs)))
    });
    let mut orca = OrcaPlanner::new(OrcaConfig::default()).expect("default config is valid");
    c.bench_function("orca/plan_10_pedestrians", |b| {
        b.iter(|| orca.plan(black_box(&obs)))
    });
}

criterion_group!(benches, bench);
criterion_main!(benches);
