//! Cost of one planning call, beside ORCA's on the same scene
//! (`human2nav_local_core::closed_loop::ring_of_ten`, the observation of
//! `orca/plan_10_pedestrians` in `plugins/orca/benches/orca.rs`), planned by each with its
//! default settings and the differential-drive limits of `robots/diablo` (ORCA: its defaults,
//! as there).
//!
//! Run: `cargo bench -p human2nav-mppi --bench mppi`.

use criterion::{Criterion, criterion_group, criterion_main};
use human2nav_core::Planner;
use human2nav_local_core::closed_loop::{ROBOT_RADIUS, diff_drive, ring_of_ten};
use human2nav_mppi::{MppiConfig, MppiPlanner};
// ORCA without its plugin entry point: two plugin crates in one binary would define it twice.
use human2nav_orca_core::{OrcaConfig, OrcaPlanner};
use std::hint::black_box;

fn bench(c: &mut Criterion) {
    let obs = ring_of_ten();
    let mut planner = MppiPlanner::new(MppiConfig::default(), Some((&diff_drive(), ROBOT_RADIUS)))
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
