//! `human2nav replay <bag>`: the planner run on what a robot recorded. A ROS 2 bag (MCAP
//! storage, CDR) gives the robot's odometry, its goal, the people a tracker saw and, when
//! there is one, an occupancy grid; at the planning rate, from the first time both odometry and
//! a goal are known to the last odometry message, Human2Nav plans from the latest of each, and
//! the plan (`nav_msgs/msg/Path`) and the first segment's velocity (`geometry_msgs/msg/Twist`)
//! are written to a new bag at that time, with a Foxglove scene of the calls beside it.
//!
//! People come from `people_msgs/msg/People` (id: the order in which each `name` first appears;
//! position and velocity as given) or from SPENCER's `spencer_tracking_msgs/msg/TrackedPersons`
//! (id: `track_id`; position `pose.pose.position`, velocity `twist.twist.linear`); each person's
//! recent positions are their earlier messages' at 0.1 s steps, and every person gets the disc
//! radius `--person-radius`. Every topic must be in the odometry's frame (no transforms are
//! applied); times are header stamps.

use anyhow::{Context, bail};
use clap::Args;
use human2nav_core::obstacle::OccupancyGrid;
use human2nav_core::{AgentState, Observation, Planner, Pose2, Twist2};
use human2nav_data::paths::find_workspace_root;
use human2nav_flow::planner::{PlannerConfig, PredictionModel, RobotPlanner};
use human2nav_sim::record::Recorder;
use human2nav_sim::rosbag::cdr::Value;
use human2nav_sim::rosbag::{
    self, BagWriter, Message, PATH_DEFINITION, TWIST_DEFINITION, Topic, TopicSpec,
};
use indicatif::{ProgressBar, ProgressStyle};
use std::collections::BTreeMap;
use std::path::PathBuf;
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
    /// Odometry topic (nav_msgs/msg/Odometry).
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
    /// Planning calls per second of recorded time.
    #[arg(long, default_value_t = 10.0)]
    pub rate: f64,
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

const STAMP: [(&str, &str); 3] = [
    ("header.stamp.sec", "int32"),
    ("header.stamp.nanosec", "uint32"),
    ("header.frame_id", "string"),
];

fn with_stamp(fields: &[(&'static str, &'static str)]) -> Vec<(&'static str, &'static str)> {
    STAMP.iter().chain(fields).copied().collect()
}

/// What the replay reads from each topic.
fn specs(args: &ReplayArgs) -> Vec<TopicSpec> {
    let f64s = |paths: &[&'static str]| -> Vec<(&'static str, &'static str)> {
        paths.iter().map(|p| (*p, "float64")).collect()
    };
    let odom = f64s(&[
        "pose.pose.position.x",
        "pose.pose.position.y",
        "pose.pose.orientation.x",
        "pose.pose.orientation.y",
        "pose.pose.orientation.z",
        "pose.pose.orientation.w",
        "twist.twist.linear.x",
        "twist.twist.linear.y",
        "twist.twist.angular.z",
    ]);
    let mut people = vec![
        ("people", "people_msgs/Person[]"),
        ("people.name", "string"),
    ];
    people.extend(f64s(&[
        "people.position.x",
        "people.position.y",
        "people.velocity.x",
        "people.velocity.y",
    ]));
    let mut tracks = vec![
        ("tracks", "spencer_tracking_msgs/TrackedPerson[]"),
        ("tracks.track_id", "uint64"),
    ];
    tracks.extend(f64s(&[
        "tracks.pose.pose.position.x",
        "tracks.pose.pose.position.y",
        "tracks.twist.twist.linear.x",
        "tracks.twist.twist.linear.y",
    ]));
    let mut map = vec![
        ("info.resolution", "float32"),
        ("info.width", "uint32"),
        ("info.height", "uint32"),
        ("data", "int8[]"),
    ];
    map.extend(f64s(&[
        "info.origin.position.x",
        "info.origin.position.y",
        "info.origin.orientation.z",
        "info.origin.orientation.w",
    ]));
    vec![
        TopicSpec {
            topic: args.odom.clone(),
            types: vec![("nav_msgs/msg/Odometry", with_stamp(&odom))],
        },
        TopicSpec {
            topic: args.goal.clone(),
            types: vec![(
                "geometry_msgs/msg/PoseStamped",
                with_stamp(&f64s(&["pose.position.x", "pose.position.y"])),
            )],
        },
        TopicSpec {
            topic: args.people.clone(),
            types: vec![
                ("people_msgs/msg/People", with_stamp(&people)),
                (
                    "spencer_tracking_msgs/msg/TrackedPersons",
                    with_stamp(&tracks),
                ),
            ],
        },
        TopicSpec {
            topic: args.map.clone(),
            types: vec![("nav_msgs/msg/OccupancyGrid", with_stamp(&map))],
        },
    ]
}

/// A number the spec guarantees (checked against the definition; 0 if it is somehow absent).
fn num(v: &Value, path: &str) -> f64 {
    v.number(path).unwrap_or(0.0)
}

fn yaw(v: &Value, prefix: &str) -> f64 {
    let q = |c: &str| num(v, &format!("{prefix}.{c}"));
    let (x, y, z, w) = (q("x"), q("y"), q("z"), q("w"));
    (2.0 * (w * z + x * y)).atan2(1.0 - 2.0 * (y * y + z * z))
}

/// The latest message of `topic` stamped at or before `t` (ns).
fn latest(topic: Option<&Topic>, t: i128) -> Option<&Message> {
    let msgs = &topic?.messages;
    let n = msgs.partition_point(|m| m.stamp.unwrap_or(i128::MIN) <= t);
    n.checked_sub(1).map(|i| &msgs[i])
}

/// One person seen in a tracker message.
#[derive(Clone, Copy, Debug)]
struct Seen {
    id: u64,
    position: [f64; 2],
    velocity: [f64; 2],
}

/// The people of one message of the people topic (`names` numbers people_msgs' names).
fn people_of(msg: &Message, msgtype: &str, names: &mut BTreeMap<String, u64>) -> Vec<Seen> {
    let v = &msg.value;
    if msgtype.starts_with("spencer_tracking_msgs") {
        v.list("tracks")
            .unwrap_or_default()
            .iter()
            .map(|p| Seen {
                id: num(p, "track_id") as u64,
                position: [
                    num(p, "pose.pose.position.x"),
                    num(p, "pose.pose.position.y"),
                ],
                velocity: [
                    num(p, "twist.twist.linear.x"),
                    num(p, "twist.twist.linear.y"),
                ],
            })
            .collect()
    } else {
        v.list("people")
            .unwrap_or_default()
            .iter()
            .map(|p| {
                let next = names.len() as u64;
                let id = *names
                    .entry(p.text("name").unwrap_or("").to_string())
                    .or_insert(next);
                Seen {
                    id,
                    position: [num(p, "position.x"), num(p, "position.y")],
                    velocity: [num(p, "velocity.x"), num(p, "velocity.y")],
                }
            })
            .collect()
    }
}

/// A `nav_msgs/OccupancyGrid` message as the planner's grid.
fn grid_of(v: &Value) -> OccupancyGrid {
    let data = v
        .list("data")
        .unwrap_or_default()
        .iter()
        .map(|c| match c {
            Value::Int(i) => *i as i8,
            _ => -1,
        })
        .collect();
    OccupancyGrid {
        origin: Pose2::new(
            num(v, "info.origin.position.x"),
            num(v, "info.origin.position.y"),
            yaw(v, "info.origin.orientation"),
        ),
        resolution: num(v, "info.resolution"),
        width: num(v, "info.width") as usize,
        height: num(v, "info.height") as usize,
        data,
        occupied_threshold: 65,
    }
}

/// Refuses a message whose frame is not `frame`.
fn same_frame(topic: &str, msg: &Message, frame: &str) -> anyhow::Result<()> {
    let f = msg.value.text("header.frame_id").unwrap_or("");
    if !f.is_empty() && !frame.is_empty() && f != frame {
        bail!(
            "topic `{topic}`, message {}: frame `{f}`, but the odometry is in `{frame}`; replay \
             applies no transforms, so record every topic in one frame",
            msg.index
        );
    }
    Ok(())
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
    let file = rosbag::mcap_file(&args.bag)?;
    let topics = rosbag::read_topics(&file, &specs(&args))?;
    let required = |name: &str| -> anyhow::Result<&Topic> {
        match topics.get(name) {
            Some(t) if !t.messages.is_empty() => Ok(t),
            _ => bail!(
                "`{}` has no messages on topic `{name}` (name another with --{})",
                file.display(),
                if name == args.odom { "odom" } else { "goal" }
            ),
        }
    };
    let odom = required(&args.odom)?;
    let goal = required(&args.goal)?;
    let people = topics.get(&args.people);
    let map = topics.get(&args.map);
    let frame = odom.messages[0]
        .value
        .text("header.frame_id")
        .unwrap_or("")
        .to_string();
    for (name, topic) in [
        (&args.goal, Some(goal)),
        (&args.people, people),
        (&args.map, map),
    ] {
        for m in topic.map(|t| t.messages.as_slice()).unwrap_or_default() {
            same_frame(name, m, &frame)?;
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
    let mut bag = BagWriter::create(&out)?;
    bag.add_topic(&args.plan_topic, "nav_msgs/msg/Path", PATH_DEFINITION)?;
    bag.add_topic(&args.cmd_topic, "geometry_msgs/msg/Twist", TWIST_DEFINITION)?;
    let mut scene = Recorder::create(&scene_path, if frame.is_empty() { "odom" } else { &frame })?;

    let stamp = |t: &Topic, i: usize| t.messages[i].stamp.unwrap_or(0);
    let start = stamp(odom, 0).max(stamp(goal, 0));
    let end = stamp(odom, odom.messages.len() - 1);
    if start > end {
        bail!(
            "the first goal on `{}` comes after the last odometry on `{}`: nothing to plan",
            args.goal,
            args.odom
        );
    }
    let step = (1e9 / args.rate).round() as i128;
    let calls = ((end - start) / step) as u64 + 1;
    let bar = ProgressBar::new(calls).with_style(
        ProgressStyle::with_template("{elapsed_precise} [{bar:40}] {pos}/{len} planning calls")
            .unwrap_or_else(|_| ProgressStyle::default_bar())
            .progress_chars("=> "),
    );
    // Every person's track: (stamp, position), in order.
    let mut names = BTreeMap::new();
    let mut tracks: BTreeMap<u64, Vec<(i128, [f64; 2])>> = BTreeMap::new();
    let seen: Vec<(i128, Vec<Seen>)> = people
        .map(|p| {
            p.messages
                .iter()
                .map(|m| (m.stamp.unwrap_or(0), people_of(m, &p.msgtype, &mut names)))
                .collect()
        })
        .unwrap_or_default();
    for (t, list) in &seen {
        for s in list {
            tracks.entry(s.id).or_default().push((*t, s.position));
        }
    }
    let history_at = |id: u64, t: i128| -> Vec<[f64; 2]> {
        let Some(track) = tracks.get(&id) else {
            return Vec::new();
        };
        (1..=8)
            .rev()
            .filter_map(|k| {
                let at = t - k * 100_000_000;
                let n = track.partition_point(|(s, _)| *s <= at);
                n.checked_sub(1).map(|i| track[i].1)
            })
            .collect()
    };

    let (mut failed, mut last_goal) = (0usize, None);
    for k in 0..calls {
        let t = start + i128::from(k) * step;
        let (Some(o), Some(g)) = (latest(Some(odom), t), latest(Some(goal), t)) else {
            continue;
        };
        let v = &o.value;
        let ego = Pose2::new(
            num(v, "pose.pose.position.x"),
            num(v, "pose.pose.position.y"),
            yaw(v, "pose.pose.orientation"),
        );
        let goal_xy = [
            num(&g.value, "pose.position.x"),
            num(&g.value, "pose.position.y"),
        ];
        // The latest people message, unless more than a second old.
        let now_seen: &[Seen] = match seen.partition_point(|(s, _)| *s <= t).checked_sub(1) {
            Some(i) if t - seen[i].0 <= 1_000_000_000 => &seen[i].1,
            _ => &[],
        };
        let agents: Vec<AgentState> = now_seen
            .iter()
            .map(|s| AgentState {
                id: s.id,
                position: s.position,
                velocity: s.velocity,
                radius: args.person_radius,
                history: history_at(s.id, t),
            })
            .collect();
        let time = (t - start) as f64 * 1e-9;
        let obs = Observation {
            time,
            frame_id: if frame.is_empty() {
                "odom".into()
            } else {
                frame.clone()
            },
            ego,
            ego_velocity: Twist2::new(
                num(v, "twist.twist.linear.x"),
                num(v, "twist.twist.linear.y"),
                num(v, "twist.twist.angular.z"),
            ),
            goal: goal_xy,
            agents,
            obstacles: Vec::new(),
            occupancy: latest(map, t).map(|m| grid_of(&m.value)),
        };
        if let Some(grid) = &obs.occupancy
            && let Err(e) = grid.validate()
        {
            let index = latest(map, t).map_or(0, |m| m.index);
            bail!(
                "topic `{}`, message {index}: the occupancy grid's {e}",
                args.map
            );
        }
        let ns = u64::try_from(t).unwrap_or(0);
        if last_goal != Some(g.index) {
            scene.static_scene(time, &rp.profile.footprint_shapes, goal_xy, &[])?;
            last_goal = Some(g.index);
        }
        scene.robot(time, ego)?;
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
            }
            Ok(_) | Err(_) => {
                failed += 1;
                bag.write(&args.cmd_topic, ns, &rosbag::twist_message(0.0, 0.0, 0.0))?;
                scene.log(time, 3, "planning call failed: stop")?;
            }
        }
        bar.inc(1);
    }
    bar.finish_and_clear();
    bag.finish()?;
    scene.finish()?;
    println!(
        "{} planning calls at {} Hz over {:.1} s of `{}` ({} odometry, {} goal, {} people \
         messages)",
        calls,
        args.rate,
        (end - start) as f64 * 1e-9,
        file.display(),
        odom.messages.len(),
        goal.messages.len(),
        people.map_or(0, |p| p.messages.len())
    );
    println!(
        "bag:   {} ({} and {})",
        out.display(),
        args.plan_topic,
        args.cmd_topic
    );
    println!("scene: {}", scene_path.display());
    if failed > 0 {
        eprintln!("{failed} planning calls failed: a zero velocity was written for each");
        return Ok(ExitCode::FAILURE);
    }
    Ok(ExitCode::SUCCESS)
}
