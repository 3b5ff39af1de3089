//! Plugin constraint terms steer the Human2Nav planner: the workspace-built `personal_space`
//! plugins, in Rust and in C, loaded for real, change which side the robot passes someone on.
//! Run after `cargo build --workspace` (as `sdk/dev.sh test` does).

#![allow(clippy::unwrap_used)] // test helpers outside #[test] functions unwrap too

use human2nav_core::bev::BevSpec;
use human2nav_core::constraint::{ConstraintTerm, Phi};
use human2nav_core::guidance::analytic::FixedWalk;
use human2nav_core::human2nav::{Human2Nav, Human2NavSettings, RobotModel};
use human2nav_core::obstacle::Obstacle;
use human2nav_core::robot::footprint::FootprintShape;
use human2nav_core::{
    AgentState, ControllerGains, GuidanceWeights, Limits, Observation, Plan, Planner, Pose2, Twist2,
};
use human2nav_integration_tests::target_profile_dir;
use human2nav_plugin::{PluginHost, RobotContext};

const LIMITS: Limits = Limits {
    v_max: 1.0,
    v_reverse_max: 0.3,
    a_max: 1.0,
    omega_max: 1.0,
    kappa_max: None,
    lateral_speed_max: 0.05,
    coupled: None,
};

/// The robot is a disc of this radius (m).
const RADIUS: f64 = 0.3;

fn robot(extra: Option<(f64, Box<dyn ConstraintTerm>)>) -> RobotModel {
    let mut phi = Phi::from_weights(&GuidanceWeights::default(), &LIMITS);
    if let Some((w, term)) = extra {
        phi.push(w, term).unwrap();
    }
    RobotModel {
        limits: LIMITS,
        footprint: vec![FootprintShape::Disc {
            center: [0.0, 0.0],
            radius: RADIUS,
        }],
        phi,
    }
}

fn standing(id: u64, x: f64, y: f64) -> AgentState {
    AgentState {
        id,
        position: [x, y],
        velocity: [0.0, 0.0],
        radius: 0.3,
        history: vec![],
    }
}

/// A pillar 2 m ahead on the way to the goal, and the people `beside` it.
fn scene(beside: &[AgentState]) -> Observation {
    Observation {
        time: 0.0,
        ego: Pose2::IDENTITY,
        ego_velocity: Twist2::new(0.5, 0.0, 0.0),
        goal: [8.0, 0.0],
        agents: beside.to_vec(),
        obstacles: vec![Obstacle::Circle {
            center: [2.0, 0.0],
            radius: 0.3,
        }],
        ..Default::default()
    }
}

fn plan(robot: RobotModel, obs: &Observation) -> Plan {
    let mut planner = Human2Nav::new(
        FixedWalk::straight(0.09, 32),
        robot,
        BevSpec::default(),
        Human2NavSettings::default(),
    )
    .unwrap();
    planner.plan(obs).unwrap()
}

/// The side the plan passes on: the sign of its mean lateral offset over the first 2 s.
fn side(plan: &Plan) -> f64 {
    let y: f64 = plan.poses[1..=20].iter().map(|p| p.y).sum::<f64>() / 20.0;
    assert!(
        y.abs() > 0.05,
        "the plan must pass on a side: mean y {y}, {:?}",
        plan.info.notes
    );
    y.signum()
}

/// A personal-space plugin term of 1 m (`library`, factory `name`).
fn personal_space(library: &str, name: &str) -> Box<dyn ConstraintTerm> {
    let robot = RobotContext {
        limits: LIMITS,
        gains: ControllerGains {
            k_x: 1.5,
            k_y: 4.0,
            k_theta: 3.0,
            k_d: 0.2,
            lookahead: 0.05,
        },
        footprint_radius: RADIUS,
    };
    let term = PluginHost::new()
        .constraint(
            &target_profile_dir().join(library),
            name,
            "personal_space = 1.0",
            Some(&robot),
        )
        .unwrap_or_else(|e| panic!("{e}: build the workspace first (`cargo build --workspace`)"));
    Box::new(term)
}

#[test]
fn a_personal_space_plugin_makes_the_robot_pass_on_the_roomier_side() {
    // Alone, the pillar ahead is passed on one side. A person stands 2.8 m off the line on
    // that side: beyond the clearance term's 0.5 m margin from the way the robot took, so
    // without the plugin the plan stays; the plugin (which sees people, not pillars) wants
    // 1 m of personal space and makes the robot take the other side.
    let free = side(&plan(robot(None), &scene(&[])));
    let crowded = scene(&[standing(2, 2.0, 2.8 * free)]);
    assert_eq!(side(&plan(robot(None), &crowded)), free);
    for (library, name) in [
        ("human2nav_personal_space", "personal_space"),
        ("human2nav_c_personal_space", "personal_space_c"),
    ] {
        let zero = plan(robot(Some((0.0, personal_space(library, name)))), &crowded);
        assert_eq!(side(&zero), free, "{library} at weight 0 changes nothing");
        let on = plan(robot(Some((1.0, personal_space(library, name)))), &crowded);
        assert_eq!(
            side(&on),
            -free,
            "{library}: the plan should pass on the side with room: {:?}",
            on.info.notes
        );
    }
}
