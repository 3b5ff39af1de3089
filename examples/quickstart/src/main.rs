//! Quickstart: plan one step for a robot in a synthetic crowd, print the plan, draw it.
//!
//! ```sh
//! cargo run --release -p human2nav-quickstart                               # diablo, guided
//! cargo run --release -p human2nav-quickstart -- robots/ackermann/robot.toml
//! cargo run --release -p human2nav-quickstart -- robots/go2/robot.toml --no-guidance
//! ```
//!
//! The picture goes to `out/quickstart/<robot>.png`. See README.md for what to try next.

use anyhow::{Context, bail};
use clap::Parser;
use human2nav::core::ablation::Arm;
use human2nav::prelude::*;
use std::path::PathBuf;

/// Plans one step for a robot in a synthetic crowd with the shipped model, prints the plan
/// and draws it to `out/quickstart/<robot>.png`.
#[derive(Debug, Parser)]
#[command(name = "quickstart")]
struct Args {
    /// The robot profile (default: robots/diablo/robot.toml in the workspace).
    robot: Option<PathBuf>,
    /// Plan with the raw samples of the model (the guidance ablation's `raw` arm: no
    /// correction, no extra candidates, no motions of the robot's own).
    #[arg(long)]
    raw: bool,
}

fn main() -> anyhow::Result<()> {
    let args = Args::parse();
    let raw = args.raw;

    // Paths in the SDK are relative to the workspace root (the folder with the top Cargo.toml).
    let cwd = std::env::current_dir()?;
    let root = find_workspace_root(&cwd)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../.."));
    let robot = args
        .robot
        .unwrap_or_else(|| root.join("robots/diablo/robot.toml"));

    // 1. The planner settings (K samples, guidance, selection) and the model folder.
    let mut config = PlannerConfig::load(&root.join("sdk/configs/planner.toml"))?;
    if raw {
        config.human2nav = Arm::Raw.settings(&config.human2nav);
    }
    let model_dir = config.model_dir(&root);
    if !model_dir.join("model.toml").is_file() {
        bail!(
            "no trained model at {}; train one with `human2nav train --config sdk/configs/train.toml`",
            model_dir.display()
        );
    }

    // 2. The robot (limits, footprint, Φ with any plugin terms) + the flow model = a planner.
    let mut robot = RobotPlanner::load(&robot, &model_dir, config.human2nav)
        .with_context(|| format!("building the planner for {}", robot.display()))?;
    let limits = *robot.limits();
    println!(
        "robot `{}`: v_max {} m/s, a_max {} m/s², ω_max {} rad/s, κ_max {:?} 1/m, lateral {} m/s",
        robot.profile.name,
        limits.v_max,
        limits.a_max,
        limits.omega_max,
        limits.kappa_max,
        limits.lateral_speed_max
    );

    // 3. A synthetic crossing crowd (no dataset needed) and what the robot sees at t = 0:
    //    itself at the start facing the goal, at rest, and the pedestrians within 10 m. Of a
    //    few generated scenes we take the busiest one.
    let mut scenes = Vec::new();
    for episode in synthetic_episodes(ScenarioClass::CrossFlow, 6, 7) {
        let obs = observation_at(&episode, &StepOptions::default())?;
        scenes.push((episode, obs));
    }
    let (episode, obs) = scenes
        .into_iter()
        .max_by_key(|(_, obs)| obs.agents.len())
        .context("the synthetic generator produced no episode")?;
    println!(
        "scene `{}`: {} pedestrians around, goal {:.1} m ahead",
        episode.id,
        obs.agents.len(),
        episode.goal_distance()
    );

    // 4. One planning call: K samples from the flow model, guided into the robot's limits,
    //    the best one by feasibility, goal progress and clearance, in the world frame.
    let plan = robot.planner.plan(&obs)?;

    // 5. What came out: poses every 0.4 s, with the feasibility of each waypoint, then TFS
    //    (share of feasible waypoints) and Φ (the soft constraint cost) before/after guidance.
    let ok = feasibility_mask(&plan.poses, plan.dt, &limits, obs.ego_velocity);
    println!("  t [s]   x [m]   y [m]  θ [rad]  feasible");
    for (k, p) in plan.poses.iter().enumerate().step_by(4) {
        let t = plan.t0 + k as f64 * plan.dt;
        println!("{t:7.1} {:7.2} {:7.2} {:8.2}  {}", p.x, p.y, p.theta, ok[k]);
    }
    let fig = PlanFigure {
        robot: &robot.profile.name,
        label: &episode.id,
        guidance: config.human2nav.guidance.enabled,
        observation: &obs,
        start: Some(episode.start),
        plan: &plan,
        limits: &limits,
        footprint_radius: robot.profile.footprint_radius,
        bev: robot.bev,
        // No predictor configured here: the pedestrians are predicted at constant velocity
        // and not drawn as a forecast.
        forecast: None,
    };
    let png = root.join(format!(
        "out/quickstart/{}{}.png",
        robot.profile.name,
        if raw { "-raw" } else { "" }
    ));
    let numbers = draw_plan_figure(&png, &fig)?;
    let phi = |v: Option<f64>| v.map_or_else(|| "–".to_string(), |x| format!("{x:.3}"));
    println!(
        "TFS {:.3} ({} of {} waypoints feasible); Φ {} before guidance, {} after",
        numbers.tfs,
        numbers.feasible,
        numbers.waypoints,
        phi(plan.info.phi_before),
        phi(plan.info.phi_after)
    );
    println!("picture: {}", png.display());
    Ok(())
}
