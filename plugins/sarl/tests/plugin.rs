//! The SARL planner directly and through the plugin host: configuration, the holonomic → plan
//! conversion, and loading the `cdylib` (built by `cargo test` beside this test binary).
//! Needs the shipped weights in `models/sarl` (committed; a missing file fails with its path).

// Helpers outside #[test] functions unwrap too (clippy.toml only allows it inside tests).
#![allow(clippy::unwrap_used)]

use approx::assert_relative_eq;
use human2nav_core::{AgentState, ControllerGains, Limits, Observation, Planner, Pose2, Twist2};
use human2nav_plugin::{PluginHost, RobotContext};
use human2nav_sarl::{SarlConfig, SarlPlanner};
use std::path::{Path, PathBuf};

fn workspace_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

fn model_dir() -> PathBuf {
    let dir = workspace_root().join("models/sarl");
    assert!(
        dir.join("model.safetensors").is_file() && dir.join("model.toml").is_file(),
        "the shipped SARL model is missing from {} (train it with `human2nav baseline train-sarl --config sdk/configs/sarl.toml`)",
        dir.display()
    );
    dir
}

/// The plugin library built beside this test binary (`target/<profile>/libhuman2nav_sarl.so`).
fn library() -> PathBuf {
    std::env::current_exe()
        .ok()
        .and_then(|exe| exe.parent().and_then(Path::parent).map(Path::to_path_buf))
        .unwrap_or_else(|| workspace_root().join("target/debug"))
        .join("human2nav_sarl")
}

fn crowd() -> Observation {
    Observation {
        time: 2.0,
        ego: Pose2::new(1.0, -2.0, 0.4),
        ego_velocity: Twist2 {
            vx: 0.6,
            vy: 0.0,
            omega: 0.1,
        },
        goal: [1.0, 6.0],
        agents: (0..7)
            .map(|i| AgentState {
                id: i,
                position: [-2.0 + i as f64, 0.5 * (i % 3) as f64],
                velocity: [0.3, -0.8 + 0.2 * i as f64],
                radius: 0.3,
                history: Vec::new(),
            })
            .collect(),
        ..Default::default()
    }
}

fn planner() -> SarlPlanner {
    SarlPlanner::from_config(SarlConfig {
        weights: model_dir(),
        ..SarlConfig::default()
    })
    .expect("the shipped model loads")
}

#[test]
fn the_plan_is_the_chosen_velocity_held_constant() {
    let mut p = planner();
    let obs = crowd();
    let v = p.velocity(&obs).unwrap();
    assert!(p.actions().actions.contains(&v));
    let plan = p.plan(&obs).unwrap();
    assert!(plan.is_finite());
    assert_eq!(plan.poses.len(), 32);
    assert_relative_eq!(plan.dt, 0.1);
    assert_eq!(plan.t0, 2.0);
    assert_eq!(plan.poses[0], obs.ego);
    let speed = v[0].hypot(v[1]);
    let heading = if speed >= 0.05 {
        v[1].atan2(v[0])
    } else {
        obs.ego.theta
    };
    for (k, pose) in plan.poses.iter().enumerate().skip(1) {
        let t = k as f64 * 0.1;
        assert_relative_eq!(pose.x, obs.ego.x + t * v[0], epsilon = 1e-12);
        assert_relative_eq!(pose.y, obs.ego.y + t * v[1], epsilon = 1e-12);
        assert_relative_eq!(pose.theta, heading, epsilon = 1e-12);
    }
}

#[test]
fn an_empty_scene_drives_at_the_goal() {
    let mut p = planner();
    let mut obs = crowd();
    obs.agents.clear();
    let (_, humans) = p.states(&obs);
    assert!(humans.is_empty());
    // The goal is due north (8 m): the closed-form empty-world optimum is full speed north.
    let v = p.velocity(&obs).unwrap();
    assert_relative_eq!(v[0], 0.0, epsilon = 1e-12);
    assert_relative_eq!(v[1], 1.0, epsilon = 1e-12);
    assert!(p.plan(&obs).unwrap().is_finite());
    // Off the 16 headings and within one step of the goal: straight at it, landing on it.
    obs.goal = [1.1, -1.85];
    let v = p.velocity(&obs).unwrap();
    assert_relative_eq!(v[0], 0.1 / 0.25, epsilon = 1e-12);
    assert_relative_eq!(v[1], 0.15 / 0.25, epsilon = 1e-12);
}

#[test]
fn only_the_nearest_agents_enter_the_network() {
    let p = SarlPlanner::from_config(SarlConfig {
        weights: model_dir(),
        max_humans: 3,
        ..SarlConfig::default()
    })
    .unwrap();
    let obs = crowd();
    let (robot, humans) = p.states(&obs);
    assert_eq!(humans.len(), 3);
    let d = |x: f64, y: f64| (x - robot.px).hypot(y - robot.py);
    let mut all: Vec<f64> = obs
        .agents
        .iter()
        .map(|a| d(a.position[0], a.position[1]))
        .collect();
    all.sort_by(f64::total_cmp);
    for (h, want) in humans.iter().zip(&all) {
        assert_relative_eq!(d(h.px, h.py), *want, epsilon = 1e-12);
    }
    // The robot's world velocity is its body twist rotated by the heading.
    assert_relative_eq!(robot.vx, 0.6 * 0.4f64.cos(), epsilon = 1e-12);
    assert_relative_eq!(robot.vy, 0.6 * 0.4f64.sin(), epsilon = 1e-12);
}

#[test]
fn configuration_errors_name_the_field_or_file() {
    let err = SarlPlanner::from_config(SarlConfig {
        weights: PathBuf::from("models/no-such-model"),
        ..SarlConfig::default()
    })
    .unwrap_err();
    assert!(err.to_string().contains("no-such-model"), "{err}");
    let err = SarlPlanner::from_config(SarlConfig {
        weights: model_dir(),
        max_speed: -1.0,
        ..SarlConfig::default()
    })
    .unwrap_err();
    assert!(err.to_string().contains("max_speed"), "{err}");
}

fn robot() -> RobotContext {
    RobotContext {
        limits: Limits {
            v_max: 1.5,
            v_reverse_max: 0.0,
            a_max: 1.0,
            omega_max: 2.0,
            kappa_max: None,
            lateral_speed_max: 0.05,
            coupled: None,
        },
        gains: ControllerGains::default(),
        footprint_radius: 0.35,
    }
}

#[test]
fn the_plugin_loads_through_the_host_and_plans() {
    let host = PluginHost::new();
    let lib = host
        .load_library(&library())
        .expect("the sarl cdylib is built beside the tests");
    assert_eq!(lib.name(), "sarl", "the library exports SARL's entry table");
    assert!(lib.factories().iter().any(|f| f.name == "sarl"));
    let config = format!("weights = {:?}", model_dir().display().to_string());
    let mut p = host
        .planner(&library(), "sarl", &config, Some(&robot()))
        .expect("the planner is created");
    assert_eq!(p.name(), "sarl");
    let obs = crowd();
    let plan = p.plan(&obs).unwrap();
    assert!(plan.is_finite());
    assert_eq!(plan.poses.len(), 32);
    // The robot context sets v_pref = v_max = 1.5 m/s: the plan moves at one of its speeds.
    let step = ((plan.poses[2].x - plan.poses[1].x).powi(2)
        + (plan.poses[2].y - plan.poses[1].y).powi(2))
    .sqrt()
        / plan.dt;
    let speeds = human2nav_sarl::action::ActionSpace::crowdnav(1.5).speeds;
    assert!(
        step < 1e-9 || speeds.iter().any(|s| (s - step).abs() < 1e-9),
        "speed {step} is not an action speed"
    );
    // An unknown key is refused with its name.
    let err = host
        .planner(&library(), "sarl", "wieghts = \"x\"", Some(&robot()))
        .unwrap_err();
    assert!(err.to_string().contains("wieghts"), "{err}");
    // A missing model fails at creation, naming the file.
    let err = host
        .planner(&library(), "sarl", "weights = \"models/absent\"", None)
        .unwrap_err();
    assert!(err.to_string().contains("absent"), "{err}");
}
