//! A first program written against the prelude alone: the shipped model plans one step for
//! each shipped robot on a synthetic crowd, and the plan is within the robot's limits.

use human2nav::prelude::*;
use std::path::PathBuf;

#[test]
fn the_prelude_plans_a_feasible_step_with_the_shipped_model() {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..");
    let config = PlannerConfig::load(&root.join("sdk/configs/planner.toml")).expect("planner.toml");
    let model_dir = config.model_dir(&root);
    let episode = synthetic_episodes(ScenarioClass::CrossFlow, 1, 7)
        .into_iter()
        .next()
        .expect("one synthetic episode");
    let obs = observation_at(&episode, &StepOptions::default()).expect("observation");
    for robot in ["diablo", "ackermann", "go2"] {
        let toml = root.join(format!("robots/{robot}/robot.toml"));
        let mut planner = RobotPlanner::load(&toml, &model_dir, config.human2nav)
            .unwrap_or_else(|e| panic!("{robot}: {e}"));
        let limits = *planner.limits();
        let plan = planner.planner.plan(&obs).expect("plan");
        assert!(plan.is_finite(), "{robot}: non-finite plan");
        assert!(!plan.poses.is_empty(), "{robot}: empty plan");
        let ok = feasibility_mask(&plan.poses, plan.dt, &limits, obs.ego_velocity);
        assert!(
            ok.iter().all(|&f| f),
            "{robot}: infeasible waypoints {ok:?}"
        );
    }
}
