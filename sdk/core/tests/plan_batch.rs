//! `Human2Nav::plan_batch`: the plans of several planners planned at once equal their plans
//! planned one by one, and the sampling's network calls are batched.

#![allow(clippy::unwrap_used)] // test helpers outside #[test] functions unwrap too

mod common;

use common::robot;
use human2nav_core::ablation::Arm;
use human2nav_core::bev::BevSpec;
use human2nav_core::flow::{FlowCondition, FlowError, FlowModel, FlowQuery};
use human2nav_core::guidance::analytic::FixedWalk;
use human2nav_core::human2nav::{Human2Nav, Human2NavSettings};
use human2nav_core::{AgentState, Observation, PlanError, Planner, Pose2, Twist2};
use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};

/// Network calls made through one model handle.
#[derive(Debug, Default)]
struct Calls {
    velocity: AtomicUsize,
    batched: AtomicUsize,
}

/// A walk straight ahead bent by the condition (goal, crowd raster) and by the poses
/// themselves, so that a velocity computed for the wrong planner, condition or input shows;
/// handles made by [`Self::handle`] report one network.
#[derive(Debug)]
struct SceneWalk {
    walk: FixedWalk,
    calls: Arc<Calls>,
}

impl SceneWalk {
    fn handle() -> Self {
        Self {
            walk: FixedWalk::straight(0.12, 32),
            calls: Arc::new(Calls::default()),
        }
    }

    fn field(&self, x: &[f64], t: f64, c: &FlowCondition, out: &mut [f64]) {
        self.walk.velocity(x, t, c, out).unwrap();
        let crowd: f64 = c.bev.iter().map(|&v| f64::from(v)).sum();
        for (o, p) in out.chunks_exact_mut(3).zip(x.chunks_exact(3)) {
            o[0] += 0.05 * p[1];
            o[1] += 0.01 * c.goal[1] + 0.002 * crowd * (1.0 - t);
        }
    }
}

impl FlowModel for SceneWalk {
    fn horizon(&self) -> usize {
        self.walk.horizon()
    }

    fn source_std(&self) -> [f64; 3] {
        [0.05; 3]
    }

    fn velocity(
        &self,
        x: &[f64],
        t: f64,
        c: &FlowCondition,
        out: &mut [f64],
    ) -> Result<(), FlowError> {
        self.calls.velocity.fetch_add(1, Ordering::Relaxed);
        self.field(x, t, c, out);
        Ok(())
    }

    fn velocity_vjp(
        &self,
        x: &[f64],
        t: f64,
        c: &FlowCondition,
        cotangent: &[f64],
        out: &mut [f64],
        vjp: &mut [f64],
    ) -> Result<(), FlowError> {
        self.field(x, t, c, out);
        vjp.fill(0.0);
        for (g, w) in vjp.chunks_exact_mut(3).zip(cotangent.chunks_exact(3)) {
            g[1] = 0.05 * w[0];
        }
        Ok(())
    }

    fn velocity_batch(&self, queries: &[FlowQuery<'_>], out: &mut [f64]) -> Result<(), FlowError> {
        self.calls.batched.fetch_add(1, Ordering::Relaxed);
        let mut rest = out;
        for q in queries {
            let (o, r) = rest.split_at_mut(q.x.len());
            self.field(q.x, q.t, q.cond, o);
            rest = r;
        }
        Ok(())
    }

    fn network_id(&self) -> Option<usize> {
        Some(1)
    }
}

/// Planners of different settings: the shipped one, crowd guidance (two conditions per step),
/// the raw samples with another `K`, and (`guided`) Algorithm 1 on.
fn settings(guided: bool) -> Vec<Human2NavSettings> {
    let shipped = Human2NavSettings::default();
    let mut all = vec![
        shipped,
        Human2NavSettings {
            crowd_weight: 2.0,
            seed: 3,
            ..shipped
        },
        Human2NavSettings {
            samples: 7,
            ..Arm::Raw.settings(&shipped)
        },
    ];
    if guided {
        all.push(Arm::Both.settings(&shipped));
    }
    all
}

fn planners(settings: &[Human2NavSettings]) -> Vec<Human2Nav<SceneWalk>> {
    settings
        .iter()
        .map(|s| {
            let bev = BevSpec::default();
            Human2Nav::new(SceneWalk::handle(), robot(), bev, *s).unwrap()
        })
        .collect()
}

/// Planner `i`'s observation at call `n`: its own pose, goal and people.
fn observation(i: usize, n: usize) -> Observation {
    let (i, n) = (i as f64, n as f64);
    Observation {
        time: 0.1 * n,
        ego: Pose2::new(0.3 * i + 0.05 * n, -0.2 * i, 0.1 * i),
        ego_velocity: Twist2::new(0.3 + 0.1 * i, 0.0, 0.05 * i),
        goal: [6.0 - i, 2.0 * i - 1.0],
        agents: vec![AgentState {
            id: 1,
            position: [2.0 + 0.3 * i - 0.1 * n, 0.5 - 0.4 * i],
            velocity: [-0.6, 0.1 * i],
            radius: 0.25,
            history: vec![],
        }],
        ..Default::default()
    }
}

#[test]
fn batched_plans_equal_plans_made_one_by_one() {
    let settings = settings(true);
    let mut alone = planners(&settings);
    let mut batched = planners(&settings);
    // Three calls in a row: the warm start and the generators carry over alike.
    for n in 0..3 {
        let obs: Vec<Observation> = (0..settings.len()).map(|i| observation(i, n)).collect();
        let mut refs: Vec<&mut Human2Nav<SceneWalk>> = batched.iter_mut().collect();
        let plans = Human2Nav::plan_batch(&mut refs, &obs).unwrap();
        for (i, (p, plan)) in alone.iter_mut().zip(plans).enumerate() {
            let plan = plan.unwrap();
            assert!(
                !plan.info.fallback,
                "planner {i}, call {n}: {:?}",
                plan.info
            );
            assert_eq!(plan, p.plan(&obs[i]).unwrap(), "planner {i}, call {n}");
        }
    }
}

#[test]
fn the_sampling_of_all_planners_is_one_network_call_per_step() {
    let settings = settings(false);
    let steps = settings[0].guidance.steps_n;
    assert!(settings.iter().all(|s| s.guidance.steps_n == steps));
    let mut batched = planners(&settings);
    let obs: Vec<Observation> = (0..settings.len()).map(|i| observation(i, 0)).collect();
    let mut refs: Vec<&mut Human2Nav<SceneWalk>> = batched.iter_mut().collect();
    let plans = Human2Nav::plan_batch(&mut refs, &obs).unwrap();
    assert!(
        plans
            .iter()
            .all(|p| p.as_ref().is_ok_and(|p| !p.info.fallback))
    );
    // The batch ran on the first planner's handle; no planner called its network alone.
    let calls: Vec<(usize, usize)> = batched
        .iter()
        .map(|p| {
            let c = &p.model().calls;
            (
                c.velocity.load(Ordering::Relaxed),
                c.batched.load(Ordering::Relaxed),
            )
        })
        .collect();
    assert_eq!(calls[0], (0, steps), "{calls:?}");
    assert!(calls[1..].iter().all(|&c| c == (0, 0)), "{calls:?}");
}

#[test]
fn a_bad_observation_fails_its_planner_alone() {
    let settings = settings(false);
    let mut batched = planners(&settings);
    let mut obs: Vec<Observation> = (0..settings.len()).map(|i| observation(i, 0)).collect();
    obs[1].goal = [f64::NAN, 0.0];
    let mut refs: Vec<&mut Human2Nav<SceneWalk>> = batched.iter_mut().collect();
    let plans = Human2Nav::plan_batch(&mut refs, &obs).unwrap();
    assert!(
        matches!(plans[1], Err(PlanError::InvalidObservation(_))),
        "{:?}",
        plans[1]
    );
    for i in [0, 2] {
        assert!(
            plans[i]
                .as_ref()
                .is_ok_and(|p| p.poses.iter().all(|q| q.is_finite()))
        );
    }
    // One planner fewer than observations is refused.
    let err = Human2Nav::plan_batch(&mut refs[..2], &obs).unwrap_err();
    assert!(
        err.to_string().contains("2 planners for 3 observations"),
        "{err}"
    );
}
