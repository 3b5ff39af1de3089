//! A small closed loop for the tests of local planners: the robot moves along each plan for one
//! replanning period (it takes the plan's pose one period on, with the body twist that reaches
//! it) while the pedestrians walk on at constant velocity, until it is within 0.3 m of the goal
//! or the time runs out. It measures what the planners' tests assert: whether the goal was
//! reached, the closest approach to people and to static obstacles, and the sharpest turn any
//! plan asked for. It also holds the three limit sets the tests drive (one per motion model).

use human2nav_core::obstacle::Obstacle;
use human2nav_core::{
    AgentState, ControllerGains, Limits, Observation, PlanError, Planner, Pose2, Twist2,
};
use human2nav_plugin::RobotContext;

/// Replanning period of the loop (s); the plans' poses are expected this far apart.
pub const PERIOD: f64 = 0.1;
/// Radius of the robot's disc in the loop (m).
pub const ROBOT_RADIUS: f64 = 0.3;
/// Distance to the goal that counts as reached (m).
pub const REACHED: f64 = 0.3;

/// A differential-drive base (diablo-like; a 0.05 m/s lateral slip tolerance).
pub fn diff_drive() -> Limits {
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

/// An omnidirectional base (go2-like).
pub fn omni() -> Limits {
    Limits {
        v_max: 2.0,
        v_reverse_max: 1.0,
        a_max: 1.5,
        omega_max: 1.8,
        kappa_max: None,
        lateral_speed_max: 0.6,
        coupled: None,
    }
}

/// A car (1.6 m turning radius).
pub fn ackermann() -> Limits {
    Limits {
        v_max: 1.5,
        v_reverse_max: 0.8,
        a_max: 1.0,
        omega_max: 1.0,
        kappa_max: Some(1.0 / 1.6),
        lateral_speed_max: 0.05,
        coupled: None,
    }
}

/// The robot context a planner plugin is created with in the loop.
pub fn robot(limits: Limits) -> RobotContext {
    RobotContext {
        limits,
        gains: ControllerGains::default(),
        footprint_radius: ROBOT_RADIUS,
    }
}

/// A pedestrian of radius 0.3 m without history.
pub fn walker(id: u64, position: [f64; 2], velocity: [f64; 2]) -> AgentState {
    AgentState {
        id,
        position,
        velocity,
        radius: 0.3,
        history: Vec::new(),
    }
}

/// What one run of the loop measured.
#[derive(Clone, Debug, PartialEq)]
pub struct Run {
    pub reached: bool,
    /// Time at the end of the run (s).
    pub time: f64,
    /// Smallest clearance to a pedestrian (centre distance minus both radii) over the run.
    pub min_walker_clearance: f64,
    /// Smallest clearance to the static obstacles over the run.
    pub min_wall_clearance: f64,
    /// Largest |Δθ| / |Δp| between consecutive plan poses of every plan (where |Δp| > 1 mm).
    pub max_plan_curvature: f64,
}

/// A run from the origin, facing the goal.
pub fn drive(
    planner: &mut dyn Planner,
    goal: [f64; 2],
    agents: &[AgentState],
    obstacles: &[Obstacle],
    limit_s: f64,
) -> Result<Run, PlanError> {
    let facing = goal[1].atan2(goal[0]);
    drive_from(planner, facing, goal, agents, obstacles, limit_s)
}

/// A run from the origin with heading `theta`. A planner error, or a plan that is not finite,
/// ends it with an error.
pub fn drive_from(
    planner: &mut dyn Planner,
    theta: f64,
    goal: [f64; 2],
    agents: &[AgentState],
    obstacles: &[Obstacle],
    limit_s: f64,
) -> Result<Run, PlanError> {
    planner.reset();
    let mut pose = Pose2::new(0.0, 0.0, theta);
    let mut velocity = Twist2::ZERO;
    let mut run = Run {
        reached: false,
        time: 0.0,
        min_walker_clearance: f64::INFINITY,
        min_wall_clearance: f64::INFINITY,
        max_plan_curvature: 0.0,
    };
    let steps = (limit_s / PERIOD).round() as usize;
    for k in 0..steps {
        let t = k as f64 * PERIOD;
        let obs = Observation {
            time: t,
            ego: pose,
            ego_velocity: velocity,
            goal,
            agents: agents
                .iter()
                .map(|a| AgentState {
                    position: a.walked_on(t),
                    ..a.clone()
                })
                .collect(),
            obstacles: obstacles.to_vec(),
            ..Default::default()
        };
        let plan = planner.plan(&obs)?;
        if !plan.is_finite() {
            return Err(PlanError::Failed {
                planner: planner.name().to_owned(),
                message: format!("a plan that is not finite at t = {t} s"),
            });
        }
        for w in plan.poses.windows(2) {
            let ds = (w[1].x - w[0].x).hypot(w[1].y - w[0].y);
            if ds > 1e-3 {
                let dth = human2nav_core::se2::wrap_angle(w[1].theta - w[0].theta);
                run.max_plan_curvature = run.max_plan_curvature.max(dth.abs() / ds);
            }
        }
        let next = plan.poses.get(1).copied().unwrap_or(pose);
        let twist = pose.between(next).log();
        velocity = Twist2::new(twist.vx / PERIOD, twist.vy / PERIOD, twist.omega / PERIOD);
        pose = next;
        let p = [pose.x, pose.y];
        for a in agents {
            let q = a.walked_on(t + PERIOD);
            let d = (p[0] - q[0]).hypot(p[1] - q[1]) - ROBOT_RADIUS - a.radius;
            run.min_walker_clearance = run.min_walker_clearance.min(d);
        }
        for o in obstacles {
            run.min_wall_clearance = run.min_wall_clearance.min(o.distance(p) - ROBOT_RADIUS);
        }
        run.time = t + PERIOD;
        if (p[0] - goal[0]).hypot(p[1] - goal[1]) < REACHED {
            run.reached = true;
            break;
        }
    }
    Ok(run)
}

/// The scene the planners' criterion benches time a call on, the same as ORCA's
/// `orca/plan_10_pedestrians`: the robot at the origin at 1 m/s toward a goal 10 m ahead, 10
/// pedestrians on a ring of radius 3 m walking toward its centre at 0.5 m/s.
pub fn ring_of_ten() -> Observation {
    let agents = (0u32..10)
        .map(|i| {
            let a = std::f64::consts::TAU * f64::from(i) / 10.0;
            let p = [3.0 * a.cos(), 3.0 * a.sin()];
            walker(u64::from(i), p, [-0.5 * p[0] / 3.0, -0.5 * p[1] / 3.0])
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
