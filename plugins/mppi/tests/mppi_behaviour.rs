//! MPPI in closed loop: the robot is moved along each plan for one replanning period (the
//! plan's pose at 0.1 s and the body twist that reaches it), then plans again.

use human2nav_core::obstacle::{Obstacle, OccupancyGrid};
use human2nav_core::{AgentState, Limits, Observation, Planner, Pose2, Twist2};
use human2nav_mppi::{MotionModel, MppiConfig, MppiPlanner};
use human2nav_plugin::{InitError, PluginInit};

use human2nav_local_core::closed_loop::{self, Run, ackermann, diff_drive, omni, robot, walker};

fn planner(limits: Limits, config: &str) -> MppiPlanner {
    MppiPlanner::from_init(&PluginInit::new(config, Some(robot(limits)))).expect("valid config")
}

fn drive(
    planner: &mut dyn Planner,
    goal: [f64; 2],
    agents: &[AgentState],
    obstacles: &[Obstacle],
    limit_s: f64,
) -> Run {
    closed_loop::drive(planner, goal, agents, obstacles, limit_s).expect("plans")
}

fn drive_from(
    planner: &mut dyn Planner,
    theta: f64,
    goal: [f64; 2],
    agents: &[AgentState],
    obstacles: &[Obstacle],
    limit_s: f64,
) -> Run {
    closed_loop::drive_from(planner, theta, goal, agents, obstacles, limit_s).expect("plans")
}

#[test]
fn every_motion_model_reaches_a_goal_8_m_away_in_an_empty_world() {
    for (limits, model) in [
        (diff_drive(), MotionModel::DiffDrive),
        (omni(), MotionModel::Omni),
        (
            ackermann(),
            MotionModel::Ackermann {
                kappa_max: 1.0 / 1.6,
            },
        ),
    ] {
        let mut p = planner(limits, "");
        assert_eq!(p.bounds().model, model);
        let run = drive(&mut p, [8.0, 0.0], &[], &[], 15.0);
        assert!(
            run.reached,
            "{model:?}: not at the goal after {} s",
            run.time
        );
        // 8 m at up to 1.5 m/s from rest: at least 5.3 s; well within twice that.
        assert!(run.time < 11.0, "{model:?}: {} s", run.time);
    }
}

#[test]
fn a_goal_off_to_the_side_is_reached_too() {
    for limits in [diff_drive(), omni(), ackermann()] {
        let mut p = planner(limits, "");
        // Starts facing the goal's direction; the goal is 8 m away diagonally.
        let run = drive(&mut p, [5.0, 6.0], &[], &[], 20.0);
        assert!(run.reached, "{:?}: {} s", p.bounds().model, run.time);
    }
}

#[test]
fn two_crossing_pedestrians_are_avoided() {
    // One walks up across the robot's line at x = 3, the other down at x = 5.5, timed to be
    // on the line when a robot driving straight at full speed would be there.
    let agents = [
        walker(1, [3.0, -2.5], [0.0, 1.0]),
        walker(2, [5.5, 4.0], [0.0, -1.0]),
    ];
    for limits in [diff_drive(), omni(), ackermann()] {
        let mut p = planner(limits, "");
        let run = drive(&mut p, [8.0, 0.0], &agents, &[], 20.0);
        assert!(run.reached, "{:?}: {} s", p.bounds().model, run.time);
        assert!(
            run.min_walker_clearance > 0.05,
            "{:?}: clearance {}",
            p.bounds().model,
            run.min_walker_clearance
        );
    }
    // The straight line would have hit the first one: the test scene does interact.
    let straight_hits = (0..80).any(|k| {
        let t = k as f64 * 0.1;
        let x = (0.5 * t * t).min(1.5 * t - 1.125); // a_max 1, v_max 1.5
        let q = agents[0].walked_on(t);
        (x - q[0]).hypot(q[1]) < 0.6
    });
    assert!(straight_hits);
}

#[test]
fn a_wall_and_a_pillar_between_robot_and_goal_are_driven_around() {
    let wall = [Obstacle::Segment {
        a: [4.0, -1.0],
        b: [4.0, 1.0],
    }];
    let pillar = [Obstacle::Circle {
        center: [4.0, 0.0],
        radius: 0.6,
    }];
    for obstacles in [&wall[..], &pillar[..]] {
        for limits in [diff_drive(), omni()] {
            let mut p = planner(limits, "");
            let run = drive(&mut p, [8.0, 0.0], &[], obstacles, 25.0);
            assert!(
                run.reached,
                "{:?} {obstacles:?}: {} s",
                p.bounds().model,
                run.time
            );
            assert!(
                run.min_wall_clearance > 0.0,
                "{:?}: clearance {}",
                p.bounds().model,
                run.min_wall_clearance
            );
        }
    }
}

#[test]
fn the_ackermann_plans_never_exceed_the_curvature() {
    let kappa = 1.0 / 1.6;
    let mut p = planner(ackermann(), "");
    // Facing +x, a goal at (2, 4): the circle tangent to the heading through the goal has a
    // radius of 2.5 m, so the robot must turn at least at curvature 0.4 somewhere.
    let run = drive_from(&mut p, 0.0, [2.0, 4.0], &[], &[], 15.0);
    assert!(run.max_plan_curvature > 0.35, "it did turn");
    assert!(
        run.max_plan_curvature <= kappa * 1.001,
        "plan curvature {} > {kappa}",
        run.max_plan_curvature
    );
    for u in p.controls() {
        assert!(u[2].abs() <= kappa * u[0].abs() + 1e-12, "{u:?}");
        assert_eq!(u[1], 0.0);
    }
}

#[test]
fn the_critics_see_walls_polygons_occupied_cells_and_walking_pedestrians() {
    let p = planner(diff_drive(), "");
    let straight = vec![[1.0, 0.0, 0.0]; 28];
    let obs = |obstacles: Vec<Obstacle>, occupancy, agents| Observation {
        ego: Pose2::new(0.0, 0.0, 0.0),
        ego_velocity: Twist2::new(1.0, 0.0, 0.0),
        goal: [8.0, 0.0],
        obstacles,
        occupancy,
        agents,
        ..Default::default()
    };
    let (free, hit) = p.evaluate(&obs(vec![], None, vec![]), &straight);
    assert!(!hit);
    let wall = Obstacle::Segment {
        a: [2.0, -1.0],
        b: [2.0, 1.0],
    };
    let square = Obstacle::Polygon {
        vertices: vec![[2.0, -0.5], [2.5, -0.5], [2.5, 0.5], [2.0, 0.5]],
    };
    for o in [wall, square] {
        let (cost, hit) = p.evaluate(&obs(vec![o.clone()], None, vec![]), &straight);
        assert!(hit && cost > free + 1000.0, "{o:?}");
    }
    let mut data = vec![0i8; 40 * 40];
    data[20 * 40 + 20] = 100; // the cell at (2.0..2.1, 0.0..0.1)
    let grid = OccupancyGrid {
        origin: Pose2::new(0.0, -2.0, 0.0),
        resolution: 0.1,
        width: 40,
        height: 40,
        data,
        occupied_threshold: 65,
    };
    let (_, hit) = p.evaluate(&obs(vec![], Some(grid), vec![]), &straight);
    assert!(hit, "the occupied cell at (2.05, 0.05) is on the path");
    // From 1 m/s at 1 m/s the robot is at x = 2 at t = 2 s: a pedestrian crossing the line
    // there at that time collides, one walking away does not.
    let crossing = walker(1, [2.0, -2.0], [0.0, 1.0]);
    let (_, hit) = p.evaluate(&obs(vec![], None, vec![crossing]), &straight);
    assert!(
        hit,
        "constant-velocity prediction puts the pedestrian on the line at t = 2 s"
    );
    let leaving = walker(1, [2.0, -2.0], [0.0, -1.0]);
    let (_, hit) = p.evaluate(&obs(vec![], None, vec![leaving]), &straight);
    assert!(!hit);
}

#[test]
fn a_reset_replays_the_same_plans() {
    let agents = [walker(1, [3.0, -2.5], [0.0, 1.0])];
    let mut p = planner(diff_drive(), "seed = 3");
    let a = drive(&mut p, [8.0, 0.0], &agents, &[], 12.0);
    let b = drive(&mut p, [8.0, 0.0], &agents, &[], 12.0);
    assert_eq!(a.time, b.time);
    assert_eq!(a.min_walker_clearance, b.min_walker_clearance);
}

#[test]
fn robot_defaults_apply_unless_the_config_sets_the_key() {
    let p = planner(diff_drive(), "");
    assert_eq!(p.radius(), 0.3);
    assert_eq!(p.bounds().vx_max, 1.5);
    assert_eq!(p.bounds().vx_min, -0.5);
    // Nav2's noise-to-limit ratios: 0.2 of 0.5 m/s, 0.4 of 1.9 rad/s.
    let std = p.noise_std();
    assert!((std[0] - 0.6).abs() < 1e-12 && std[1] == 0.0, "{std:?}");
    assert!((std[2] - 0.4 / 1.9 * 2.0).abs() < 1e-12, "{std:?}");
    let p = planner(diff_drive(), "radius = 0.5\nvx_max = 1.0\nvx_min = 0.0");
    assert_eq!(p.radius(), 0.5);
    assert_eq!(p.bounds().vx_max, 1.0);
    assert_eq!(p.bounds().vx_min, 0.0);
    // Without a robot: Nav2's defaults, differential drive.
    let p = MppiPlanner::new(MppiConfig::default(), None).unwrap();
    assert_eq!(p.bounds().model, MotionModel::DiffDrive);
    assert_eq!(p.bounds().vx_max, 0.5);
    assert_eq!(p.config().batch_size, 1000);
    let std = p.noise_std();
    assert!(
        (std[0] - 0.2).abs() < 1e-12 && (std[2] - 0.4).abs() < 1e-12,
        "{std:?}"
    );
}

#[test]
fn bad_configs_are_refused_naming_the_key() {
    let cases = [
        ("batch_size = 0", "batch_size"),
        ("time_steps = 0", "time_steps"),
        ("iteration_count = 0", "iteration_count"),
        ("model_dt = 0.0", "model_dt"),
        ("model_dt = -0.1", "model_dt"),
        ("model_dt = nan", "model_dt"),
        ("temperature = 0.0", "temperature"),
        ("temperature = -1.0", "temperature"),
        ("vx_std = -0.1", "vx_std"),
        ("wz_std = inf", "wz_std"),
        ("vx_max = 0.0", "vx_max"),
        ("vx_min = 0.5", "vx_min"),
        ("kappa_max = 0.0", "kappa_max"),
        ("radius = -1.0", "radius"),
        ("gamma = -0.1", "gamma"),
        ("collision_cost = nan", "collision_cost"),
        ("batch_size = 100000\ntime_steps = 1000", "batch_size"),
    ];
    for (config, key) in cases {
        let err = MppiPlanner::from_init(&PluginInit::new(config, Some(robot(diff_drive()))))
            .expect_err(config);
        match &err {
            InitError::Invalid { field, .. } => assert_eq!(field, key, "{config}: {err}"),
            other => panic!("{config}: expected an invalid `{key}`, got {other}"),
        }
    }
    // Unknown keys: refused by the parser, naming the key.
    let err = MppiPlanner::from_init(&PluginInit::new("batch_sise = 10", None)).unwrap_err();
    assert!(
        err.is_config() && err.to_string().contains("batch_sise"),
        "{err}"
    );
    let err = MppiPlanner::from_init(&PluginInit::new("batch_size = -5", None)).unwrap_err();
    assert!(matches!(err, InitError::Parse { .. }), "{err}");
}

#[test]
fn a_robot_that_cannot_drive_is_refused_with_the_reason() {
    let stuck = Limits {
        omega_max: 0.0,
        ..diff_drive()
    };
    let err = MppiPlanner::from_init(&PluginInit::new("", Some(robot(stuck)))).unwrap_err();
    let text = err.to_string();
    assert!(
        text.contains("cannot drive") && text.contains("omega_max"),
        "{text}"
    );
}

#[test]
fn degenerate_observations_give_finite_plans() {
    let mut p = planner(ackermann(), "");
    // At the goal, at rest, a pedestrian on top of the robot.
    let obs = Observation {
        goal: [0.0, 0.0],
        agents: vec![walker(1, [0.0, 0.0], [0.0, 0.0])],
        ..Default::default()
    };
    let plan = p.plan(&obs).unwrap();
    assert!(plan.is_finite());
    assert_eq!(plan.poses.len(), 29);
    // Time running backwards (a new episode without reset) restarts the warm start.
    let later = Observation {
        time: 5.0,
        ..obs.clone()
    };
    p.plan(&later).unwrap();
    assert!(p.plan(&obs).unwrap().is_finite());
    let bad = Observation {
        goal: [f64::NAN, 0.0],
        ..obs
    };
    assert!(p.plan(&bad).is_err());
}
