//! The `foresight` yardstick of a `human2nav` bench method (`sdk/configs/bench_foresight.toml`,
//! `human2nav_sim::foresight`): share 0 plans as the shipped planner does, to the pose, and
//! share 1 plans with the recorded future of the people in view.

#![allow(clippy::unwrap_used)]

use human2nav_core::robot::footprint::clearance_at;
use human2nav_core::{AgentState, Observation, Pose2};
use human2nav_experiments::bench::human2nav_method;
use human2nav_plugin::PluginHost;
use human2nav_sim::MethodSpec;
use human2nav_sim::PlannerContext;
use human2nav_sim::config::{BenchConfig, MethodConfig};
use human2nav_sim::episode::{AgentTrack, Episode, ScenarioClass};
use std::path::Path;

/// Where the walker below walks up and down (m).
const WALKER_X: f64 = 2.0;

/// A pedestrian observed at (`WALKER_X`, 1.5) walking +y at 1 m/s, away from the robot's straight
/// way to its goal at (5, 0), whose recording turns back then and crosses that way 1.5 s later.
fn turning_walker() -> (Episode, Observation) {
    let mut positions: Vec<[f64; 2]> = (0..=10).map(|k| [WALKER_X, 0.5 + 0.1 * k as f64]).collect();
    positions.extend((1..=40).map(|k| [WALKER_X, (1.5 - 0.1 * k as f64).max(-1.5)]));
    let episode = Episode {
        id: "turning".into(),
        scene: "test/turning".into(),
        source: "synthetic".into(),
        scenario: ScenarioClass::CrossFlow,
        dt: 0.1,
        start: Pose2::IDENTITY,
        goal: [5.0, 0.0],
        time_budget: 12.5,
        agents: vec![AgentTrack {
            id: 3,
            start_step: 0,
            positions,
            radius: 0.3,
        }],
        density: 1,
        obstacles: Vec::new(),
        human_path: Vec::new(),
    };
    let obs = Observation {
        time: 1.0,
        goal: [5.0, 0.0],
        agents: vec![AgentState {
            id: 3,
            position: [WALKER_X, 1.5],
            velocity: [0.0, 1.0],
            radius: 0.3,
            history: Vec::new(),
        }],
        ..Observation::default()
    };
    (episode, obs)
}

#[test]
fn foresight_zero_is_the_shipped_planner_and_full_foresight_sees_the_recording() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    let cfg = BenchConfig::load(&root.join("sdk/configs/bench_foresight.toml")).unwrap();
    let host = PluginHost::new();
    let robots = human2nav_sim::config::load_robots_with(&cfg, &host).unwrap();
    let diablo = robots.iter().find(|r| r.name == "diablo").unwrap();
    let (episode, obs) = turning_walker();
    let ctx = PlannerContext {
        robot: diablo,
        sim: &cfg.sim,
        episode: &episode,
        seed: 5,
    };
    let plan = |spec: &MethodSpec| spec.make(&ctx).unwrap().plan(&obs).unwrap().poses;
    let shipped: MethodConfig = toml::from_str(
        "name = \"shipped\"\nkind = \"human2nav\"\n\
         config = { planner = \"sdk/configs/planner.toml\" }\n",
    )
    .unwrap();
    let shipped = plan(&human2nav_method(&shipped, &cfg).unwrap());
    let methods: Vec<MethodSpec> = cfg
        .methods
        .iter()
        .map(|m| human2nav_method(m, &cfg).unwrap())
        .collect();
    let names: Vec<&str> = methods.iter().map(|m| m.name.as_str()).collect();
    assert_eq!(
        names,
        [
            "foresight-0",
            "foresight-25",
            "foresight-50",
            "foresight-75",
            "foresight-100",
            "foresight-100-within-1.5",
            "foresight-100-within-3",
            "foresight-100-within-5",
            "foresight-100-until-0.5",
            "foresight-100-until-1",
            "foresight-100-until-2",
            "foresight-100-within-3-until-1",
            "foresight-50-within-3-until-1",
        ]
    );
    assert_eq!(plan(&methods[0]), shipped, "share 0 is constant velocity");
    let full = plan(&methods[4]);
    assert_ne!(full, shipped, "the recorded turn changes the plan");
    // Knowing the walker comes back, the plan keeps clear of where it will be at every
    // waypoint (y = 1.5 - 0.1 k, at least -1.5, k steps after the observation); the shipped
    // planner, which expects it to walk on away, plans through it.
    let touches = |plan: &[Pose2]| {
        plan.iter().enumerate().skip(1).any(|(k, p)| {
            let walker = [WALKER_X, (1.5 - 0.1 * k as f64).max(-1.5)];
            clearance_at(&diablo.footprint, *p, walker, 0.3) < 0.0
        })
    };
    assert!(!touches(&full));
    assert!(
        touches(&shipped),
        "without foresight the plan meets the walker"
    );
    // The walker is 2.5 m from the robot: within 3 m it gets the foresight, within 1.5 m not.
    assert_eq!(plan(&methods[6]), full);
    assert_eq!(plan(&methods[5]), shipped);
}
