//! Batched planning with the shipped model on the native backend: one network pass for
//! several conditions gives each the values of its own pass, some rows of a kept pass serve a
//! later call at those rows, and robot planners planned as a batch plan what they plan one by
//! one.

#![allow(clippy::unwrap_used)] // test helpers outside #[test] functions unwrap too

use human2nav_core::bev::{BevAgent, BevSpec, rasterize_agents};
use human2nav_core::flow::{FlowCondition, FlowModel, FlowQuery};
use human2nav_core::human2nav::Human2Nav;
use human2nav_core::{AgentState, Observation, Planner, Pose2, Twist2};
use human2nav_flow::NativeCfm;
use human2nav_flow::planner::{PlannerConfig, PlannerModel, RobotPlanner};
use rand::{Rng, SeedableRng};
use std::path::{Path, PathBuf};

fn workspace() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

fn shipped() -> NativeCfm {
    NativeCfm::load(&workspace().join("models/human2nav-cfm")).unwrap()
}

/// A condition with `people` walkers scattered by `seed` (none: an empty raster).
fn condition(model: &NativeCfm, people: usize, seed: u64) -> FlowCondition {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let cells = model.card().net.bev_cells;
    let spec = BevSpec {
        cells,
        resolution: 0.3,
    };
    let mut bev = vec![0.0; spec.len()];
    let agents = (0..people).map(|_| BevAgent {
        position: [rng.random_range(-1.0..4.0), rng.random_range(-2.0..2.0)],
        velocity: [rng.random_range(-1.0..1.0), 0.0],
        radius: 0.3,
    });
    rasterize_agents(spec, Pose2::IDENTITY, agents, &mut bev);
    FlowCondition {
        bev,
        goal: [rng.random_range(1.0..6.0), rng.random_range(-3.0..3.0)],
        velocity: [rng.random_range(0.0..1.0), 0.0],
    }
}

fn poses(model: &NativeCfm, k: usize, seed: u64) -> Vec<f64> {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    (0..k * model.horizon() * 3)
        .map(|_| rng.random_range(-2.0..2.0))
        .collect()
}

#[test]
fn a_call_at_some_rows_of_a_kept_pass_gives_what_a_pass_of_its_own_gives() {
    // Algorithm 1 on a shortlist: the rollout evaluated 6 samples, the VJPs and the next
    // rollout's first step ask for rows 1, 4 and 5 (a crowd, so the crowd pathway's tape too).
    let cond = condition(&shipped(), 6, 7);
    let x = poses(&shipped(), 6, 8);
    let per = x.len() / 6;
    let rows = [1, 4, 5];
    let sub: Vec<f64> = rows
        .iter()
        .flat_map(|&r| x[r * per..(r + 1) * per].to_vec())
        .collect();
    let cot: Vec<f64> = (0..sub.len()).map(|i| (i as f64 * 0.61).sin()).collect();
    for t in [0.0, 0.6] {
        let kept = shipped();
        let mut all = vec![0.0; x.len()];
        kept.velocity(&x, t, &cond, &mut all).unwrap();
        let (mut out, mut vjp) = (vec![0.0; sub.len()], vec![0.0; sub.len()]);
        kept.velocity_vjp(&sub, t, &cond, &cot, &mut out, &mut vjp)
            .unwrap();
        let mut v = vec![0.0; sub.len()];
        kept.velocity(&sub, t, &cond, &mut v).unwrap();
        // A model of its own: nothing kept.
        let (mut out1, mut vjp1) = (vec![0.0; sub.len()], vec![0.0; sub.len()]);
        shipped()
            .velocity_vjp(&sub, t, &cond, &cot, &mut out1, &mut vjp1)
            .unwrap();
        let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&out), bits(&out1), "t = {t}");
        assert_eq!(bits(&v), bits(&out1), "t = {t}");
        assert_eq!(bits(&vjp), bits(&vjp1), "t = {t}");
        assert!(vjp.iter().any(|g| *g != 0.0));
    }
}

#[test]
fn a_batch_of_conditions_equals_their_calls_one_by_one() {
    let model = shipped();
    // Groups of different sizes, crowds and flow times; one condition twice.
    let conds: Vec<FlowCondition> = [(3, 1), (0, 2), (6, 3), (1, 4)]
        .iter()
        .map(|&(people, seed)| condition(&model, people, seed))
        .collect();
    let groups = [
        (0, 4, 0.0),
        (1, 1, 0.2),
        (2, 7, 0.4),
        (3, 4, 0.8),
        (0, 2, 0.6),
    ];
    let xs: Vec<Vec<f64>> = groups
        .iter()
        .enumerate()
        .map(|(i, &(_, k, _))| poses(&model, k, 10 + i as u64))
        .collect();
    let queries: Vec<FlowQuery<'_>> = groups
        .iter()
        .zip(&xs)
        .map(|(&(c, _, t), x)| FlowQuery {
            x,
            t,
            cond: &conds[c],
        })
        .collect();
    let alone: Vec<f64> = queries
        .iter()
        .flat_map(|q| {
            let mut v = vec![0.0; q.x.len()];
            // A model of its own: nothing cached from the batch.
            shipped().velocity(q.x, q.t, q.cond, &mut v).unwrap();
            v
        })
        .collect();
    let mut batched = vec![0.0; alone.len()];
    // Twice: the second call reuses the batch's encodings.
    for _ in 0..2 {
        model.velocity_batch(&queries, &mut batched).unwrap();
        assert_eq!(batched, alone);
    }
    // No query is no work; an output of the wrong size is refused.
    model.velocity_batch(&[], &mut []).unwrap();
    let err = model
        .velocity_batch(&queries, &mut batched[1..])
        .unwrap_err();
    assert!(err.to_string().contains("out"), "{err}");
}

fn observation(i: usize, n: usize) -> Observation {
    let (f, m) = (i as f64, n as f64);
    Observation {
        time: 0.1 * m,
        ego: Pose2::new(0.5 * f + 0.08 * m, -0.3 * f, 0.2 * f - 0.3),
        ego_velocity: Twist2::new(0.5, 0.0, 0.1),
        goal: [6.0 + f, 1.5 - f],
        agents: (0..i + 1)
            .map(|a| AgentState {
                id: a as u64,
                position: [2.0 + 0.8 * a as f64 - 0.1 * m, 0.6 * f - 0.5 * a as f64],
                velocity: [-0.7, 0.1 * a as f64],
                radius: 0.3,
                history: vec![],
            })
            .collect(),
        ..Default::default()
    }
}

#[test]
fn robot_planners_planned_as_a_batch_plan_what_they_plan_alone() {
    let root = workspace();
    let config = PlannerConfig::load(&root.join("sdk/configs/planner.toml")).unwrap();
    let model = shipped();
    // Two robots, the same network; one crowd-guided planner (two conditions a step).
    let robots = ["diablo", "go2", "diablo", "tracked"];
    let build = || -> Vec<RobotPlanner> {
        robots
            .iter()
            .enumerate()
            .map(|(i, r)| {
                let mut settings = config.human2nav;
                if i == 2 {
                    settings.crowd_weight = 1.5;
                }
                let profile = human2nav_flow::planner::load_profile(
                    &root.join(format!("robots/{r}/robot.toml")),
                )
                .unwrap();
                RobotPlanner::new(profile, PlannerModel::from(model.clone()), settings).unwrap()
            })
            .collect()
    };
    let (mut alone, mut batched) = (build(), build());
    for n in 0..3 {
        let obs: Vec<Observation> = (0..robots.len()).map(|i| observation(i, n)).collect();
        let mut refs: Vec<&mut Human2Nav<PlannerModel>> =
            batched.iter_mut().map(|p| &mut p.planner).collect();
        let plans = Human2Nav::plan_batch(&mut refs, &obs).unwrap();
        for (i, (p, plan)) in alone.iter_mut().zip(plans).enumerate() {
            let plan = plan.unwrap();
            assert!(!plan.info.fallback, "{i}, call {n}: {:?}", plan.info.notes);
            assert_eq!(plan, p.planner.plan(&obs[i]).unwrap(), "{i}, call {n}");
        }
    }
}
