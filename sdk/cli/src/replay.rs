//! `human2nav replay <bag>`: the planner run on what a robot recorded. A ROS 2 bag (MCAP
//! storage, CDR) gives the robot's odometry, its goal, the people a tracker saw, when there is
//! one an occupancy grid, and the transforms between their frames; at the planning rate, from
//! the first time both odometry and a goal are known to the last odometry message, Human2Nav
//! plans from the latest of each, and the plan (`nav_msgs/msg/Path`) and the first segment's
//! velocity (`geometry_msgs/msg/Twist`) are written to a new bag at that time, with a Foxglove
//! scene of the calls beside it.
//!
//! The bag is read as a stream, and what the planner gets (topics and their mapping, frames,
//! timing) is [`human2nav_sim::rosbag::inputs`]; this module loads the planner and writes the
//! outputs.

use anyhow::{Context, bail};
use clap::Args;
use human2nav_core::{Observation, Planner};
use human2nav_data::paths::find_workspace_root;
use human2nav_flow::planner::{PlannerConfig, PredictionModel, RobotPlanner};
use human2nav_sim::record::Recorder;
use human2nav_sim::rosbag::inputs::{Call, InputSettings, InputTopics, ReplayInputs};
use human2nav_sim::rosbag::{self, BagWriter, PATH_DEFINITION, TWIST_DEFINITION};
use indicatif::{ProgressBar, ProgressStyle};
use std::path::{Path, PathBuf};
use std::process::ExitCode;

/// Arguments of `human2nav replay`.
#[derive(Debug, Args)]
pub struct ReplayArgs {
    /// The bag: an .mcap file, or a rosbag2 folder holding one.
    pub bag: PathBuf,
    /// The robot profile to plan for (robot.toml).
    #[arg(long)]
    pub robot: PathBuf,
    /// Planner configuration [default: sdk/configs/planner.toml under the workspace root].
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Model folder [default: the configuration's].
    #[arg(long)]
    pub model: Option<PathBuf>,
    /// The bag written: the plans and commands [default: out/replay/<bag name>.mcap under the
    /// workspace root]; the Foxglove scene goes beside it as <name>.scene.mcap.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Odometry topic (nav_msgs/msg/Odometry); its frame is the one everything is planned in.
    #[arg(long, default_value = "/odom")]
    pub odom: String,
    /// Goal topic (geometry_msgs/msg/PoseStamped).
    #[arg(long, default_value = "/goal_pose")]
    pub goal: String,
    /// Tracked people (people_msgs/msg/People or spencer_tracking_msgs/msg/TrackedPersons); a
    /// bag without it is replayed with nobody around.
    #[arg(long, default_value = "/people")]
    pub people: String,
    /// Occupancy grid topic (nav_msgs/msg/OccupancyGrid), used when the bag has it.
    #[arg(long, default_value = "/map")]
    pub map: String,
    /// Transforms (tf2_msgs/msg/TFMessage) that bring the goal, people and map into the
    /// odometry's frame; each message is transformed with the latest at or before its stamp.
    #[arg(long, default_value = "/tf")]
    pub tf: String,
    /// Static transforms (tf2_msgs/msg/TFMessage), valid at any stamp.
    #[arg(long, default_value = "/tf_static")]
    pub tf_static: String,
    /// Planning calls per second of recorded time.
    #[arg(long, default_value_t = 10.0)]
    pub rate: f64,
    /// How late (s) a message may be logged, after the odometry of its stamp, and still count
    /// for the calls at or after its stamp; one logged later counts from the next call on. The
    /// replay holds about this many seconds of messages.
    #[arg(long, default_value_t = 1.0)]
    pub max_delay: f64,
    /// Disc radius given to every person (m).
    #[arg(long, default_value_t = 0.3)]
    pub person_radius: f64,
    /// Topic of the plans written.
    #[arg(long, default_value = "/human2nav/plan")]
    pub plan_topic: String,
    /// Topic of the velocity commands written.
    #[arg(long, default_value = "/human2nav/cmd_vel")]
    pub cmd_topic: String,
}

/// Runs `human2nav replay`.
pub fn run(args: ReplayArgs) -> anyhow::Result<ExitCode> {
    if !(args.rate.is_finite() && args.rate > 0.0 && args.rate <= 1000.0) {
        bail!(
            "--rate {}: give calls per second, above 0 and at most 1000",
            args.rate
        );
    }
    if !(args.person_radius.is_finite() && args.person_radius > 0.0 && args.person_radius < 5.0) {
        bail!(
            "--person-radius {}: give metres, above 0 and below 5",
            args.person_radius
        );
    }
    if !(args.max_delay.is_finite() && args.max_delay >= 0.0 && args.max_delay <= 60.0) {
        bail!("--max-delay {}: give seconds, from 0 to 60", args.max_delay);
    }
    let file = rosbag::mcap_file(&args.bag)?;
    let topics = InputTopics {
        odom: args.odom.clone(),
        goal: args.goal.clone(),
        people: args.people.clone(),
        map: args.map.clone(),
        tf: args.tf.clone(),
        tf_static: args.tf_static.clone(),
    };
    let settings = InputSettings {
        rate: args.rate,
        person_radius: args.person_radius,
        max_delay: args.max_delay,
    };
    let mut inputs = ReplayInputs::open(&file, &topics, settings)?;
    // Where the file's summary counts the messages, a missing topic is refused before the
    // planner is loaded.
    if let Some(counts) = inputs.reader().summary_counts() {
        for (name, flag) in [(&args.odom, "odom"), (&args.goal, "goal")] {
            if counts.get(name).copied().unwrap_or(0) == 0 {
                bail!(no_messages(&file, name, flag));
            }
        }
    }

    let cwd = std::env::current_dir().context("reading the current directory")?;
    let workspace = find_workspace_root(&cwd).unwrap_or(cwd);
    let cfg = match &args.config {
        Some(p) => PlannerConfig::load(p)?,
        None => PlannerConfig::load(&workspace.join("sdk/configs/planner.toml"))?,
    };
    let model_dir = args
        .model
        .clone()
        .unwrap_or_else(|| cfg.model_dir(&workspace));
    human2nav_flow::tch::set_num_threads(i32::try_from(cfg.threads).unwrap_or(1));
    let mut rp = RobotPlanner::load_with(&args.robot, &model_dir, cfg.backend, cfg.human2nav)
        .with_context(|| format!("loading the planner for {}", args.robot.display()))?;
    if let Some(p) = PredictionModel::load(&cfg, &workspace)? {
        rp = rp.with_predictor(p.predictor()?);
    }

    let out = args.out.clone().unwrap_or_else(|| {
        let stem = file
            .file_stem()
            .map_or("bag".into(), |s| s.to_string_lossy().to_string());
        workspace.join(format!("out/replay/{stem}.mcap"))
    });
    let scene_path = out.with_extension("scene.mcap");
    let done = replay(&args, &file, &mut inputs, &mut rp, &out, &scene_path);
    if done.is_err() {
        // A bag found broken part way through leaves no half-written outputs behind.
        let _ = std::fs::remove_file(&out);
        let _ = std::fs::remove_file(&scene_path);
    }
    done
}

fn no_messages(file: &Path, topic: &str, flag: &str) -> String {
    format!(
        "`{}` has no messages on topic `{topic}` (name another with --{flag})",
        file.display()
    )
}

/// Why a bag gave no planning call.
fn no_calls(args: &ReplayArgs, file: &Path, inputs: &ReplayInputs) -> anyhow::Error {
    let counts = inputs.reader().counts();
    let count = |t: &str| counts.get(t).copied().unwrap_or(0);
    if count(&args.odom) == 0 {
        return anyhow::anyhow!(no_messages(file, &args.odom, "odom"));
    }
    if count(&args.goal) == 0 {
        return anyhow::anyhow!(no_messages(file, &args.goal, "goal"));
    }
    if inputs.first_goal().is_none() {
        return anyhow::anyhow!(
            "none of the {} goals on `{}` could be brought into the odometry's frame: each is \
             stamped before the first transform of its frame (the first: {})",
            count(&args.goal),
            args.goal,
            inputs
                .stats()
                .first_untransformed
                .as_deref()
                .unwrap_or("none")
        );
    }
    anyhow::anyhow!(
        "the first goal on `{}` comes after the last odometry on `{}`: nothing to plan",
        args.goal,
        args.odom
    )
}

/// The planning calls, and the bag and scene they write.
fn replay(
    args: &ReplayArgs,
    file: &Path,
    inputs: &mut ReplayInputs,
    rp: &mut RobotPlanner,
    out: &Path,
    scene_path: &Path,
) -> anyhow::Result<ExitCode> {
    let bar = ProgressBar::new_spinner().with_style(
        ProgressStyle::with_template("{elapsed_precise} {spinner} {pos} planning calls, {msg}")
            .unwrap_or_else(|_| ProgressStyle::default_spinner()),
    );
    let mut outputs: Option<(BagWriter, Recorder)> = None;
    let (mut failed, mut last_goal) = (0usize, None);
    while let Some(call) = inputs.next_call()? {
        let start = inputs.start().unwrap_or(call.stamp);
        let time = (call.stamp - start) as f64 * 1e-9;
        let (bag, scene) = match &mut outputs {
            Some(o) => o,
            None => {
                let mut bag = BagWriter::create(out)?;
                bag.add_topic(&args.plan_topic, "nav_msgs/msg/Path", PATH_DEFINITION)?;
                bag.add_topic(&args.cmd_topic, "geometry_msgs/msg/Twist", TWIST_DEFINITION)?;
                let scene = Recorder::create(scene_path, &call.frame)?;
                outputs.insert((bag, scene))
            }
        };
        if last_goal != Some(call.goal_index) {
            scene.static_scene(time, &rp.profile.footprint_shapes, call.goal, &[])?;
            last_goal = Some(call.goal_index);
        }
        if !plan_once(args, rp, &call, time, bag, scene)? {
            failed += 1;
        }
        bar.inc(1);
        bar.set_message(format!("{time:.1} s of recorded time"));
    }
    bar.finish_and_clear();
    let Some((bag, scene)) = outputs else {
        return Err(no_calls(args, file, inputs));
    };
    bag.finish()?;
    scene.finish()?;
    let counts = inputs.reader().counts();
    let count = |t: &str| counts.get(t).copied().unwrap_or(0);
    let (start, end) = (
        inputs.start().unwrap_or(0),
        inputs.odometry_span().map_or(0, |(_, e)| e),
    );
    println!(
        "{} planning calls at {} Hz over {:.1} s of `{}` ({} odometry, {} goal, {} people \
         messages)",
        inputs.calls(),
        args.rate,
        (end - start) as f64 * 1e-9,
        file.display(),
        count(&args.odom),
        count(&args.goal),
        count(&args.people)
    );
    let stats = inputs.stats();
    println!(
        "read:  {} messages {}; held at most {} at once (messages waiting for their planning \
         time, and transforms)",
        inputs.reader().seen(),
        if inputs.reader().indexed() {
            "in log-time order, through the file's index"
        } else {
            "in file order (the file has no index)"
        },
        stats.peak_held
    );
    println!(
        "bag:   {} ({} and {})",
        out.display(),
        args.plan_topic,
        args.cmd_topic
    );
    println!("scene: {}", scene_path.display());
    if stats.late > 0 {
        eprintln!(
            "{} messages were logged more than --max-delay {} s after the odometry of their \
             stamp: each counted from the next planning call on",
            stats.late, args.max_delay
        );
    }
    if let Some(first) = &stats.first_untransformed {
        eprintln!(
            "{} messages were left out, stamped before the first transform of their frame (the \
             first: {first})",
            stats.untransformed
        );
    }
    if failed > 0 {
        eprintln!("{failed} planning calls failed: a zero velocity was written for each");
        return Ok(ExitCode::FAILURE);
    }
    Ok(ExitCode::SUCCESS)
}

/// One planning call: the plan and its first segment's velocity written, or a zero velocity
/// where it failed (false).
fn plan_once(
    args: &ReplayArgs,
    rp: &mut RobotPlanner,
    call: &Call,
    time: f64,
    bag: &mut BagWriter,
    scene: &mut Recorder,
) -> anyhow::Result<bool> {
    let obs = Observation {
        time,
        frame_id: call.frame.clone(),
        ego: call.ego,
        ego_velocity: call.ego_velocity,
        goal: call.goal,
        agents: call.agents.clone(),
        obstacles: Vec::new(),
        occupancy: call.occupancy.clone(),
    };
    let ns = u64::try_from(call.stamp).unwrap_or(0);
    scene.robot(time, call.ego)?;
    scene.observed_people(time, &obs.agents)?;
    match rp.planner.plan(&obs) {
        Ok(plan) if plan.poses.len() > 1 && plan.dt > 0.0 => {
            let poses: Vec<[f64; 3]> = plan.poses.iter().map(|p| [p.x, p.y, p.theta]).collect();
            bag.write(
                &args.plan_topic,
                ns,
                &rosbag::path_message(ns, &obs.frame_id, &poses),
            )?;
            let (a, b) = (plan.poses[0], plan.poses[1]);
            let (dx, dy) = (b.x - a.x, b.y - a.y);
            let (c, s) = (a.theta.cos(), a.theta.sin());
            let dtheta = (b.theta - a.theta + std::f64::consts::PI)
                .rem_euclid(2.0 * std::f64::consts::PI)
                - std::f64::consts::PI;
            let twist = rosbag::twist_message(
                (c * dx + s * dy) / plan.dt,
                (-s * dx + c * dy) / plan.dt,
                dtheta / plan.dt,
            );
            bag.write(&args.cmd_topic, ns, &twist)?;
            let candidates = if plan.info.guided.is_empty() {
                &plan.info.candidates
            } else {
                &plan.info.guided
            };
            scene.plan(time, &plan.poses, candidates)?;
            Ok(true)
        }
        Ok(_) | Err(_) => {
            bag.write(&args.cmd_topic, ns, &rosbag::twist_message(0.0, 0.0, 0.0))?;
            scene.log(time, 3, "planning call failed: stop")?;
            Ok(false)
        }
    }
}
