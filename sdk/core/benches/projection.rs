//! Cost of the exact last-step correction ([`human2nav_core::projection`]) on one plan of 32
//! poses with centimetre jitter (what the trained flow model produces), for a differential
//! drive and for a car with a curvature limit, with the default settings: a fresh solver per
//! plan (`project`), the solver a planner keeps from plan to plan (`project_with`, cycling
//! through differently jittered plans so that every QP has new values), and that kept solver
//! with every QP handed to Clarabel (`_clarabel`, at the fallback's tolerance), the reference
//! of the structured solver.
//!
//! Run: `cargo bench -p human2nav-core --bench projection`.

use criterion::{Criterion, criterion_group, criterion_main};
use human2nav_core::projection::{
    CLARABEL_TOLERANCE, ProjectionSettings, ProjectionSolver, project, project_with,
};
use human2nav_core::{Limits, Pose2, Twist2};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::hint::black_box;

/// 32 poses along an arc at 1.3 m/s turning at 0.2 rad/s, each coordinate jittered by ±3 cm
/// (±0.09 rad in heading).
fn jittery_plan(seed: u64) -> Vec<Pose2> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut p = Pose2::IDENTITY;
    (0..32)
        .map(|_| {
            p = p.euler_step(Twist2::new(1.3, 0.0, 0.2), 0.1);
            Pose2 {
                x: p.x + rng.random_range(-0.03..0.03),
                y: p.y + rng.random_range(-0.03..0.03),
                theta: p.theta + rng.random_range(-0.09..0.09),
            }
        })
        .collect()
}

fn bench_projection(c: &mut Criterion) {
    let plan = jittery_plan(7);
    let plans: Vec<Vec<Pose2>> = (0..8).map(jittery_plan).collect();
    let v0 = Twist2::new(1.3, 0.0, 0.2);
    let settings = ProjectionSettings::default();
    let diff_drive = Limits {
        v_max: 1.5,
        v_reverse_max: 0.5,
        a_max: 1.0,
        omega_max: 2.0,
        kappa_max: None,
        lateral_speed_max: 0.05,
        coupled: None,
    };
    let car = Limits {
        omega_max: 1.0,
        kappa_max: Some(1.0 / 1.6),
        ..diff_drive
    };
    for (name, limits) in [("diff_drive", diff_drive), ("car", car)] {
        c.bench_function(&format!("projection/{name}_t32"), |b| {
            b.iter(|| project(black_box(&plan), 0.1, &limits, v0, &settings))
        });
        for (suffix, mut solver) in [
            ("", ProjectionSolver::default()),
            (
                "_clarabel",
                ProjectionSolver::clarabel_only(CLARABEL_TOLERANCE),
            ),
        ] {
            let mut i = 0;
            c.bench_function(&format!("projection/{name}_t32_kept_solver{suffix}"), |b| {
                b.iter(|| {
                    i = (i + 1) % plans.len();
                    project_with(
                        black_box(&plans[i]),
                        0.1,
                        &limits,
                        v0,
                        &settings,
                        &mut solver,
                    )
                })
            });
        }
    }
}

criterion_group!(benches, bench_projection);
criterion_main!(benches);
