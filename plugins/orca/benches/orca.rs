//! Cost of one ORCA decision.
//!
//! * `orca/velocity_n<k>`: neighbour selection, `k` ORCA half-planes and the exact 2-D linear
//!   program for an agent inside a ring of `k` approaching neighbours (the worst case: many
//!   binding lines);
//! * `orca/plan_10_pedestrians`: the full planner call (observation to 32-pose plan).
//!
//! Run: `cargo bench -p human2nav-orca --bench orca`.

use criterion::{Criterion, criterion_group, criterion_main};
use human2nav_core::{AgentState, Observation, Planner, Pose2, Twist2};
use human2nav_orca::lp::Vec2;
use human2nav_orca::orca::{Neighbor, OrcaParams, compute_new_velocity};
use human2nav_orca::{OrcaConfig, OrcaPlanner};
use std::f64::consts::TAU;
use std::hint::black_box;

fn ring(k: usize, rho: f64) -> Vec<Neighbor> {
    (0..k)
        .map(|i| {
            let a = TAU * i as f64 / k as f64;
            let p = Vec2::new(rho * a.cos(), rho * a.sin());
            Neighbor {
                position: p,
                velocity: p * (-0.5 / rho),
                radius: 0.3,
            }
        })
        .collect()
}

fn bench(c: &mut Criterion) {
    let params = OrcaParams {
        neighbor_dist: 10.0,
        max_neighbors: 16,
        time_horizon: 5.0,
        time_step: 0.1,
        radius: 0.3,
        max_speed: 1.5,
    };
    for k in [1usize, 5, 10, 16] {
        let others = ring(k, 2.0);
        c.bench_function(&format!("orca/velocity_n{k}"), |b| {
            b.iter(|| {
                compute_new_velocity(
                    black_box(Vec2::ZERO),
                    black_box(Vec2::new(1.0, 0.0)),
                    Vec2::new(1.5, 0.0),
                    black_box(&others),
                    &params,
                )
            })
        });
    }
    let agents: Vec<AgentState> = ring(10, 3.0)
        .iter()
        .enumerate()
        .map(|(i, n)| AgentState {
            id: i as u64,
            position: n.position.to_array(),
            velocity: n.velocity.to_array(),
            radius: n.radius,
            history: Vec::new(),
        })
        .collect();
    let obs = Observation {
        time: 0.0,
        ego: Pose2::new(0.0, 0.0, 0.0),
        ego_velocity: Twist2::new(1.0, 0.0, 0.0),
        goal: [10.0, 0.0],
        agents,
    };
    let mut planner = OrcaPlanner::new(OrcaConfig::default()).expect("default config is valid");
    c.bench_function("orca/plan_10_pedestrians", |b| {
        b.iter(|| planner.plan(black_box(&obs)))
    });
}

criterion_group!(benches, bench);
criterion_main!(benches);
