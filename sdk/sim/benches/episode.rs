//! Cost of the simulator itself (everything but the planner's own work).
//!
//! * `sim/episode_straight_<robot>`: one closed-loop episode (5 m, 12.5 s budget, a crowd of
//!   12 replayed pedestrians) with the straight baseline: replay, clearance, observations at
//!   10 Hz, tracking, saturation and stepping at 20 Hz;
//! * `sim/metrics`: the per-episode metrics (TFS of every plan included) of that run.
//!
//! Run: `cargo bench -p human2nav-sim --bench episode`.

use criterion::{Criterion, criterion_group, criterion_main};
use human2nav_core::Pose2;
use human2nav_sim::episode::{AgentTrack, Episode, ScenarioClass};
use human2nav_sim::straight::{StraightConfig, StraightPlanner};
use human2nav_sim::{EpisodeMetrics, RobotSetup, SimConfig, run_episode};
use std::hint::black_box;
use std::path::PathBuf;

fn episode() -> Episode {
    // Twelve pedestrians walking away from the robot's line y = 0 at 1 m/s, starting 1.5 m off it.
    let agents = (0..12)
        .map(|i| {
            let x = 0.5 + 0.4 * i as f64;
            let side = if i % 2 == 0 { 1.0 } else { -1.0 };
            AgentTrack {
                id: i,
                start_step: 0,
                positions: (0..130)
                    .map(|k| [x, side * (1.5 + 0.1 * k as f64)])
                    .collect(),
                radius: 0.3,
            }
        })
        .collect();
    Episode {
        id: "bench".into(),
        scene: "bench".into(),
        source: "synthetic".into(),
        scenario: ScenarioClass::CrossFlow,
        dt: 0.1,
        start: Pose2::new(0.0, 0.0, 0.0),
        goal: [5.0, 0.0],
        time_budget: 12.5,
        agents,
        density: 12,
        obstacles: Vec::new(),
        human_path: Vec::new(),
    }
}

fn bench(c: &mut Criterion) {
    let ep = episode();
    let sim = SimConfig::default();
    for name in ["diablo", "go2", "ackermann"] {
        let path = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
            .join("../../robots")
            .join(name)
            .join("robot.toml");
        let robot = RobotSetup::load(&path).expect("workspace robot profile");
        let cfg = StraightConfig {
            speed: robot.limits.v_max,
            accel: 0.8 * robot.limits.a_max,
            ..StraightConfig::default()
        };
        c.bench_function(&format!("sim/episode_straight_{name}"), |b| {
            b.iter(|| {
                let mut p = StraightPlanner::new(cfg.clone()).expect("valid config");
                run_episode(black_box(&ep), &robot, &mut p, &sim)
            })
        });
        if name == "diablo" {
            let mut p = StraightPlanner::new(cfg.clone()).expect("valid config");
            let run = run_episode(&ep, &robot, &mut p, &sim);
            c.bench_function("sim/metrics", |b| {
                b.iter(|| EpisodeMetrics::compute(black_box(&run), &robot.limits))
            });
        }
    }
}

criterion_group!(benches, bench);
criterion_main!(benches);
