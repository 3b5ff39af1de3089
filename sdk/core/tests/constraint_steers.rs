//! A constraint term changes what the robot does: every candidate of the Human2Nav planner's
//! selection is scored with Φ, so a term a user adds (in Rust here; the C and Rust plugins in
//! `tests/tests/constraint_steers.rs`) and the robot's `[cost]` weights steer the chosen plan,
//! and a term that fails is reported, never left out in silence.

#![allow(clippy::unwrap_used)] // test helpers outside #[test] functions unwrap too

mod common;

use human2nav_core::bev::BevSpec;
use human2nav_core::constraint::{
    ConstraintContext, ConstraintError, ConstraintTerm, Phi, TrajBatch, sigmoid, softplus,
};
use human2nav_core::guidance::analytic::FixedWalk;
use human2nav_core::human2nav::{Human2Nav, Human2NavSettings, RobotModel};
use human2nav_core::{GuidanceWeights, Observation, Plan, Planner, Twist2};

/// The test robot (`common::robot`), Φ with `weights` plus `extra` terms.
fn robot(weights: &GuidanceWeights, extra: Vec<(f64, Box<dyn ConstraintTerm>)>) -> RobotModel {
    let limits = common::limits();
    let mut phi = Phi::from_weights(weights, &limits);
    for (w, term) in extra {
        phi.push(w, term).unwrap();
    }
    RobotModel {
        phi,
        ..common::robot()
    }
}

/// Someone standing 2 m ahead on the way to the goal: the robot passes on one side.
fn blocked() -> Observation {
    common::someone_ahead(8.0)
}

fn plan(robot: RobotModel, obs: &Observation) -> Plan {
    // Every sample walks straight ahead at 0.9 m/s (a person's way to a goal ahead); the
    // robot's own motions give the selection its ways round.
    let mut planner = Human2Nav::new(
        FixedWalk::straight(0.09, 32),
        robot,
        BevSpec::default(),
        Human2NavSettings::default(),
    )
    .unwrap();
    planner.plan(obs).unwrap()
}

/// The side the plan passes the pedestrian on: the sign of its mean lateral offset over its
/// first two seconds (world frame = ego frame here).
fn side(plan: &Plan) -> f64 {
    let y: f64 = plan.poses[1..=20].iter().map(|p| p.y).sum::<f64>() / 20.0;
    assert!(y.abs() > 0.05, "the plan must pass on a side: mean y {y}");
    y.signum()
}

/// `(1/T) Σ_k softplus(γ·s·y_k)/γ` over the poses after the current one: penalises poses on
/// side `s` (`+1`: left, `y > 0`), a term any user could write.
struct AvoidSide(f64);

const SIDE_GAMMA: f64 = 10.0;

impl ConstraintTerm for AvoidSide {
    fn name(&self) -> &str {
        "avoid_side"
    }

    fn evaluate(
        &self,
        batch: TrajBatch<'_>,
        _ctx: &ConstraintContext<'_>,
        cost: &mut [f64],
        grad: &mut [f64],
    ) -> Result<(), ConstraintError> {
        let inv = 1.0 / batch.horizon.max(1) as f64;
        for b in 0..batch.batch {
            for (k, p) in batch.trajectory(b).chunks_exact(3).enumerate().skip(1) {
                let z = SIDE_GAMMA * self.0 * p[1];
                cost[b] += softplus(z) / SIDE_GAMMA * inv;
                grad[(b * batch.horizon + k) * 3 + 1] += self.0 * sigmoid(z) * inv;
            }
        }
        Ok(())
    }
}

#[test]
fn a_term_that_penalises_one_side_flips_the_plan_to_the_other() {
    let obs = blocked();
    let weights = GuidanceWeights::default();
    let free = side(&plan(robot(&weights, vec![]), &obs));
    let flipped = plan(
        robot(&weights, vec![(1.0, Box::new(AvoidSide(free)))]),
        &obs,
    );
    assert_eq!(side(&flipped), -free, "{:?}", flipped.info.notes);
    // Penalising the other side keeps it where it was.
    let kept = plan(
        robot(&weights, vec![(1.0, Box::new(AvoidSide(-free)))]),
        &obs,
    );
    assert_eq!(side(&kept), free);
}

#[test]
fn a_term_at_weight_zero_is_no_term_and_a_heavy_one_changes_the_plan() {
    let obs = blocked();
    let weights = GuidanceWeights::default();
    let none = plan(robot(&weights, vec![]), &obs);
    let zero = plan(robot(&weights, vec![(0.0, Box::new(AvoidSide(1.0)))]), &obs);
    assert_eq!(none.poses, zero.poses);
    let light = plan(
        robot(&weights, vec![(0.5, Box::new(AvoidSide(side(&none))))]),
        &obs,
    );
    let heavy = plan(
        robot(&weights, vec![(1000.0, Box::new(AvoidSide(side(&none))))]),
        &obs,
    );
    assert_ne!(none.poses, heavy.poses);
    assert_ne!(light.poses, heavy.poses);
}

/// The largest yaw rate of a plan (rad/s).
fn max_yaw_rate(plan: &Plan) -> f64 {
    plan.poses
        .windows(2)
        .map(|w| (w[1].theta - w[0].theta).abs() / plan.dt)
        .fold(0.0, f64::max)
}

#[test]
fn raising_a_cost_weight_changes_the_plan_where_candidates_differ_in_that_quantity() {
    // The goal behind the robot's left shoulder: the candidates differ in how hard they turn.
    let obs = Observation {
        goal: [-1.0, 3.0],
        agents: vec![],
        ego_velocity: Twist2::new(0.0, 0.0, 0.0),
        ..blocked()
    };
    let base = GuidanceWeights::default();
    let spin_averse = GuidanceWeights {
        lambda_omega: 1000.0,
        ..base
    };
    let turn = plan(robot(&base, vec![]), &obs);
    let gentle = plan(robot(&spin_averse, vec![]), &obs);
    assert_ne!(turn.poses, gentle.poses);
    assert!(
        max_yaw_rate(&gentle) < max_yaw_rate(&turn),
        "λ_ω = 1000: {} rad/s, λ_ω = 1: {} rad/s",
        max_yaw_rate(&gentle),
        max_yaw_rate(&turn)
    );
}

/// A term that answers NaN for every trajectory.
struct Broken;

impl ConstraintTerm for Broken {
    fn name(&self) -> &str {
        "broken_term"
    }

    fn evaluate(
        &self,
        _batch: TrajBatch<'_>,
        _ctx: &ConstraintContext<'_>,
        cost: &mut [f64],
        _grad: &mut [f64],
    ) -> Result<(), ConstraintError> {
        cost.fill(f64::NAN);
        Ok(())
    }
}

#[test]
fn a_term_that_answers_nan_stops_the_robot_with_an_error_naming_it() {
    let robot = robot(&GuidanceWeights::default(), vec![(1.0, Box::new(Broken))]);
    let plan = plan(robot, &blocked());
    assert!(plan.info.fallback && plan.is_finite());
    let error = plan.info.error.unwrap_or_default();
    assert!(
        error.contains("broken_term") && error.contains("non-finite"),
        "{error}"
    );
}
