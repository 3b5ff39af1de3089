//! The guidance ablation: one planning step under the four configurations ("arms") that tell
//! apart what Algorithm 1 and the last-step correction each contribute.
//!
//! | arm | Algorithm 1 | last-step correction (QP) | slowed, stop and goal candidates |
//! |---|---|---|---|
//! | [`Arm::Raw`] | off | off | off (the selection among all `K` samples as they come) |
//! | [`Arm::Alg1`] | on | off | on |
//! | [`Arm::Qp`] | off | on | on (the shipped planner, bar its own motions) |
//! | [`Arm::Both`] | on | on | on |
//!
//! Every arm samples, and every arm selects (with Φ, like the shipped planner).
//!
//! No arm offers the robot's own motions (`Human2NavSettings::motions`, a lever of the
//! selection, not a guidance stage), so the shipped planner is `qp` plus those motions.
//! "On" runs the configured `iterations_m`, or Algorithm 1's tuned default
//! ([`GuidanceSettings::default`]) when the configured planner runs none, as the shipped one
//! does.
//!
//! [`ablation_step`] plans one observation with one planner per arm, each reset first so that
//! no warm start carries over; with the same seed every arm draws the same source samples, so
//! the differences are the stages' alone. [`ArmSummary`] aggregates the steps of one arm.

use crate::feasibility::{self, Violations};
use crate::guidance::GuidanceSettings;
use crate::human2nav::Human2NavSettings;
use crate::limits::Limits;
use crate::planner::{Observation, Plan, PlanError, Planner};
use crate::robot::footprint::{self, FootprintShape};
use crate::se2::Pose2;
use std::time::Instant;

/// One configuration of the ablation (module docs).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Arm {
    /// The flow model's samples, no guidance, no correction.
    Raw,
    /// Algorithm 1 without the last-step correction.
    Alg1,
    /// The last-step correction without Algorithm 1's iterations.
    Qp,
    /// Algorithm 1 followed by the correction.
    Both,
}

impl Arm {
    /// Every arm, in table order.
    pub const ALL: [Arm; 4] = [Arm::Raw, Arm::Alg1, Arm::Qp, Arm::Both];

    /// Short name for tables and file names.
    pub fn key(self) -> &'static str {
        match self {
            Arm::Raw => "raw",
            Arm::Alg1 => "alg1",
            Arm::Qp => "qp",
            Arm::Both => "alg1+qp",
        }
    }

    /// Description for table legends.
    pub fn label(self) -> &'static str {
        match self {
            Arm::Raw => "raw samples",
            Arm::Alg1 => "Algorithm 1 only",
            Arm::Qp => "QP only",
            Arm::Both => "Algorithm 1 + QP",
        }
    }

    /// `base` (the configured planner) with this arm's stages switched on or off; every other
    /// setting is kept, so the arms differ in the stages alone. Algorithm 1 "on" with a base of
    /// `iterations_m = 0` runs [`GuidanceSettings::default`]'s iterations.
    pub fn settings(self, base: &Human2NavSettings) -> Human2NavSettings {
        let mut s = *base;
        // The arms measure the guidance stages on the model's samples: the robot's own motions
        // (a separate lever of the selection) are off in every arm.
        s.motions = 0;
        if s.guidance.iterations_m == 0 && matches!(self, Arm::Alg1 | Arm::Both) {
            s.guidance.iterations_m = GuidanceSettings::default().iterations_m;
        }
        match self {
            Arm::Raw => {
                s.guidance.enabled = false;
                s.projection.enabled = false;
                s.guided_samples = 0;
                s.slowdown = 1.0;
                s.stop_candidate = false;
                s.goal_approach = 0.0;
            }
            Arm::Alg1 => {
                s.guidance.enabled = true;
                s.projection.enabled = false;
            }
            Arm::Qp => {
                s.guidance.enabled = false;
                s.projection.enabled = true;
            }
            Arm::Both => {
                s.guidance.enabled = true;
                s.projection.enabled = true;
            }
        }
        s
    }
}

impl std::str::FromStr for Arm {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Arm::ALL.into_iter().find(|a| a.key() == s).ok_or_else(|| {
            format!(
                "unknown arm `{s}` (expected one of {})",
                Arm::ALL.map(Arm::key).join(", ")
            )
        })
    }
}

impl std::fmt::Display for Arm {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.key())
    }
}

/// Share of `violations` that break each limit, in the order of [`Violations::NAMES`] (all
/// zero for an empty slice).
pub fn limit_shares(violations: &[Violations]) -> [f64; feasibility::LIMIT_COUNT] {
    let n = violations.len().max(1) as f64;
    Violations::count(violations).map(|c| c as f64 / n)
}

/// One arm's plan of one observation.
#[derive(Clone, Debug, PartialEq)]
pub struct ArmStep {
    /// The arm that planned this step.
    pub arm: Arm,
    /// Plan TFS ([`feasibility::tfs_plan`]; pose 0 is the robot with its current velocity).
    pub tfs: f64,
    /// Share of the plan's waypoints that violate each limit ([`Violations::NAMES`] order).
    pub violations: [f64; feasibility::LIMIT_COUNT],
    /// Φ of the kept sample before Algorithm 1 (`None` when the plan follows no sample, e.g.
    /// braking to a stop).
    pub phi_before: Option<f64>,
    /// Φ of the kept sample after Algorithm 1 (equal to `phi_before` when guidance is off;
    /// `None` when the plan follows no sample).
    pub phi_after: Option<f64>,
    /// Mean distance (m) between this plan and the raw arm's plan at equal times.
    pub displacement: f64,
    /// Mean distance (m) between this plan and the sample it follows before any guidance or
    /// correction (`None` when it follows no sample).
    pub sample_displacement: Option<f64>,
    /// Algorithm 1 iterations run (`None` when it did not run).
    pub iterations: Option<usize>,
    /// Wall time of the planning call, milliseconds.
    pub millis: f64,
    /// The planner fell back to stopping in place.
    pub fallback: bool,
    /// Share of the model's samples before guidance that touch someone walking on at constant
    /// velocity ([`meets_someone`]; `None` without samples).
    pub contact_samples: Option<f64>,
    /// The same share after Algorithm 1 (`None` when it did not run).
    pub contact_guided: Option<f64>,
    /// The plan touches someone walking on at constant velocity.
    pub plan_contact: bool,
}

/// Whether the robot's footprint `footprint`, following `poses` (world frame; pose `j` at
/// `(j + first)·dt` after the observation), overlaps the disc of an agent of `obs` walking on
/// at its observed velocity.
pub fn meets_someone(
    poses: &[Pose2],
    first: usize,
    dt: f64,
    obs: &Observation,
    footprint: &[FootprintShape],
) -> bool {
    poses.iter().enumerate().any(|(j, p)| {
        let t = (j + first) as f64 * dt;
        obs.agents
            .iter()
            .any(|a| footprint::clearance_at(footprint, *p, a.walked_on(t), a.radius) < 0.0)
    })
}

/// Share of `paths` (each pose `j` at `(j + 1)·dt`) that [`meets_someone`]; `None` when empty.
fn contact_share(
    paths: &[Vec<Pose2>],
    dt: f64,
    obs: &Observation,
    footprint: &[FootprintShape],
) -> Option<f64> {
    (!paths.is_empty()).then(|| {
        let met = paths
            .iter()
            .filter(|p| meets_someone(p, 1, dt, obs, footprint))
            .count();
        met as f64 / paths.len() as f64
    })
}

/// Mean distance (m) between the positions of two pose sequences, over the poses both have.
pub fn mean_displacement(a: &[Pose2], b: &[Pose2]) -> f64 {
    let n = a.len().min(b.len());
    if n == 0 {
        return 0.0;
    }
    a.iter()
        .zip(b)
        .map(|(p, q)| (p.x - q.x).hypot(p.y - q.y))
        .sum::<f64>()
        / n as f64
}

/// TFS of a plan (its pose 0 is the robot at the planning instant), see [`feasibility::tfs_plan`].
pub fn plan_tfs(plan: &Plan, limits: &Limits, obs: &Observation) -> f64 {
    feasibility::tfs_plan(&plan.poses, plan.dt, limits, obs.ego_velocity)
}

/// Plans `obs` with each `(arm, planner)` (reset first) and measures each plan; the raw arm's
/// plan, when present, is the reference of [`ArmStep::displacement`] (else the first arm's).
/// Contacts are judged with the robot's `footprint`.
pub fn ablation_step<P: Planner + ?Sized>(
    planners: &mut [(Arm, &mut P)],
    obs: &Observation,
    limits: &Limits,
    footprint: &[FootprintShape],
) -> Result<Vec<ArmStep>, PlanError> {
    let mut plans = Vec::with_capacity(planners.len());
    for (arm, planner) in planners.iter_mut() {
        planner.reset();
        let start = Instant::now();
        let plan = planner.plan(obs)?;
        plans.push((*arm, plan, start.elapsed().as_secs_f64() * 1e3));
    }
    let reference = plans
        .iter()
        .position(|(a, _, _)| *a == Arm::Raw)
        .unwrap_or(0);
    let reference = plans.get(reference).map(|(_, p, _)| p.poses.clone());
    Ok(plans
        .into_iter()
        .map(|(arm, plan, millis)| {
            let sample_displacement = plan
                .info
                .selected
                .and_then(|i| plan.info.candidates.get(i))
                .map(|before| mean_displacement(&plan.poses, before));
            ArmStep {
                arm,
                tfs: plan_tfs(&plan, limits, obs),
                violations: limit_shares(&feasibility::plan_violations(
                    &plan.poses,
                    plan.dt,
                    limits,
                    obs.ego_velocity,
                )),
                phi_before: plan.info.phi_before,
                phi_after: plan.info.phi_after,
                displacement: reference
                    .as_deref()
                    .map_or(0.0, |r| mean_displacement(&plan.poses, r)),
                sample_displacement,
                iterations: plan.info.guidance_iterations,
                millis,
                fallback: plan.info.fallback,
                contact_samples: contact_share(&plan.info.candidates, plan.dt, obs, footprint),
                contact_guided: contact_share(&plan.info.guided, plan.dt, obs, footprint),
                plan_contact: meets_someone(&plan.poses, 0, plan.dt, obs, footprint),
            }
        })
        .collect())
}

/// Means over the steps of one arm (means of optional values skip the missing ones; NaN when
/// none is present).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ArmSummary {
    /// The arm summarised.
    pub arm: Arm,
    /// Number of planning steps.
    pub windows: usize,
    /// Mean plan TFS, in `[0, 1]`.
    pub tfs: f64,
    /// Share of steps whose plan is entirely feasible (TFS = 1).
    pub all_feasible: f64,
    /// Mean share of waypoints violating each limit ([`Violations::NAMES`] order).
    pub violations: [f64; feasibility::LIMIT_COUNT],
    /// Mean Φ of the kept sample before Algorithm 1, over the steps that kept one.
    pub phi_before: f64,
    /// Mean Φ of the kept sample after Algorithm 1, over the steps that kept one.
    pub phi_after: f64,
    /// Mean distance to the reference (raw) arm's plan at equal times (m).
    pub displacement: f64,
    /// Mean distance to the followed sample before guidance and correction (m), over the
    /// steps that follow one.
    pub sample_displacement: f64,
    /// Mean number of Algorithm 1 iterations, over the steps where it ran.
    pub iterations: f64,
    /// Median wall time of a planning call, milliseconds.
    pub millis_p50: f64,
    /// Number of steps that fell back to stopping in place.
    pub fallbacks: usize,
    /// Mean share of the samples touching someone before guidance ([`ArmStep::contact_samples`]).
    pub contact_samples: f64,
    /// The same after Algorithm 1, over the steps where it ran.
    pub contact_guided: f64,
    /// Share of steps whose plan touches someone.
    pub plan_contact: f64,
}

impl ArmSummary {
    /// Summarises the steps of `arm` among `steps` (other arms' steps are skipped).
    pub fn of(arm: Arm, steps: &[ArmStep]) -> Self {
        let steps: Vec<&ArmStep> = steps.iter().filter(|s| s.arm == arm).collect();
        let n = steps.len();
        let mean = |v: &mut dyn Iterator<Item = f64>| {
            let (sum, count) = v.fold((0.0, 0usize), |(s, c), x| (s + x, c + 1));
            if count == 0 {
                f64::NAN
            } else {
                sum / count as f64
            }
        };
        let mut shares = [0.0; feasibility::LIMIT_COUNT];
        for s in &steps {
            for (acc, v) in shares.iter_mut().zip(s.violations) {
                *acc += v / n as f64;
            }
        }
        let mut millis: Vec<f64> = steps.iter().map(|s| s.millis).collect();
        millis.sort_by(f64::total_cmp);
        Self {
            arm,
            windows: n,
            tfs: mean(&mut steps.iter().map(|s| s.tfs)),
            all_feasible: mean(&mut steps.iter().map(|s| f64::from(u8::from(s.tfs >= 1.0)))),
            violations: shares,
            phi_before: mean(&mut steps.iter().filter_map(|s| s.phi_before)),
            phi_after: mean(&mut steps.iter().filter_map(|s| s.phi_after)),
            displacement: mean(&mut steps.iter().map(|s| s.displacement)),
            sample_displacement: mean(&mut steps.iter().filter_map(|s| s.sample_displacement)),
            iterations: mean(&mut steps.iter().filter_map(|s| s.iterations.map(|i| i as f64))),
            millis_p50: millis.get(n / 2).copied().unwrap_or(f64::NAN),
            fallbacks: steps.iter().filter(|s| s.fallback).count(),
            contact_samples: mean(&mut steps.iter().filter_map(|s| s.contact_samples)),
            contact_guided: mean(&mut steps.iter().filter_map(|s| s.contact_guided)),
            plan_contact: mean(&mut steps.iter().map(|s| f64::from(u8::from(s.plan_contact)))),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::planner::{AgentState, PlanInfo};
    use crate::se2::Twist2;

    /// A planner that drives straight at a fixed speed, so its TFS is known.
    struct Straight {
        speed: f64,
        resets: usize,
    }

    impl Planner for Straight {
        fn name(&self) -> &str {
            "straight"
        }
        fn plan(&mut self, obs: &Observation) -> Result<Plan, PlanError> {
            let poses = (0..5)
                .map(|k| Pose2::new(obs.ego.x + self.speed * 0.1 * k as f64, obs.ego.y, 0.0))
                .collect();
            Ok(Plan {
                t0: obs.time,
                dt: 0.1,
                poses,
                info: PlanInfo {
                    guidance_iterations: Some(3),
                    ..PlanInfo::default()
                },
            })
        }
        fn reset(&mut self) {
            self.resets += 1;
        }
    }

    fn observation() -> Observation {
        Observation {
            time: 0.0,
            ego: Pose2::IDENTITY,
            ego_velocity: Twist2::new(1.0, 0.0, 0.0),
            goal: [5.0, 0.0],
            agents: Vec::<AgentState>::new(),
            ..Default::default()
        }
    }

    #[test]
    fn arm_keys_round_trip() {
        for arm in Arm::ALL {
            assert_eq!(arm.key().parse::<Arm>(), Ok(arm));
        }
        let err = "alg2".parse::<Arm>().unwrap_err();
        assert!(err.contains("alg2") && err.contains("alg1+qp"), "{err}");
    }

    #[test]
    fn arms_switch_only_their_stages() {
        let base = Human2NavSettings::default();
        let raw = Arm::Raw.settings(&base);
        assert!(!raw.guidance.enabled && !raw.projection.enabled);
        assert!(raw.slowdown == 1.0 && !raw.stop_candidate && raw.goal_approach == 0.0);
        assert_eq!(raw.guided_samples, 0);
        // The shipped planner runs no Algorithm 1: it is the QP arm plus the robot's motions,
        // and the arms with Algorithm 1 switch it on with its tuned count.
        assert!(!base.guidance.enabled);
        assert!(base.motions > 0);
        assert_eq!(
            Arm::Qp.settings(&base),
            Human2NavSettings { motions: 0, ..base }
        );
        assert!(Arm::ALL.iter().all(|a| a.settings(&base).motions == 0));
        let tuned = GuidanceSettings::default().iterations_m;
        assert!(tuned > 0);
        assert_eq!(base.guidance.iterations_m, tuned);
        let alg1 = Arm::Alg1.settings(&base);
        assert!(alg1.guidance.enabled && !alg1.projection.enabled);
        assert_eq!(alg1.guidance.iterations_m, tuned);
        let both = Arm::Both.settings(&base);
        assert!(both.guidance.enabled && both.projection.enabled);
        assert_eq!(both.guidance.iterations_m, tuned);
        assert_eq!(both.samples, base.samples);
        assert_eq!(both.selection, base.selection);
        // A configured count is kept by the arms that run Algorithm 1; QP switches it off.
        let mut five = base;
        five.guidance.iterations_m = 5;
        assert_eq!(Arm::Alg1.settings(&five).guidance.iterations_m, 5);
        assert_eq!(Arm::Both.settings(&five).guidance.iterations_m, 5);
        assert!(!Arm::Qp.settings(&five).guidance.enabled);
    }

    #[test]
    fn steps_measure_each_plan_against_the_raw_one() {
        let limits = Limits {
            v_max: 1.5,
            v_reverse_max: 0.5,
            a_max: 1.0,
            omega_max: 2.0,
            kappa_max: None,
            lateral_speed_max: 0.05,
            coupled: None,
        };
        let mut slow = Straight {
            speed: 1.0,
            resets: 0,
        };
        // Twice the speed limit: every waypoint violates it, and the first also accelerates
        // from 1 m/s to 2·v_max in one step.
        let mut fast = Straight {
            speed: 2.0 * limits.v_max,
            resets: 0,
        };
        // Somebody standing 1 m ahead: the slow plan stops short of touching them (its last
        // pose 0.4 m ahead, the discs of 0.3 m just touching), the fast one runs into them.
        let obs = Observation {
            agents: vec![AgentState {
                id: 1,
                position: [1.0, 0.0],
                velocity: [0.0, 0.0],
                radius: 0.3,
                history: vec![],
            }],
            ..observation()
        };
        let disc = [FootprintShape::Disc {
            center: [0.0, 0.0],
            radius: 0.3,
        }];
        let mut arms: [(Arm, &mut dyn Planner); 2] =
            [(Arm::Raw, &mut slow), (Arm::Alg1, &mut fast)];
        let steps = ablation_step(&mut arms, &obs, &limits, &disc).unwrap();
        assert!(!steps[0].plan_contact && steps[1].plan_contact);
        assert_eq!(steps[0].contact_samples, None, "no samples, no share");
        assert_eq!(slow.resets, 1);
        assert_eq!(fast.resets, 1);
        assert_eq!(steps[0].tfs, 1.0);
        assert_eq!(steps[0].displacement, 0.0);
        assert_eq!(steps[1].tfs, 0.0);
        let share = |name: &str, v: [f64; feasibility::LIMIT_COUNT]| {
            v[Violations::NAMES.iter().position(|n| *n == name).unwrap()]
        };
        assert_eq!(share("speed", steps[1].violations), 1.0);
        assert_eq!(share("lateral", steps[1].violations), 0.0);
        assert!(share("acceleration", steps[1].violations) > 0.0);
        // Waypoint k is 0.1·k·(2 v_max − 1) m ahead of the raw plan's: mean of k = 0..4 is 10/5.
        let gap = 0.1 * (2.0 * limits.v_max - 1.0) * 10.0 / 5.0;
        assert!((steps[1].displacement - gap).abs() < 1e-12);
        assert_eq!(steps[1].iterations, Some(3));

        let summary = ArmSummary::of(
            Arm::Alg1,
            &[steps[1].clone(), steps[0].clone(), steps[1].clone()],
        );
        assert_eq!(summary.windows, 2);
        assert_eq!(summary.tfs, 0.0);
        assert_eq!(summary.all_feasible, 0.0);
        assert_eq!(share("speed", summary.violations), 1.0);
        assert_eq!(summary.iterations, 3.0);
        assert!(summary.phi_before.is_nan());
        assert_eq!(summary.plan_contact, 1.0);
        assert!(summary.contact_samples.is_nan());
        let raw = ArmSummary::of(Arm::Raw, &steps);
        assert_eq!(raw.plan_contact, 0.0);
        assert_eq!(raw.all_feasible, 1.0);
        assert_eq!(ArmSummary::of(Arm::Qp, &steps).windows, 0);
    }

    #[test]
    fn displacement_is_the_mean_position_gap() {
        let a = [Pose2::new(0.0, 0.0, 0.0), Pose2::new(1.0, 0.0, 0.3)];
        let b = [Pose2::new(0.0, 0.0, 1.0), Pose2::new(1.0, 2.0, 0.0)];
        assert!((mean_displacement(&a, &b) - 1.0).abs() < 1e-12);
        assert_eq!(mean_displacement(&a, &[]), 0.0);
    }
}
