//! The reference planner on analytic flow models: frames, guidance on/off, determinism and the
//! safe fallback.

#![allow(clippy::unwrap_used)] // test helpers outside #[test] functions unwrap too

mod common;

use approx::assert_relative_eq;
use human2nav_core::ablation::Arm;
use human2nav_core::bev::BevSpec;
use human2nav_core::flow::{FlowCondition, FlowError, FlowModel};
use human2nav_core::forecast::{CrowdPredictor, Forecast, ForecastError, constant_velocity_path};
use human2nav_core::guidance::analytic::FixedWalk;
use human2nav_core::guidance::{GuidanceVariant, PaperSettings};
use human2nav_core::human2nav::{
    GuidanceTerms, Human2Nav, Human2NavSettings, RobotModel, SelectionWeights, pose_at,
};
use human2nav_core::obstacle::{Obstacle, OccupancyGrid, footprint_clearance};
use human2nav_core::tfs::tfs_plan;
use human2nav_core::{AgentState, Deadline, Observation, Plan, Planner, Pose2, Stage, Twist2};
use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::{Duration, Instant};

use common::{ROBOT_RADIUS, limits, robot};

/// A "human" future the robot cannot follow: straight ahead at 1.6 m/s, 32 poses at 0.1 s.
///
/// The field is `f_k = log(target_k)` for every sample and time, started from (almost) the
/// identity, so the plain rollout lands on the target and any steering survives to the end:
/// the behaviour of a trained field whose data has spread, unlike a field that snaps every
/// sample onto one fixed target.
type HumanFuture = FixedWalk;

fn fast_straight() -> HumanFuture {
    FixedWalk::straight(0.16, 32)
}

fn observation() -> Observation {
    Observation {
        time: 2.0,
        ego: Pose2::new(3.0, -1.0, 0.7),
        ego_velocity: Twist2::new(0.8, 0.0, 0.0),
        goal: [10.0, 5.0],
        agents: vec![AgentState {
            id: 7,
            position: [6.0, 2.0],
            velocity: [-0.5, 0.0],
            radius: 0.25,
            history: vec![],
        }],
        ..Default::default()
    }
}

/// The shipped planner, or (`shipped = false`) the raw samples of the guidance ablation.
fn planner(shipped: bool) -> Human2Nav<HumanFuture> {
    let settings = if shipped {
        Human2NavSettings::default()
    } else {
        Arm::Raw.settings(&Human2NavSettings::default())
    };
    Human2Nav::new(fast_straight(), robot(), BevSpec::default(), settings).unwrap()
}

/// The plan relative to the ego pose, as the TFS helper wants it.
fn ego_frame(plan: &[Pose2], ego: Pose2) -> Vec<Pose2> {
    plan.iter().map(|p| ego.between(*p)).collect()
}

#[test]
fn plan_starts_at_the_robot_and_is_in_the_world_frame() {
    let obs = observation();
    let plan = planner(false).plan(&obs).unwrap();
    assert_eq!(plan.poses.len(), 33);
    assert_relative_eq!(plan.t0, obs.time);
    assert_relative_eq!(plan.dt, 0.1);
    assert_eq!(plan.poses[0], obs.ego);
    // Unguided, the rollout lands on the human future: 0.16 m per step straight ahead in the
    // ego frame (up to the 1e-4 source noise).
    let last = obs.ego.between(plan.poses[32]);
    assert_relative_eq!(last.x, 0.16 * 32.0, epsilon = 1e-3);
    assert_relative_eq!(last.y, 0.0, epsilon = 1e-3);
    assert!(!plan.info.fallback);
    assert_eq!(
        plan.info.candidates.len(),
        Human2NavSettings::default().samples
    );
    assert!(plan.info.guided.is_empty());
}

/// TFS of the plans of the unguided planner and of `guided`, and Φ before/after Algorithm 1.
fn tfs_pair(guided: &mut Human2Nav<HumanFuture>) -> (f64, f64, f64, f64, usize) {
    let obs = observation();
    let unguided = planner(false).plan(&obs).unwrap();
    let plan = guided.plan(&obs).unwrap();
    let tfs = |p: &[Pose2]| tfs_plan(&ego_frame(p, obs.ego), 0.1, &limits(), obs.ego_velocity);
    (
        tfs(&unguided.poses),
        tfs(&plan.poses),
        plan.info.phi_before.unwrap(),
        plan.info.phi_after.unwrap(),
        plan.info.guided.len(),
    )
}

#[test]
fn algorithm_1_alone_makes_an_infeasible_human_trajectory_feasible() {
    let mut settings = Human2NavSettings {
        samples: 16,
        guided_samples: 0,
        motions: 0,
        ..Default::default()
    };
    settings.projection.enabled = false;
    settings.guidance.enabled = true;
    // Φ of the robot's limits alone, as in the paper: the straight future runs into the
    // pedestrian, and the clearance term's contact penalty is not what this test is about.
    settings.selection.clearance = 0.0;
    // The preconditioned direction: a uniform over-speed is what it removes and the plain
    // gradient (the shipped default) does not (guidance module docs).
    settings.guidance.precondition = true;
    settings.guidance.steps_n = 10;
    settings.guidance.iterations_m = 8;
    settings.guidance.learning_rate = 0.03;
    let mut p = Human2Nav::new(fast_straight(), robot(), BevSpec::default(), settings).unwrap();
    let (tfs_u, tfs_g, before, after, guided) = tfs_pair(&mut p);
    eprintln!("TFS unguided {tfs_u:.3}, guided {tfs_g:.3}; Φ {before:.4} → {after:.4}");
    assert!(
        tfs_u < 0.1,
        "1.6 m/s everywhere must violate v_max = 1 m/s (TFS {tfs_u})"
    );
    assert!(tfs_g >= 0.95, "guided TFS {tfs_g}");
    assert!(after < 0.1 * before, "Φ {before} → {after}");
    assert_eq!(guided, 16, "guided_samples = 0 guides every sample");
}

#[test]
fn algorithm_1_and_the_correction_guide_a_shortlist_and_end_feasible() {
    // 16 samples (the default is 4, all of them shortlisted), so that the shortlist is one.
    let settings = Arm::Both.settings(&Human2NavSettings {
        samples: 16,
        ..Default::default()
    });
    let mut p = Human2Nav::new(fast_straight(), robot(), BevSpec::default(), settings).unwrap();
    let (tfs_u, tfs_g, before, after, guided) = tfs_pair(&mut p);
    assert!(tfs_u < 0.1, "unguided TFS {tfs_u}");
    assert_eq!(tfs_g, 1.0, "Algorithm 1 + last-step correction");
    // The adaptive step never lets Φ rise (on a uniform over-speed the plain gradient barely
    // moves it; the correction makes the plan feasible).
    assert!(after <= before, "Φ {before} → {after}");
    assert_eq!(guided, Human2NavSettings::default().guided_samples);
}

#[test]
fn the_paper_variant_guides_every_sample() {
    let mut settings = Arm::Both.settings(&Human2NavSettings::default());
    settings.guidance.variant = GuidanceVariant::Paper;
    settings.samples = 16;
    assert_eq!(settings.guided_samples, 4);
    let mut p = Human2Nav::new(fast_straight(), robot(), BevSpec::default(), settings).unwrap();
    let (_, tfs_g, before, after, guided) = tfs_pair(&mut p);
    assert_eq!(guided, 16, "the paper variant ignores guided_samples");
    assert!(
        before.is_finite() && after.is_finite(),
        "Φ {before} → {after}"
    );
    assert_eq!(tfs_g, 1.0, "Algorithm 1 + last-step correction");
}

#[test]
fn the_shipped_planner_table_parses_and_validates() {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs/planner.toml");
    let text = std::fs::read_to_string(&path).unwrap();
    let mut table: toml::Table = toml::from_str(&text).unwrap();
    let settings: Human2NavSettings = table.remove("human2nav").unwrap().try_into().unwrap();
    settings.validate().unwrap();
    // One source of truth: the code's defaults are the shipped planner's settings.
    assert_eq!(settings, Human2NavSettings::default());
    assert_eq!(settings.guidance.variant, GuidanceVariant::Adaptive);
    // The commented [human2nav.guidance.paper] table holds the core defaults.
    assert_eq!(settings.guidance.paper, PaperSettings::default());
}

#[test]
fn huge_counts_in_the_planner_table_are_errors_naming_the_field() {
    use human2nav_core::human2nav::MAX_SAMPLES;
    for (text, field) in [
        ("samples = 100000", "human2nav.samples"),
        ("guided_samples = 100000", "human2nav.guided_samples"),
        ("[guidance]\niterations_m = 1000000000", "`iterations_m`"),
        ("[guidance]\nsteps_n = 5000", "`steps_n`"),
        ("[projection]\niterations = 1000000", "`iterations`"),
    ] {
        let settings: Human2NavSettings = toml::from_str(text).unwrap();
        match settings.validate() {
            Err(e) => {
                let msg = e.to_string();
                assert!(msg.contains(field), "{text}: {msg}");
            }
            Ok(()) => panic!("{text} was accepted"),
        }
    }
    let most = Human2NavSettings {
        samples: MAX_SAMPLES,
        guided_samples: MAX_SAMPLES,
        ..Human2NavSettings::default()
    };
    assert!(most.validate().is_ok());
}

#[test]
fn same_seed_same_plan_after_reset() {
    let obs = observation();
    let mut p = planner(true);
    let a = p.plan(&obs).unwrap();
    p.reset();
    let b = p.plan(&obs).unwrap();
    assert_eq!(a.poses, b.poses);
}

#[test]
fn warm_start_keeps_the_previous_plan_available() {
    let mut p = planner(true);
    let obs = observation();
    let first = p.plan(&obs).unwrap();
    // A tenth of a second later, on the previous plan.
    let mut next = obs.clone();
    next.time += 0.1;
    next.ego = pose_at(&first, next.time);
    let second = p.plan(&next).unwrap();
    assert!(second.is_finite());
    // `selected` names the source sample of the plan (`None`: the shifted previous plan).
    assert!(second.info.selected.is_none_or(|i| i < 16));
}

#[test]
fn non_finite_observation_is_an_error() {
    let mut obs = observation();
    obs.goal[1] = f64::NAN;
    let err = planner(true).plan(&obs).unwrap_err();
    assert!(err.to_string().contains("goal"), "{err}");
}

/// A pose 1e300 m away or a speed of 100 m/s is a unit error, refused by name for every front
/// end (they all plan through `Observation::validate`).
#[test]
fn an_observation_beyond_the_bounds_is_an_error_naming_the_field() {
    type Spoil = fn(&mut Observation);
    let cases: [(&str, Spoil); 4] = [
        ("ego pose", |o| o.ego = Pose2::new(1e300, 0.0, 0.0)),
        ("ego velocity", |o| {
            o.ego_velocity = Twist2::new(100.0, 0.0, 0.0)
        }),
        ("goal", |o| o.goal = [0.0, -2e6]),
        ("agent 7", |o| o.agents[0].velocity = [0.0, 100.0]),
    ];
    for (field, spoil) in cases {
        let mut obs = observation();
        spoil(&mut obs);
        let err = planner(true).plan(&obs).unwrap_err();
        assert!(err.to_string().contains(field), "{field}: {err}");
    }
}

/// A robot that starts overlapping an obstacle, or faster than its limits (but within what an
/// observation may hold), still gets a plan, flagged in `PlanInfo::warnings`; an ordinary start
/// gets none.
#[test]
fn a_start_inside_an_obstacle_or_beyond_the_limits_is_flagged() {
    let plain = planner(true).plan(&observation()).unwrap();
    assert!(plain.info.warnings.is_empty(), "{:?}", plain.info.warnings);
    let mut inside = observation();
    inside.obstacles = vec![Obstacle::Circle {
        center: [3.1, -1.0],
        radius: 0.5,
    }];
    let plan = planner(true).plan(&inside).unwrap();
    assert!(plan.is_finite());
    assert!(
        plan.info
            .warnings
            .iter()
            .any(|w| w.contains("inside obstacles[0]")),
        "{:?}",
        plan.info.warnings
    );
    let mut fast = observation();
    fast.ego_velocity = Twist2::new(5.0, 0.0, 0.0);
    let plan = planner(true).plan(&fast).unwrap();
    assert!(plan.is_finite());
    assert!(
        plan.info
            .warnings
            .iter()
            .any(|w| w.contains("forward speed of 5.000")),
        "{:?}",
        plan.info.warnings
    );
}

/// A model whose output is NaN: the planner must stop in place, never pass the NaN on.
struct Broken;

impl FlowModel for Broken {
    fn horizon(&self) -> usize {
        32
    }
    fn velocity(
        &self,
        _: &[f64],
        _: f64,
        _: &FlowCondition,
        out: &mut [f64],
    ) -> Result<(), FlowError> {
        out.fill(f64::NAN);
        Ok(())
    }
    fn velocity_vjp(
        &self,
        x: &[f64],
        t: f64,
        c: &FlowCondition,
        _: &[f64],
        out: &mut [f64],
        vjp: &mut [f64],
    ) -> Result<(), FlowError> {
        vjp.fill(f64::NAN);
        self.velocity(x, t, c, out)
    }
}

#[test]
fn a_broken_model_gives_the_stop_in_place_fallback() {
    let obs = observation();
    let mut p = Human2Nav::new(
        Broken,
        robot(),
        BevSpec::default(),
        Human2NavSettings::default(),
    )
    .unwrap();
    let plan = p.plan(&obs).unwrap();
    assert!(plan.is_finite());
    assert!(plan.info.fallback);
    assert!(plan.poses.iter().all(|q| *q == obs.ego));
    assert!(!plan.info.notes.is_empty());
}

#[test]
fn invalid_settings_name_the_field() {
    let settings = Human2NavSettings {
        samples: human2nav_core::human2nav::MAX_SAMPLES + 1,
        ..Human2NavSettings::default()
    };
    let err = Human2Nav::new(fast_straight(), robot(), BevSpec::default(), settings).unwrap_err();
    assert!(err.to_string().contains("samples"), "{err}");
}

#[test]
fn a_robot_without_a_footprint_is_an_error() {
    let robot = RobotModel {
        footprint: Vec::new(),
        ..robot()
    };
    let err = Human2Nav::new(
        fast_straight(),
        robot,
        BevSpec::default(),
        Human2NavSettings::default(),
    )
    .unwrap_err();
    assert!(err.to_string().contains("footprint"), "{err}");
}

#[test]
fn time_scaling_keeps_the_path_and_scales_the_speed() {
    use human2nav_core::human2nav::time_scaled;
    // 1 m/s straight ahead, then a quarter turn at the end.
    let mut traj: Vec<Pose2> = (1..=10)
        .map(|k| Pose2::new(0.1 * k as f64, 0.0, 0.0))
        .collect();
    traj.push(Pose2::new(1.1, 0.0, 0.5));
    assert_eq!(time_scaled(&traj, 1.0), traj);
    let half = time_scaled(&traj, 0.5);
    assert_eq!(half.len(), traj.len());
    for (j, p) in half.iter().take(10).enumerate() {
        assert_relative_eq!(p.x, 0.05 * (j + 1) as f64, epsilon = 1e-12);
        assert_relative_eq!(p.y, 0.0, epsilon = 1e-12);
    }
    // Half the time covers half the path: the turn at the end is not reached.
    assert_relative_eq!(half[10].x, 0.55, epsilon = 1e-12);
    assert!(
        time_scaled(&traj, 0.0)
            .iter()
            .all(|p| *p == Pose2::IDENTITY)
    );
}

/// The robot drives along +x at 0.8 m/s toward a pedestrian standing 1.3 m ahead (contact at
/// 0.6 m between centres); braking at a_max stops it after 0.32 m.
fn blocked() -> Observation {
    Observation {
        time: 0.0,
        ego: Pose2::IDENTITY,
        ego_velocity: Twist2::new(0.8, 0.0, 0.0),
        goal: [8.0, 0.0],
        agents: vec![AgentState {
            id: 1,
            position: [1.3, 0.0],
            velocity: [0.0, 0.0],
            radius: 0.3,
            history: vec![],
        }],
        ..Default::default()
    }
}

/// The smallest predicted gap between the plan's footprint and the pedestrian of `obs`.
fn predicted_gap(plan: &[Pose2], obs: &Observation) -> f64 {
    let a = &obs.agents[0];
    plan.iter()
        .enumerate()
        .map(|(j, p)| {
            let t = j as f64 * 0.1;
            let (ax, ay) = (
                a.position[0] + a.velocity[0] * t,
                a.position[1] + a.velocity[1] * t,
            );
            (p.x - ax).hypot(p.y - ay) - ROBOT_RADIUS - a.radius
        })
        .fold(f64::INFINITY, f64::min)
}

#[test]
fn a_pedestrian_in_the_way_makes_the_planner_stop_instead_of_driving_into_them() {
    let obs = blocked();
    // Without the slowed copies and the stop candidate every candidate drives straight at
    // the model's pace (corrected to v_max): through the pedestrian. (The robot's own motions
    // are off here; `the_robots_own_motions_steer_round_what_the_samples_run_into` has them.)
    let only_samples = Human2NavSettings {
        slowdown: 1.0,
        stop_candidate: false,
        warm_start: false,
        motions: 0,
        ..Default::default()
    };
    let through = Human2Nav::new(fast_straight(), robot(), BevSpec::default(), only_samples)
        .unwrap()
        .plan(&obs)
        .unwrap();
    let gap_through = predicted_gap(&through.poses, &obs);
    assert!(gap_through < 0.0, "gap {gap_through}");
    // With them, the planner brakes in front of the pedestrian.
    let with_stop = Human2NavSettings {
        motions: 0,
        ..Default::default()
    };
    let stops = Human2Nav::new(fast_straight(), robot(), BevSpec::default(), with_stop)
        .unwrap()
        .plan(&obs)
        .unwrap();
    let gap = predicted_gap(&stops.poses, &obs);
    assert!(gap > 0.0, "gap {gap}; notes {:?}", stops.info.notes);
    assert!(
        stops.info.notes.iter().any(|n| n == "braking to a stop"),
        "{:?}",
        stops.info.notes
    );
    assert_eq!(stops.info.selected, None);
    // Within the limits from the current velocity: the correction turned "stand here" into
    // braking.
    let ego = ego_frame(&stops.poses, obs.ego);
    assert_eq!(tfs_plan(&ego, 0.1, &limits(), obs.ego_velocity), 1.0);
    assert!(stops.poses[32].x > 0.25 && stops.poses[32].x < 0.6);
}

/// The planner's default settings with `selection`.
fn selecting(selection: SelectionWeights) -> Human2NavSettings {
    Human2NavSettings {
        selection,
        ..Default::default()
    }
}

/// The collision penalty is what stops the robot short of a pedestrian it predicts: without
/// it a contact costs only the clearance of the waypoints before it, and driving through wins
/// on progress. A penalty that is not a finite number ≥ 0 is refused, naming the field.
#[test]
fn the_collision_penalty_is_what_makes_the_planner_brake() {
    use human2nav_core::human2nav::COLLISION_PENALTY;
    let obs = blocked();
    let with = |collision: f64| {
        let settings = Human2NavSettings {
            motions: 0,
            ..selecting(SelectionWeights {
                collision,
                ..SelectionWeights::default()
            })
        };
        Human2Nav::new(fast_straight(), robot(), BevSpec::default(), settings)
    };
    assert_eq!(SelectionWeights::default().collision, COLLISION_PENALTY);
    let brakes = with(COLLISION_PENALTY).unwrap().plan(&obs).unwrap();
    assert!(predicted_gap(&brakes.poses, &obs) > 0.0);
    let through = with(0.0).unwrap().plan(&obs).unwrap();
    let gap = predicted_gap(&through.poses, &obs);
    assert!(gap < 0.0, "gap {gap}; notes {:?}", through.info.notes);
    for bad in [f64::NAN, f64::INFINITY, -1.0] {
        let err = with(bad).unwrap_err().to_string();
        assert!(err.contains("selection.collision"), "{bad}: {err}");
    }
}

/// The robot at rest, its goal 8 m ahead, and someone at `x` m on its line walking toward it
/// at 0.8 m/s.
fn oncoming(x: f64) -> Observation {
    Observation {
        time: 0.0,
        ego: Pose2::IDENTITY,
        ego_velocity: Twist2::new(0.0, 0.0, 0.0),
        goal: [8.0, 0.0],
        agents: vec![AgentState {
            id: 1,
            position: [x, 0.0],
            velocity: [-0.8, 0.0],
            radius: 0.3,
            history: vec![],
        }],
        ..Default::default()
    }
}

/// The plan for `obs` of the planner with the default settings but `selection`.
fn plan_selecting(selection: SelectionWeights, obs: &Observation) -> Plan {
    Human2Nav::new(
        fast_straight(),
        robot(),
        BevSpec::default(),
        selecting(selection),
    )
    .unwrap()
    .plan(obs)
    .unwrap()
}

/// Someone walks down the robot's line toward it, far enough that a plan driving at the goal
/// ends just short of them. With a hold the selection also checks each plan standing at its
/// end for that long, sees the contact that follows, and picks a plan that leaves their path.
#[test]
fn a_hold_after_the_plan_keeps_the_robot_out_of_someones_path() {
    let obs = oncoming(6.5);
    let hold = |hold: f64| SelectionWeights {
        hold,
        ..SelectionWeights::default()
    };
    // The plan followed by the robot standing at its end for 2 s.
    let held = |p: &[Pose2]| {
        let mut poses = p.to_vec();
        poses.extend(std::iter::repeat_n(p[p.len() - 1], 20));
        poses
    };
    let without = plan_selecting(hold(0.0), &obs);
    assert!(predicted_gap(&without.poses, &obs) > 0.0);
    let gap = predicted_gap(&held(&without.poses), &obs);
    assert!(gap < 0.0, "standing at its end: gap {gap}");
    let with = plan_selecting(hold(2.0), &obs);
    let gap = predicted_gap(&held(&with.poses), &obs);
    assert!(gap > 0.0, "gap {gap}; notes {:?}", with.info.notes);
    let err = selecting(hold(f64::NAN))
        .validate()
        .unwrap_err()
        .to_string();
    assert!(err.contains("selection.hold"), "{err}");
}

/// Someone walks down the robot's line toward it, far enough that every plan ends short of
/// them. With a lookahead the selection scores each plan continued at its last step's twist
/// for that long, sees that driving on at the goal meets them, and picks a plan that goes on
/// out of their path. A lookahead that is not a number in 0 to 10 s is refused by name.
#[test]
fn a_lookahead_past_the_plan_sees_the_contact_of_driving_on() {
    use human2nav_core::human2nav::continued;
    let obs = oncoming(7.0);
    let lookahead = |lookahead: f64| SelectionWeights {
        lookahead,
        ..SelectionWeights::default()
    };
    let without = plan_selecting(lookahead(0.0), &obs);
    assert!(predicted_gap(&without.poses, &obs) > 0.0);
    let gap = predicted_gap(&continued(&without.poses, 20), &obs);
    assert!(gap < 0.0, "driving on for 2 s: gap {gap}");
    let with = plan_selecting(lookahead(2.0), &obs);
    assert_eq!(
        with.poses.len(),
        without.poses.len(),
        "the plan sent is the candidate"
    );
    let gap = predicted_gap(&continued(&with.poses, 20), &obs);
    assert!(gap > 0.0, "gap {gap}; notes {:?}", with.info.notes);
    for bad in [f64::NAN, -0.1, 10.5] {
        let err = selecting(lookahead(bad))
            .validate()
            .unwrap_err()
            .to_string();
        assert!(err.contains("selection.lookahead"), "{bad}: {err}");
    }
}

/// The model's samples run straight past a goal 0.8 m ahead and to the left; within
/// `goal_approach` the planner also offers "straight to the goal", which wins, ends at the goal
/// and is feasible. Without it the plan ends outside the benchmark's 0.3 m goal tolerance.
#[test]
fn a_goal_close_by_is_approached_directly() {
    let ego = Pose2::new(1.0, 2.0, 0.3);
    let goal_ego = Pose2::new(0.6, 0.5, 0.0);
    let goal_world = ego.compose(goal_ego);
    let obs = Observation {
        time: 0.0,
        ego,
        ego_velocity: Twist2::ZERO,
        goal: [goal_world.x, goal_world.y],
        agents: vec![],
        ..Default::default()
    };
    let end_gap = |approach: f64| {
        // The robot's own motions off: some of them end near the goal too.
        let settings = Human2NavSettings {
            goal_approach: approach,
            motions: 0,
            ..Human2NavSettings::default()
        };
        let mut p = Human2Nav::new(fast_straight(), robot(), BevSpec::default(), settings).unwrap();
        let plan = p.plan(&obs).unwrap();
        let end = plan.poses.last().copied().unwrap();
        let tfs = tfs_plan(
            &ego_frame(&plan.poses, ego),
            0.1,
            &limits(),
            obs.ego_velocity,
        );
        (
            (end.x - goal_world.x).hypot(end.y - goal_world.y),
            tfs,
            plan.info.notes,
        )
    };
    let (gap, tfs, notes) = end_gap(1.0);
    assert!(gap < 0.1, "ends {gap} m from the goal ({notes:?})");
    assert_eq!(tfs, 1.0);
    assert!(
        notes.iter().any(|n| n == "straight to the goal"),
        "{notes:?}"
    );
    let (gap, _, notes) = end_gap(0.0);
    assert!(
        gap > 0.3,
        "without the approach it ends {gap} m away ({notes:?})"
    );
}

/// The fast human future with a hook run ahead of every network call.
struct Hooked<H> {
    inner: HumanFuture,
    hook: H,
}

/// What a [`Hooked`] model does before each network call.
trait BeforeCall {
    fn before_call(&self);
}

impl<H: BeforeCall> FlowModel for Hooked<H> {
    fn horizon(&self) -> usize {
        self.inner.horizon()
    }
    fn source_std(&self) -> [f64; 3] {
        self.inner.source_std()
    }
    fn velocity(
        &self,
        x: &[f64],
        t: f64,
        c: &FlowCondition,
        out: &mut [f64],
    ) -> Result<(), FlowError> {
        self.hook.before_call();
        self.inner.velocity(x, t, c, out)
    }
    fn velocity_vjp(
        &self,
        x: &[f64],
        t: f64,
        c: &FlowCondition,
        cot: &[f64],
        out: &mut [f64],
        vjp: &mut [f64],
    ) -> Result<(), FlowError> {
        self.hook.before_call();
        self.inner.velocity_vjp(x, t, c, cot, out, vjp)
    }
}

/// A virtual clock: every network call costs one tick, and the test's deadline reads the same
/// clock, so where the deadline falls is exact and the test is deterministic. Counts the calls
/// that start once the deadline has passed.
struct Ticking {
    clock: Arc<AtomicUsize>,
    deadline_tick: usize,
    late_calls: AtomicUsize,
}

impl BeforeCall for Ticking {
    fn before_call(&self) {
        if self.clock.fetch_add(1, Ordering::SeqCst) >= self.deadline_tick {
            self.late_calls.fetch_add(1, Ordering::SeqCst);
        }
    }
}

/// A planner on the ticking model with its deadline `deadline_tick` network calls in.
fn ticking(
    settings: Human2NavSettings,
    deadline_tick: usize,
) -> (Human2Nav<Hooked<Ticking>>, Deadline) {
    let clock = Arc::new(AtomicUsize::new(0));
    let model = Hooked {
        inner: fast_straight(),
        hook: Ticking {
            clock: Arc::clone(&clock),
            deadline_tick,
            late_calls: AtomicUsize::new(0),
        },
    };
    let planner = Human2Nav::new(model, robot(), BevSpec::default(), settings).unwrap();
    let deadline = Deadline::from_fn(move || clock.load(Ordering::SeqCst) >= deadline_tick);
    (planner, deadline)
}

/// Network calls of one planning call of `settings` without a deadline.
fn calls_without_deadline(settings: Human2NavSettings) -> usize {
    let (mut p, _) = ticking(settings, usize::MAX);
    p.plan(&observation()).unwrap();
    p.model().hook.clock.load(Ordering::SeqCst)
}

#[test]
fn a_deadline_anywhere_in_the_call_gives_a_feasible_plan_and_no_late_network_call() {
    let obs = observation();
    let tfs = |p: &[Pose2]| tfs_plan(&ego_frame(p, obs.ego), 0.1, &limits(), obs.ego_velocity);
    // The shipped planner (no Algorithm 1 iterations), and Algorithm 1 on in both variants.
    let alg1 = Arm::Both.settings(&Human2NavSettings::default());
    let mut paper = alg1;
    paper.guidance.variant = GuidanceVariant::Paper;
    let no_stop = Human2NavSettings {
        stop_candidate: false,
        ..alg1
    };
    for settings in [Human2NavSettings::default(), alg1, paper, no_stop] {
        let n = settings.guidance.steps_n;
        let total = calls_without_deadline(settings);
        // N plain steps, then M iterations of N forward calls, each after a backward pass of
        // N VJPs (N − 1 when μ_0 is not needed): the fast future stays infeasible, so no
        // iteration stops early. The adaptive variant skips the backward pass when every
        // sample was restored to where its direction was computed.
        let m = if settings.guidance.enabled {
            settings.guidance.iterations_m
        } else {
            0
        };
        let backward = total - n - m * n;
        let paper = settings.guidance.variant == GuidanceVariant::Paper;
        if paper {
            assert_eq!(backward, m * n);
        } else {
            assert!(
                backward % (n - 1) == 0 && backward <= m * (n - 1),
                "{total} calls"
            );
        }
        // An iteration costs 2N calls (paper), or N to 2N − 1 (adaptive).
        let (fewest, most) = if paper {
            (2 * n, 2 * n)
        } else {
            (n, 2 * n - 1)
        };
        let mut done_before = 0;
        for at in 0..=total + 1 {
            let (mut p, deadline) = ticking(settings, at);
            let plan = p.plan_within(&obs, &deadline).unwrap();
            let stages = plan.info.stages.unwrap();
            assert_eq!(
                p.model().hook.late_calls.load(Ordering::SeqCst),
                0,
                "deadline at call {at}: a network call started after it"
            );
            assert!(plan.is_finite() && !plan.info.fallback, "deadline at {at}");
            assert_eq!(tfs(&plan.poses), 1.0, "deadline at call {at}: not feasible");
            assert_eq!(stages.sampling.done, at.min(n), "deadline at {at}");
            assert_eq!(stages.sampling.planned, n);
            if at > total {
                assert_eq!(stages.cut_short, None, "deadline at {at}");
                assert_eq!(stages.guidance.done, m);
                assert!(stages.correction.complete());
            } else {
                // Passed during sampling, during guidance, or just as the last network call
                // returned (then the correction is what it cuts).
                let expected = if at < n {
                    Stage::Sampling
                } else if at < total {
                    Stage::Guidance
                } else {
                    Stage::Correction
                };
                assert_eq!(stages.cut_short, Some(expected), "deadline at {at}");
                let done = stages.guidance.done;
                let spent = at.saturating_sub(n);
                assert!(
                    (spent / most..=spent / fewest).contains(&done) && done >= done_before,
                    "deadline at {at}: {done} iterations done"
                );
                done_before = done;
                assert!(!stages.correction.complete() || stages.correction.planned <= 2);
                assert!(plan.info.notes.iter().any(|n| n.starts_with("deadline")));
            }
        }
    }
}

#[test]
fn a_deadline_before_sampling_keeps_the_previous_plan_or_brakes() {
    let obs = observation();
    // Guidance on: nothing sampled, so the plan brakes to a stop (the corrected stop candidate).
    let (mut p, deadline) = ticking(Human2NavSettings::default(), 0);
    let plan = p.plan_within(&obs, &deadline).unwrap();
    assert!(!plan.info.fallback);
    assert!(plan.info.notes.iter().any(|n| n == "braking to a stop"));
    assert!(plan.info.candidates.is_empty());

    // A full call first, then one with no time: the previous plan is kept (it is feasible).
    let (mut p, _) = ticking(Human2NavSettings::default(), usize::MAX);
    let first = p.plan(&obs).unwrap();
    let later = Observation {
        time: obs.time + 0.1,
        ego: pose_at(&first, obs.time + 0.1),
        ..obs.clone()
    };
    let second = p.plan_within(&later, &Deadline::from_fn(|| true)).unwrap();
    assert!(!second.info.fallback);
    assert!(
        second
            .info
            .notes
            .iter()
            .any(|n| n == "kept the previous plan"),
        "{:?}",
        second.info.notes
    );

    // The raw samples (no correction, hence no stop candidate): no samples and no previous
    // plan leave only the stop-in-place fallback.
    let off = Arm::Raw.settings(&Human2NavSettings::default());
    let (mut p, deadline) = ticking(off, 0);
    let plan = p.plan_within(&obs, &deadline).unwrap();
    assert!(plan.info.fallback && plan.is_finite());
}

/// A network call that takes this long of wall-clock time.
struct Sleepy(Duration);

impl BeforeCall for Sleepy {
    fn before_call(&self) {
        std::thread::sleep(self.0);
    }
}

#[test]
fn the_budget_setting_bounds_a_slow_model_by_the_clock() {
    // 32 calls of 20 ms would take 640 ms; the budget is 50 ms. The bound checked is loose
    // (one call plus 400 ms of slack for a loaded machine): the exact property, no call after
    // the deadline, is the virtual-clock test's.
    let settings = Human2NavSettings {
        budget_ms: 50.0,
        ..Default::default()
    };
    let model = Hooked {
        inner: fast_straight(),
        hook: Sleepy(Duration::from_millis(20)),
    };
    let mut p = Human2Nav::new(model, robot(), BevSpec::default(), settings).unwrap();
    let started = Instant::now();
    let plan = p.plan(&observation()).unwrap();
    let took = started.elapsed();
    assert!(took < Duration::from_millis(50 + 20 + 400), "took {took:?}");
    let stages = plan.info.stages.unwrap();
    assert!(stages.cut_short.is_some(), "{stages:?}");
    assert!(plan.is_finite() && !plan.info.fallback);
}

#[test]
fn a_budget_outside_its_range_is_an_error_naming_the_field() {
    for budget_ms in [-1.0, f64::NAN, 1e9] {
        let settings = Human2NavSettings {
            budget_ms,
            ..Default::default()
        };
        let err = settings.validate().unwrap_err().to_string();
        assert!(err.contains("budget_ms"), "{err}");
    }
}

/// The robot at the origin facing +x at rest, the goal 5 m ahead, nobody around.
fn open_floor() -> Observation {
    Observation {
        goal: [5.0, 0.0],
        ..Observation::default()
    }
}

fn min_wall_clearance(plan: &[Pose2], wall: &Obstacle) -> f64 {
    plan.iter()
        .map(|p| footprint_clearance(&robot().footprint, *p, wall))
        .fold(f64::INFINITY, f64::min)
}

#[test]
fn a_wall_or_an_occupied_grid_column_across_the_way_stops_the_plan_short_of_it() {
    let wall = Obstacle::Segment {
        a: [1.2, -5.0],
        b: [1.2, 5.0],
    };
    let free = planner(true).plan(&open_floor()).unwrap();
    assert!(
        min_wall_clearance(&free.poses, &wall) < 0.0,
        "without the wall the plan runs through where it would be"
    );
    let walled = Observation {
        obstacles: vec![wall.clone()],
        ..open_floor()
    };
    let plan = planner(true).plan(&walled).unwrap();
    assert!(!plan.info.fallback);
    assert!(
        min_wall_clearance(&plan.poses, &wall) >= 0.0,
        "{:?}",
        plan.info.notes
    );

    // The same wall as a column of occupied cells (0.1 m) of a grid around the robot.
    let (w, h) = (60, 100);
    let mut data = vec![0i8; w * h];
    for row in 0..h {
        data[row * w + 32] = 100; // x from 1.2 to 1.3 with the origin at (-2, -5)
    }
    let grid = OccupancyGrid {
        origin: Pose2::new(-2.0, -5.0, 0.0),
        resolution: 0.1,
        width: w,
        height: h,
        data,
        occupied_threshold: 65,
    };
    let gridded = Observation {
        occupancy: Some(grid),
        ..open_floor()
    };
    let plan = planner(true).plan(&gridded).unwrap();
    assert!(min_wall_clearance(&plan.poses, &wall) >= 0.0);
    let mut broken = gridded.clone();
    if let Some(g) = broken.occupancy.as_mut() {
        g.data.pop();
    }
    let err = planner(true).plan(&broken).unwrap_err().to_string();
    assert!(err.contains("occupancy: data holds"), "{err}");
}

#[test]
fn the_robots_own_motions_steer_round_what_the_samples_run_into() {
    let ego = Pose2::new(0.0, 0.0, 0.0);
    let obs = someone_ahead();
    let plan_with = |motions: usize| {
        let settings = Human2NavSettings {
            motions,
            ..Human2NavSettings::default()
        };
        let mut p = Human2Nav::new(fast_straight(), robot(), BevSpec::default(), settings).unwrap();
        p.plan(&obs).unwrap()
    };
    let progress = |plan: &human2nav_core::Plan| plan.poses.last().unwrap().x;
    let clear = |plan: &human2nav_core::Plan| {
        plan.poses
            .iter()
            .all(|q| (q.x - 2.0).hypot(q.y) > ROBOT_RADIUS + 0.3)
    };
    // Without them the planner can only slow down or stop in front of the person.
    let without = plan_with(0);
    assert!(
        clear(&without) && progress(&without) < 1.5,
        "{:?}",
        without.info.notes
    );
    // With them it goes round, within the limits, and says where the plan came from.
    let with = plan_with(500);
    assert!(clear(&with), "{:?}", with.poses);
    assert!(
        progress(&with) > progress(&without) + 0.5,
        "{} against {}",
        progress(&with),
        progress(&without)
    );
    assert!(
        with.info
            .notes
            .iter()
            .any(|n| n == "one of the robot's own motions"),
        "{:?}",
        with.info.notes
    );
    let local = ego_frame(&with.poses, ego);
    assert_eq!(tfs_plan(&local, 0.1, &limits(), obs.ego_velocity), 1.0);
    // A count beyond the bound is an error naming the field.
    let settings = Human2NavSettings {
        motions: human2nav_core::human2nav::MAX_MOTIONS + 1,
        ..Human2NavSettings::default()
    };
    let err = Human2Nav::new(fast_straight(), robot(), BevSpec::default(), settings).unwrap_err();
    assert!(err.to_string().contains("motions"), "{err}");
}

/// A predictor with a fixed answer: agent `id` walks from its position to `to` in the first
/// second and stays there; everyone else moves on at constant velocity. Or it fails.
struct Scripted {
    id: u64,
    to: [f64; 2],
    fail: bool,
}

impl CrowdPredictor for Scripted {
    fn name(&self) -> &str {
        "scripted"
    }
    fn forecast(
        &mut self,
        obs: &Observation,
        horizon: usize,
        dt: f64,
    ) -> Result<Forecast, ForecastError> {
        if self.fail {
            return Err("no forecast today".into());
        }
        Forecast::one_path_each(&obs.agents, horizon, |a| {
            if a.id != self.id {
                return constant_velocity_path(a, horizon, dt);
            }
            (1..=horizon)
                .map(|j| {
                    let s = (j as f64 * dt).min(1.0);
                    let p = a.position;
                    [
                        p[0] + s * (self.to[0] - p[0]),
                        p[1] + s * (self.to[1] - p[1]),
                    ]
                })
                .collect()
        })
    }
}

/// Someone standing 1 m to the left of the robot's way to its goal, 2 m ahead, and the
/// smallest gap between the robot's disc and them along a plan if they step into the way.
fn bystander() -> (Observation, impl Fn(&[Pose2]) -> f64) {
    let obs = Observation {
        time: 0.0,
        ego: Pose2::IDENTITY,
        ego_velocity: Twist2::new(0.8, 0.0, 0.0),
        goal: [6.0, 0.0],
        agents: vec![AgentState {
            id: 3,
            position: [2.0, 1.0],
            velocity: [0.0, 0.0],
            radius: 0.3,
            history: vec![],
        }],
        ..Default::default()
    };
    let gap = |plan: &[Pose2]| {
        plan.iter()
            .skip(1)
            .enumerate()
            .map(|(j, p)| {
                let s = ((j + 1) as f64 * 0.1).min(1.0);
                let q = [2.0, 1.0 - s];
                (p.x - q[0]).hypot(p.y - q[1]) - ROBOT_RADIUS - 0.3
            })
            .fold(f64::INFINITY, f64::min)
    };
    (obs, gap)
}

#[test]
fn the_selection_avoids_where_its_predictor_says_people_go() {
    let (obs, gap) = bystander();
    // At constant velocity the bystander stays put, and the plan runs through the place they
    // step into.
    let plain = planner(true).plan(&obs).unwrap();
    assert!(gap(&plain.poses) < 0.0, "gap {}", gap(&plain.poses));
    let mut predicted = planner(true).with_predictor(Box::new(Scripted {
        id: 3,
        to: [2.0, 0.0],
        fail: false,
    }));
    assert_eq!(predicted.predictor().map(|p| p.name()), Some("scripted"));
    let plan = predicted.plan(&obs).unwrap();
    assert!(gap(&plan.poses) >= 0.0, "gap {}", gap(&plan.poses));
    assert!(!plan.info.fallback);
}

#[test]
fn a_failing_predictor_leaves_constant_velocity_and_a_note() {
    let (obs, _) = bystander();
    let plain = planner(true).plan(&obs).unwrap();
    let plan = planner(true)
        .with_predictor(Box::new(Scripted {
            id: 3,
            to: [2.0, 0.0],
            fail: true,
        }))
        .plan(&obs)
        .unwrap();
    assert_eq!(plan.poses, plain.poses);
    assert!(
        plan.info
            .notes
            .iter()
            .any(|n| n.contains("predictor scripted failed (no forecast today)")),
        "{:?}",
        plan.info.notes
    );
}

#[test]
fn crowd_guidance_is_checked_and_leaves_a_model_blind_to_its_raster_unchanged() {
    let obs = observation();
    let with = |w: f64| Human2NavSettings {
        crowd_weight: w,
        ..Human2NavSettings::default()
    };
    // The analytic field ignores its raster: guided by the crowd or not, it draws the same.
    let plain = planner(true).plan(&obs).unwrap();
    let guided = Human2Nav::new(fast_straight(), robot(), BevSpec::default(), with(4.0))
        .unwrap()
        .plan(&obs)
        .unwrap();
    assert_eq!(plain.poses, guided.poses);
    for bad in [-1.0, f64::NAN, f64::INFINITY, 101.0] {
        let err = with(bad).validate().unwrap_err().to_string();
        assert!(err.contains("crowd_weight"), "{err}");
    }
}

fn someone_ahead() -> Observation {
    common::someone_ahead(6.0)
}

/// With `motions_recovery` the robot's own motions come in only when every model candidate
/// runs into someone: on an open floor the plan is the one without motions; with somebody
/// standing where every sample goes, a motion takes the robot round.
#[test]
fn motions_as_a_recovery_come_in_only_when_every_model_candidate_meets_someone() {
    let plan = |obs: &Observation, motions: usize, motions_recovery: bool| {
        let settings = Human2NavSettings {
            motions,
            motions_recovery,
            ..Human2NavSettings::default()
        };
        Human2Nav::new(fast_straight(), robot(), BevSpec::default(), settings)
            .unwrap()
            .plan(obs)
            .unwrap()
    };
    let free = open_floor();
    assert_eq!(plan(&free, 500, true).poses, plan(&free, 0, false).poses);
    let ahead = someone_ahead();
    let recovered = plan(&ahead, 500, true);
    assert!(
        recovered
            .info
            .notes
            .iter()
            .any(|n| n == "one of the robot's own motions"),
        "{:?}",
        recovered.info.notes
    );
    assert_eq!(recovered.poses, plan(&ahead, 500, false).poses);
}

/// `samples = 0` plans from the robot's own motions and the extra candidates alone (the arm
/// that measures what the model adds); without motions, or as a recovery from nothing, it is
/// an error naming the field.
#[test]
fn zero_samples_plan_from_the_motions_alone() {
    let settings = Human2NavSettings {
        samples: 0,
        ..Human2NavSettings::default()
    };
    let mut planner =
        Human2Nav::new(fast_straight(), robot(), BevSpec::default(), settings).unwrap();
    let plan = planner.plan(&open_floor()).unwrap();
    assert!(!plan.info.fallback, "{:?}", plan.info.notes);
    assert!(
        plan.poses.last().unwrap().x > 1.0,
        "it drives towards the goal"
    );
    assert!(plan.info.candidates.is_empty());
    for (bad, field) in [
        (
            Human2NavSettings {
                samples: 0,
                motions: 0,
                ..Human2NavSettings::default()
            },
            "human2nav.samples",
        ),
        (
            Human2NavSettings {
                samples: 0,
                motions_recovery: true,
                ..Human2NavSettings::default()
            },
            "human2nav.motions_recovery",
        ),
    ] {
        let err = Human2Nav::new(fast_straight(), robot(), BevSpec::default(), bad)
            .err()
            .unwrap()
            .to_string();
        assert!(err.contains(field), "{err}");
    }
}

/// Someone standing 1.6 m ahead, 0.15 m left of the line the model's samples walk.
fn standing_ahead() -> Observation {
    let mut obs = blocked();
    obs.agents[0].position = [1.6, 0.15];
    obs
}

/// The samples of one call before and after Algorithm 1 descending `terms` (200 last-step
/// iterations; no correction after it, so that what it did shows).
fn guided_samples(terms: GuidanceTerms) -> (Vec<Vec<Pose2>>, Vec<Vec<Pose2>>) {
    let mut settings = Human2NavSettings {
        guidance_terms: terms,
        ..Human2NavSettings::default()
    };
    settings.projection.enabled = false;
    settings.guidance.enabled = true;
    settings.guidance.last_step_iterations = 200;
    let mut planner = Human2Nav::new(fast_straight(), robot(), BevSpec::default(), settings)
        .expect("valid settings");
    let plan = planner.plan(&standing_ahead()).expect("a plan");
    (plan.info.candidates, plan.info.guided)
}

#[test]
fn algorithm_1_on_the_scene_terms_steers_the_samples_out_of_contact() {
    let obs = standing_ahead();
    let gap = |samples: &[Vec<Pose2>]| {
        samples
            .iter()
            .map(|s| predicted_gap(s, &obs))
            .fold(f64::INFINITY, f64::min)
    };
    let (raw, scene) = guided_samples(GuidanceTerms::Scene);
    let (_, all) = guided_samples(GuidanceTerms::All);
    assert_eq!(scene.len(), raw.len());
    assert!(gap(&raw) < 0.0, "the samples walk into the person");
    // The limit terms of this over-speed walk dwarf the clearance term: with every term the
    // iterations go to the limits, with the scene's terms to the person.
    assert!(
        gap(&scene) > 0.0,
        "scene terms: smallest gap {:.3} m (raw {:.3}, all terms {:.3})",
        gap(&scene),
        gap(&raw),
        gap(&all)
    );
    assert!(
        gap(&all) < 0.0,
        "all terms: smallest gap {:.3} m",
        gap(&all)
    );
}

#[test]
fn guidance_terms_parse_from_the_planner_table() {
    let settings: Human2NavSettings = toml::from_str("guidance_terms = \"scene\"").expect("parses");
    assert_eq!(settings.guidance_terms, GuidanceTerms::Scene);
    assert_eq!(
        Human2NavSettings::default().guidance_terms,
        GuidanceTerms::All
    );
    let err = toml::from_str::<Human2NavSettings>("guidance_terms = \"limits\"")
        .expect_err("an unknown choice");
    assert!(err.to_string().contains("guidance_terms"), "{err}");
}

/// A test term: `per_metre` times the distance of a trajectory's last pose from the robot (0:
/// it adds nothing; negative: a negative cost), and whether it declares itself separable and
/// non-negative (`ConstraintTerm::separable_nonnegative`). A term that adds nothing and does
/// not declare it makes the selection score every candidate with Φ instead of pruning by the
/// score without it.
struct EndDistance {
    per_metre: f64,
    declares: bool,
}

/// The term that turns the pruning off and changes nothing else.
const OPAQUE: EndDistance = EndDistance {
    per_metre: 0.0,
    declares: false,
};

impl human2nav_core::constraint::ConstraintTerm for EndDistance {
    fn name(&self) -> &str {
        "end_distance"
    }

    fn evaluate(
        &self,
        batch: human2nav_core::constraint::TrajBatch<'_>,
        _ctx: &human2nav_core::constraint::ConstraintContext<'_>,
        cost: &mut [f64],
        _grad: &mut [f64],
    ) -> Result<(), human2nav_core::constraint::ConstraintError> {
        if self.per_metre == 0.0 {
            return Ok(());
        }
        let per = batch.horizon * 3;
        for (c, t) in cost.iter_mut().zip(batch.data.chunks_exact(per)) {
            *c += self.per_metre * t[per - 3].hypot(t[per - 2]);
        }
        Ok(())
    }

    fn separable_nonnegative(&self) -> bool {
        self.declares
    }
}

/// The selection's branch and bound chooses what scoring every candidate chooses, to the bit:
/// the shipped planner (its samples, their corrections and 500 motions) plans the same poses
/// with and without a term that turns the pruning off, over scenes with crowds, walls,
/// pillars and tables, goals near and far, and several start velocities.
#[test]
fn pruned_selection_plans_what_full_scoring_plans() {
    let mut seed = 0x2545_f491_4f6c_dd1d_u64;
    let mut uniform = |lo: f64, hi: f64| {
        seed ^= seed << 13;
        seed ^= seed >> 7;
        seed ^= seed << 17;
        lo + (hi - lo) * (seed >> 11) as f64 / (1u64 << 53) as f64
    };
    let mut opaque = robot();
    opaque.phi.push(1.0, Box::new(OPAQUE)).unwrap();
    let mut pruned = Human2Nav::new(
        fast_straight(),
        robot(),
        BevSpec::default(),
        Human2NavSettings::default(),
    )
    .unwrap();
    let mut full = Human2Nav::new(
        fast_straight(),
        opaque,
        BevSpec::default(),
        Human2NavSettings::default(),
    )
    .unwrap();
    let mut chosen = std::collections::HashSet::new();
    for scene in 0..24 {
        let ego = Pose2::new(uniform(-2.0, 2.0), uniform(-2.0, 2.0), uniform(-3.1, 3.1));
        let reach = if scene % 4 == 0 { 0.8 } else { 6.0 };
        let bearing = uniform(-3.1, 3.1);
        let mut agents: Vec<AgentState> = (0..scene % 9)
            .map(|id| AgentState {
                id: id as u64,
                position: ego.act([uniform(0.5, 5.0), uniform(-2.5, 2.5)]),
                velocity: [uniform(-1.3, 1.3), uniform(-1.3, 1.3)],
                radius: 0.25,
                history: vec![],
            })
            .collect();
        if scene % 2 == 0 {
            // A line of people standing across the way to the goal: the candidates that
            // make the most progress run into them, and the plan is one that does not.
            let toward = |d: f64, side: f64| {
                ego.act([
                    d * bearing.cos() - side * bearing.sin(),
                    d * bearing.sin() + side * bearing.cos(),
                ])
            };
            agents.extend((0..5).map(|k| AgentState {
                id: 100 + k,
                position: toward(1.2, 0.5 * k as f64 - 1.0),
                velocity: [0.0, 0.0],
                radius: 0.25,
                history: vec![],
            }));
        }
        let mut obstacles = vec![];
        if scene % 3 == 1 {
            obstacles.push(Obstacle::Segment {
                a: ego.act([-3.0, 1.6]),
                b: ego.act([6.0, 1.6]),
            });
            obstacles.push(Obstacle::Circle {
                center: ego.act([2.5, -0.8]),
                radius: 0.3,
            });
            let c = ego.act([4.0, -1.5]);
            obstacles.push(Obstacle::Polygon {
                vertices: vec![
                    [c[0] - 0.4, c[1] - 0.3],
                    [c[0] + 0.4, c[1] - 0.3],
                    [c[0] + 0.4, c[1] + 0.3],
                    [c[0] - 0.4, c[1] + 0.3],
                ],
            });
        }
        let obs = Observation {
            time: 0.1 * scene as f64,
            ego,
            ego_velocity: Twist2::new(uniform(-0.2, 1.0), 0.0, uniform(-0.5, 0.5)),
            goal: ego.act([reach * bearing.cos(), reach * bearing.sin()]),
            agents,
            obstacles,
            ..Default::default()
        };
        let (a, b) = (pruned.plan(&obs).unwrap(), full.plan(&obs).unwrap());
        let bits = |p: &Plan| -> Vec<[u64; 3]> {
            p.poses
                .iter()
                .map(|q| [q.x.to_bits(), q.y.to_bits(), q.theta.to_bits()])
                .collect()
        };
        assert_eq!(bits(&a), bits(&b), "scene {scene}");
        chosen.insert(bits(&a));
    }
    // The scenes are not all alike: the plans differ.
    assert!(chosen.len() > 12, "{} different plans", chosen.len());
}

/// A term that breaks its declaration (a negative cost) turns the selection's pruning off
/// for the call: the plan is the one scoring every candidate gives.
#[test]
fn a_term_that_breaks_its_declaration_plans_as_full_scoring_does() {
    let planner = |term: Option<EndDistance>| {
        let mut r = robot();
        if let Some(term) = term {
            r.phi.push(1.0, Box::new(term)).unwrap();
        }
        Human2Nav::new(
            fast_straight(),
            r,
            BevSpec::default(),
            Human2NavSettings::default(),
        )
        .unwrap()
    };
    let negative = |declares| EndDistance {
        per_metre: -2.0,
        declares,
    };
    let mut liar = planner(Some(negative(true)));
    let mut honest = planner(Some(negative(false)));
    let mut plain = planner(None);
    let mut changed = 0;
    for scene in 0..8 {
        let k = scene as f64;
        let obs = Observation {
            time: 0.1 * k,
            ego: Pose2::new(0.0, 0.0, 0.4 * k),
            ego_velocity: Twist2::new(0.1 * k, 0.0, 0.0),
            goal: [3.0 * (0.4 * k).cos(), 3.0 * (0.4 * k).sin()],
            agents: vec![AgentState {
                id: 1,
                position: [1.5 * (0.4 * k + 0.2).cos(), 1.5 * (0.4 * k + 0.2).sin()],
                velocity: [0.0, 0.0],
                radius: 0.25,
                history: vec![],
            }],
            ..Default::default()
        };
        let a = liar.plan(&obs).unwrap();
        assert_eq!(a.poses, honest.plan(&obs).unwrap().poses, "scene {scene}");
        changed += usize::from(a.poses != plain.plan(&obs).unwrap().poses);
    }
    // The term matters: it changes plans.
    assert!(changed > 0);
}
