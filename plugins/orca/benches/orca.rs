//! Cost of ORCA: one decision, the planner call, and a whole crowd.
//!
//! * `orca/velocity_n<k>`: neighbour selection, `k` ORCA half-planes and the exact 2-D linear
//!   program for an agent inside a ring of `k` approaching neighbours (the worst case: many
//!   binding lines);
//! * `orca/plan_10_pedestrians`: the full planner call (observation to 32-pose plan);
//! * `orca/circle_n<N>` (N = 5, 100, 1000): a crowd stepped by [`OrcaSim`] (default neighbour
//!   search: the scan below 64 agents, the k-d tree from 64) in RVO2's Circle scenario, the
//!   workload of the RVO2 comparison in `ARCHITECTURE.md`. `N` agents start evenly spaced on
//!   a circle of radius `ρ = max(10, 4·N/2π)` m (4 m of arc each) and head for the antipode,
//!   with RVO2's Circle settings: radius 1.5 m, max speed 2 m/s, neighbour distance 15 m,
//!   10 neighbours, time step 0.25 s; time horizon 5 s. Each step the preferred velocity is
//!   the goal vector clipped to unit length plus a pseudo-random perturbation of at most
//!   0.01 m/s per axis (a 64-bit LCG), as RVO2's Blocks example perturbs its agents: without it
//!   the exactly symmetric crowd deadlocks in a ring around the centre. One iteration runs,
//!   from the start, the `⌈8ρ⌉` steps an unobstructed agent needs to cross (the approach, the
//!   jam in the centre, part of the way out): 80 steps at N = 5, 510 at 100, 5093 at 1000.
//!   **Time per agent-step = time / (steps · N) = 1 / thrpt** (criterion's throughput is in
//!   agent-steps per second; the bench prints the agent-steps of an iteration).
//!
//! Run: `cargo bench -p human2nav-orca --bench orca` (only the crowd:
//! `cargo bench -p human2nav-orca --bench orca -- circle`).

use criterion::{BatchSize, Criterion, SamplingMode, Throughput, criterion_group, criterion_main};
use human2nav_core::{AgentState, Observation, Planner, Pose2, Twist2};
use human2nav_orca::lp::Vec2;
use human2nav_orca::orca::{Neighbor, OrcaParams, compute_new_velocity};
use human2nav_orca::{OrcaConfig, OrcaPlanner, OrcaSim};
use std::f64::consts::TAU;
use std::hint::black_box;
use std::time::Duration;

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
        ..Default::default()
    };
    let mut planner = OrcaPlanner::new(OrcaConfig::default()).expect("default config is valid");
    c.bench_function("orca/plan_10_pedestrians", |b| {
        b.iter(|| planner.plan(black_box(&obs)))
    });
}

/// The circle scenario: the starting crowd, the goals and the number of steps of one
/// iteration (see the module docs).
struct Circle {
    start: OrcaSim,
    goals: Vec<Vec2>,
    steps: usize,
}

fn circle(n: usize) -> Circle {
    let rho = (4.0 * n as f64 / TAU).max(10.0);
    let params = OrcaParams {
        neighbor_dist: 15.0,
        max_neighbors: 10,
        time_horizon: 5.0,
        time_step: 0.25,
        radius: 1.5,
        max_speed: 2.0,
    };
    let mut start = OrcaSim::new(0.25).expect("0.25 s is a valid time step");
    let mut goals = Vec::with_capacity(n);
    for i in 0..n {
        let a = TAU * i as f64 / n as f64;
        let p = Vec2::new(rho * a.cos(), rho * a.sin());
        start.add_agent(p, params);
        goals.push(-p);
    }
    Circle {
        start,
        goals,
        steps: (8.0 * rho).ceil() as usize,
    }
}

/// A 64-bit LCG (Knuth's MMIX constants): uniform numbers in [0, 1).
struct Lcg(u64);

impl Lcg {
    fn uniform(&mut self) -> f64 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (self.0 >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// Runs `steps` steps: preferred velocities (goal vector clipped to unit length, plus the
/// perturbation), then one ORCA step for everybody.
fn run_circle(sim: &mut OrcaSim, goals: &[Vec2], steps: usize) {
    let mut rng = Lcg(1);
    for _ in 0..steps {
        for (i, goal) in goals.iter().enumerate() {
            let to_goal = *goal - sim.positions()[i];
            let pref = if to_goal.norm_sq() > 1.0 {
                to_goal.normalized()
            } else {
                to_goal
            };
            let jitter = Vec2::new(rng.uniform() - 0.5, rng.uniform() - 0.5) * 0.02;
            sim.pref_velocities_mut()[i] = pref + jitter;
        }
        sim.step();
    }
}

fn bench_circle(c: &mut Criterion) {
    let mut group = c.benchmark_group("orca");
    for n in [5usize, 100, 1000] {
        let scenario = circle(n);
        let agent_steps = scenario.steps * n;
        eprintln!(
            "orca/circle_n{n}: one iteration = {} steps x {n} agents = {agent_steps} agent-steps",
            scenario.steps
        );
        // An iteration takes from tens of microseconds (N = 5) to seconds (N = 1000): samples
        // of equal size, fewer of them for the large crowds.
        let (samples, seconds) = if n <= 10 {
            (100, 5)
        } else if n <= 100 {
            (20, 10)
        } else {
            (10, 35)
        };
        group
            .throughput(Throughput::Elements(agent_steps as u64))
            .sampling_mode(SamplingMode::Flat)
            .sample_size(samples)
            .measurement_time(Duration::from_secs(seconds));
        group.bench_function(format!("circle_n{n}"), |b| {
            b.iter_batched_ref(
                || scenario.start.clone(),
                |sim| run_circle(sim, &scenario.goals, scenario.steps),
                BatchSize::PerIteration,
            )
        });
    }
    group.finish();
}

criterion_group!(benches, bench, bench_circle);
criterion_main!(benches);
