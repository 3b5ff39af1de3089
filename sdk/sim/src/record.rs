//! Runs and planning calls as MCAP logs that Foxglove opens with no plugin: every message is
//! JSON in one of Foxglove's own schemas (`foxglove.FrameTransform`, `foxglove.PoseInFrame`,
//! `foxglove.PosesInFrame`, `foxglove.SceneUpdate`, `foxglove.Log`), each channel carrying its
//! JSON Schema (`jsonschema` encoding; the schemas here describe the fields written).
//!
//! Topics (frame `world` unless said):
//!
//! | topic | schema | what |
//! |---|---|---|
//! | `/tf` | `foxglove.FrameTransform` | `world` → `base_link`: the robot's pose, every step |
//! | `/robot/pose` | `foxglove.PoseInFrame` | the same pose, for plots |
//! | `/plan` | `foxglove.PosesInFrame` | each plan the robot followed, when it was made |
//! | `/scene/static` | `foxglove.SceneUpdate` | entities `footprint` (frame `base_link`: the collision footprint), `goal` and `obstacles`, once at the start |
//! | `/scene/people` | `foxglove.SceneUpdate` | entity `pedestrians` (discs as 1.7 m cylinders), every step |
//! | `/scene/plan` | `foxglove.SceneUpdate` | entities `plan` and `candidates` (line strips), with each plan |
//! | `/outcome` | `foxglove.Log` | how the run ended (info: success, warning: timeout, error: collision), at its end; a planning call's summary |
//!
//! The scene is three topics, not one, so that a viewer that jumps to a time (which shows the
//! latest message of each topic) shows all of it: the static scene, the people and the plan.
//!
//! A run's MCAP also holds a `run` metadata record: suite, episode, scene, robot, method, seed
//! and the run's metrics as text. Times are simulation time from 0 (nanoseconds).

mod schema;

use crate::bench::ResultRow;
use crate::episode::Episode;
use crate::error::SimError;
use crate::replay::{CrowdReplay, PedestrianSample};
use crate::runner::{EpisodeRun, Outcome, RobotSetup};
use human2nav_core::obstacle::Obstacle;
use human2nav_core::robot::footprint::FootprintShape;
use human2nav_core::{AgentState, Observation, Plan, Pose2};
use schema::schema_of;
use serde_json::{Map, Value, json};
use std::collections::BTreeMap;
use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};

/// The robot's frame, child of the world frame on `/tf`.
pub const ROBOT_FRAME: &str = "base_link";
/// Height of the cylinders drawn for people (m).
const PERSON_HEIGHT: f64 = 1.7;
/// Height of the robot's footprint prisms and of obstacle pillars (m).
const BODY_HEIGHT: f64 = 0.4;

/// The topics and their schema names (see the module docs), indexed by the constants below.
const TOPICS: [(&str, &str); 7] = [
    ("/tf", "foxglove.FrameTransform"),
    ("/robot/pose", "foxglove.PoseInFrame"),
    ("/plan", "foxglove.PosesInFrame"),
    ("/scene/static", "foxglove.SceneUpdate"),
    ("/scene/people", "foxglove.SceneUpdate"),
    ("/scene/plan", "foxglove.SceneUpdate"),
    ("/outcome", "foxglove.Log"),
];
const TF: usize = 0;
const ROBOT_POSE: usize = 1;
const PLAN: usize = 2;
const SCENE_STATIC: usize = 3;
const SCENE_PEOPLE: usize = 4;
const SCENE_PLAN: usize = 5;
const OUTCOME: usize = 6;

/// An MCAP file being written, one channel per topic of the module docs.
pub struct Recorder {
    writer: mcap::Writer<BufWriter<File>>,
    path: PathBuf,
    frame: String,
    channels: [u16; TOPICS.len()],
    sequence: u32,
}

impl std::fmt::Debug for Recorder {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Recorder")
            .field("path", &self.path)
            .field("frame", &self.frame)
            .finish_non_exhaustive()
    }
}

/// Seconds as a Foxglove `time`.
fn stamp(t: f64) -> Value {
    let ns = nanos(t);
    json!({"sec": ns / 1_000_000_000, "nsec": ns % 1_000_000_000})
}

/// Seconds as nanoseconds from 0 (negative and non-finite times at 0).
fn nanos(t: f64) -> u64 {
    if t.is_finite() && t > 0.0 {
        (t * 1e9).round() as u64
    } else {
        0
    }
}

fn vec3(x: f64, y: f64, z: f64) -> Value {
    json!({"x": x, "y": y, "z": z})
}

/// The quaternion of a rotation by `yaw` about z.
fn yaw_quat(yaw: f64) -> Value {
    let h = 0.5 * yaw;
    json!({"x": 0.0, "y": 0.0, "z": h.sin(), "w": h.cos()})
}

fn pose(x: f64, y: f64, z: f64, yaw: f64) -> Value {
    json!({"position": vec3(x, y, z), "orientation": yaw_quat(yaw)})
}

fn color(r: f64, g: f64, b: f64, a: f64) -> Value {
    json!({"r": r, "g": g, "b": b, "a": a})
}

/// A `foxglove.LinePrimitive` through `points` at height `z` (type 0: strip, 1: loop, 2: list).
fn line(
    kind: u8,
    points: impl IntoIterator<Item = [f64; 2]>,
    z: f64,
    width: f64,
    c: Value,
) -> Value {
    let points: Vec<Value> = points.into_iter().map(|p| vec3(p[0], p[1], z)).collect();
    json!({
        "type": kind, "pose": pose(0.0, 0.0, 0.0, 0.0), "thickness": width,
        "scale_invariant": false, "points": points, "color": c, "colors": [], "indices": []
    })
}

/// An upright `foxglove.CylinderPrimitive` standing on the ground.
fn cylinder(center: [f64; 2], radius: f64, height: f64, c: Value) -> Value {
    json!({
        "pose": pose(center[0], center[1], 0.5 * height, 0.0),
        "size": vec3(2.0 * radius, 2.0 * radius, height),
        "bottom_scale": 1.0, "top_scale": 1.0, "color": c
    })
}

/// A `foxglove.SceneEntity` with the primitives in `parts` (`cylinders`, `lines`, ...).
fn entity(t: f64, frame: &str, id: &str, parts: Map<String, Value>) -> Value {
    let mut e = json!({
        "timestamp": stamp(t), "frame_id": frame, "id": id,
        "lifetime": {"sec": 0, "nsec": 0}, "frame_locked": frame == ROBOT_FRAME,
        "metadata": [], "arrows": [], "cubes": [], "spheres": [], "cylinders": [],
        "lines": [], "triangles": [], "texts": [], "models": []
    });
    if let Value::Object(map) = &mut e {
        map.extend(parts);
    }
    e
}

fn parts(items: impl IntoIterator<Item = (&'static str, Vec<Value>)>) -> Map<String, Value> {
    items
        .into_iter()
        .map(|(k, v)| (k.to_string(), Value::Array(v)))
        .collect()
}

fn xy(p: &Pose2) -> [f64; 2] {
    [p.x, p.y]
}

impl Recorder {
    /// Creates (or replaces) the MCAP file at `path` (its folder created when missing), with
    /// `frame` as the world frame.
    pub fn create(path: &Path, frame: &str) -> Result<Self, SimError> {
        if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir).map_err(|e| SimError::io(dir, e))?;
        }
        let file = File::create(path).map_err(|e| SimError::io(path, e))?;
        let failed = |e: mcap::McapError| SimError::Record {
            path: path.to_path_buf(),
            message: e.to_string(),
        };
        let mut writer = mcap::WriteOptions::new()
            .profile("")
            .library(concat!("human2nav ", env!("CARGO_PKG_VERSION")))
            .create(BufWriter::new(file))
            .map_err(failed)?;
        let mut channels = [0u16; TOPICS.len()];
        for (slot, (topic, schema)) in channels.iter_mut().zip(TOPICS) {
            let text = schema_of(schema).to_string();
            let id = writer
                .add_schema(schema, "jsonschema", text.as_bytes())
                .map_err(failed)?;
            *slot = writer
                .add_channel(id, topic, "json", &BTreeMap::new())
                .map_err(failed)?;
        }
        Ok(Self {
            writer,
            path: path.to_path_buf(),
            frame: frame.to_string(),
            channels,
            sequence: 0,
        })
    }

    fn failed(&self, e: impl std::fmt::Display) -> SimError {
        SimError::Record {
            path: self.path.clone(),
            message: e.to_string(),
        }
    }

    /// Writes `message` on the channel of topic `k` (index into [`TOPICS`]) at `t`.
    fn write(&mut self, k: usize, t: f64, message: &Value) -> Result<(), SimError> {
        let data = message.to_string();
        self.sequence += 1;
        let header = mcap::records::MessageHeader {
            channel_id: self.channels[k],
            sequence: self.sequence,
            log_time: nanos(t),
            publish_time: nanos(t),
        };
        self.writer
            .write_to_known_channel(&header, data.as_bytes())
            .map_err(|e| self.failed(e))
    }

    /// The robot at `pose` at `t`: `/tf` and `/robot/pose`.
    pub fn robot(&mut self, t: f64, at: Pose2) -> Result<(), SimError> {
        let tf = json!({
            "timestamp": stamp(t), "parent_frame_id": self.frame, "child_frame_id": ROBOT_FRAME,
            "translation": vec3(at.x, at.y, 0.0), "rotation": yaw_quat(at.theta)
        });
        self.write(TF, t, &tf)?;
        let p = json!({
            "timestamp": stamp(t), "frame_id": self.frame, "pose": pose(at.x, at.y, 0.0, at.theta)
        });
        self.write(ROBOT_POSE, t, &p)
    }

    /// What does not move, at `t`: the robot's footprint (frame `base_link`), the goal and the
    /// obstacles, on `/scene/static`.
    pub fn static_scene(
        &mut self,
        t: f64,
        footprint: &[FootprintShape],
        goal: [f64; 2],
        obstacles: &[Obstacle],
    ) -> Result<(), SimError> {
        let red = || color(0.85, 0.15, 0.1, 0.8);
        let (mut cubes, mut cylinders) = (Vec::new(), Vec::new());
        for s in footprint {
            match *s {
                FootprintShape::Disc { center, radius } => {
                    cylinders.push(cylinder(center, radius, BODY_HEIGHT, red()))
                }
                FootprintShape::Rect { center, half, yaw } => cubes.push(json!({
                    "pose": pose(center[0], center[1], 0.5 * BODY_HEIGHT, yaw),
                    "size": vec3(2.0 * half[0], 2.0 * half[1], BODY_HEIGHT), "color": red()
                })),
            }
        }
        let robot = entity(
            t,
            ROBOT_FRAME,
            "footprint",
            parts([("cubes", cubes), ("cylinders", cylinders)]),
        );
        let goal = entity(
            t,
            &self.frame,
            "goal",
            parts([(
                "cylinders",
                vec![cylinder(goal, 0.25, 0.05, color(0.1, 0.3, 0.9, 0.9))],
            )]),
        );
        let (mut pillars, mut lines) = (Vec::new(), Vec::new());
        let grey = || color(0.25, 0.25, 0.25, 1.0);
        for o in obstacles {
            match o {
                Obstacle::Circle { center, radius } => {
                    pillars.push(cylinder(*center, *radius, 1.0, grey()))
                }
                Obstacle::Polygon { vertices } => {
                    lines.push(line(1, vertices.iter().copied(), 0.02, 0.08, grey()))
                }
                Obstacle::Segment { a, b } => lines.push(line(2, [*a, *b], 0.02, 0.08, grey())),
            }
        }
        let obstacles = entity(
            t,
            &self.frame,
            "obstacles",
            parts([("cylinders", pillars), ("lines", lines)]),
        );
        let update = json!({"deletions": [], "entities": [robot, goal, obstacles]});
        self.write(SCENE_STATIC, t, &update)
    }

    /// The people of an observation at `t` ([`Self::pedestrians`]), each with its recent
    /// positions up to where it is now.
    pub fn observed_people(&mut self, t: f64, agents: &[AgentState]) -> Result<(), SimError> {
        let people: Vec<PedestrianSample> = agents
            .iter()
            .map(|a| PedestrianSample {
                id: a.id,
                position: a.position,
                velocity: a.velocity,
                radius: a.radius,
            })
            .collect();
        let histories: Vec<Vec<[f64; 2]>> = agents
            .iter()
            .map(|a| a.history.iter().copied().chain([a.position]).collect())
            .collect();
        self.pedestrians(t, &people, &histories)
    }

    /// The people at `t` as cylinders, with their recent positions as faint lines when given
    /// (`histories[i]` for `people[i]`), on `/scene/people`.
    pub fn pedestrians(
        &mut self,
        t: f64,
        people: &[PedestrianSample],
        histories: &[Vec<[f64; 2]>],
    ) -> Result<(), SimError> {
        let cylinders = people
            .iter()
            .map(|p| {
                cylinder(
                    p.position,
                    p.radius,
                    PERSON_HEIGHT,
                    color(0.55, 0.55, 0.6, 0.85),
                )
            })
            .collect();
        let lines = histories
            .iter()
            .filter(|h| h.len() > 1)
            .map(|h| line(0, h.iter().copied(), 0.02, 0.03, color(0.5, 0.5, 0.55, 0.6)))
            .collect();
        let e = entity(
            t,
            &self.frame,
            "pedestrians",
            parts([("cylinders", cylinders), ("lines", lines)]),
        );
        self.write(SCENE_PEOPLE, t, &json!({"deletions": [], "entities": [e]}))
    }

    /// A plan made at `t`: `/plan` (its poses) and the `plan` and `candidates` line strips on
    /// `/scene/plan`.
    pub fn plan(
        &mut self,
        t: f64,
        poses: &[Pose2],
        candidates: &[Vec<Pose2>],
    ) -> Result<(), SimError> {
        let p = json!({
            "timestamp": stamp(t), "frame_id": self.frame,
            "poses": poses.iter().map(|q| pose(q.x, q.y, 0.0, q.theta)).collect::<Vec<_>>()
        });
        self.write(PLAN, t, &p)?;
        let chosen = entity(
            t,
            &self.frame,
            "plan",
            parts([(
                "lines",
                vec![line(
                    0,
                    poses.iter().map(xy),
                    0.05,
                    0.06,
                    color(1.0, 0.55, 0.0, 1.0),
                )],
            )]),
        );
        let others = candidates
            .iter()
            .map(|c| line(0, c.iter().map(xy), 0.04, 0.02, color(1.0, 0.75, 0.3, 0.45)))
            .collect();
        let candidates = entity(t, &self.frame, "candidates", parts([("lines", others)]));
        self.write(
            SCENE_PLAN,
            t,
            &json!({"deletions": [], "entities": [chosen, candidates]}),
        )
    }

    /// A line on `/outcome` at `t` (level 2: info, 3: warning, 4: error).
    pub fn log(&mut self, t: f64, level: u8, message: &str) -> Result<(), SimError> {
        let log = json!({
            "timestamp": stamp(t), "level": level, "message": message, "name": "human2nav",
            "file": "", "line": 0
        });
        self.write(OUTCOME, t, &log)
    }

    /// Writes `metadata` as a metadata record named `name`.
    pub fn metadata(
        &mut self,
        name: &str,
        metadata: BTreeMap<String, String>,
    ) -> Result<(), SimError> {
        let record = mcap::records::Metadata {
            name: name.to_string(),
            metadata,
        };
        self.writer
            .write_metadata(&record)
            .map_err(|e| self.failed(e))
    }

    /// Finishes the file (its summary and index).
    pub fn finish(mut self) -> Result<(), SimError> {
        self.writer.finish().map_err(|e| self.failed(e))?;
        Ok(())
    }
}

/// The file of a run's recording under the recording folder:
/// `<suite>/<robot>/<method>/<episode>.mcap`, each name with every character other than ASCII
/// letters, digits, `-`, `_` and `.` replaced by `_` (and a leading `.` too).
pub fn run_file(row: &ResultRow) -> PathBuf {
    let safe = |s: &str| {
        let mut out: String = s
            .chars()
            .map(|c| {
                if c.is_ascii_alphanumeric() || "-_.".contains(c) {
                    c
                } else {
                    '_'
                }
            })
            .collect();
        if out.is_empty() || out.starts_with('.') {
            out.insert(0, '_');
        }
        out
    };
    PathBuf::from(safe(&row.suite))
        .join(safe(&row.robot))
        .join(safe(&row.method))
        .join(format!("{}.mcap", safe(&row.episode)))
}

/// Writes the recording of one run (module docs) to `path`: the robot every step, the people
/// every step (replayed from the episode, or as the reactive crowd moved), each plan with its
/// candidates, the static scene at the start, the outcome at the end and the row as metadata.
pub fn record_run(
    path: &Path,
    episode: &Episode,
    run: &EpisodeRun,
    robot: &RobotSetup,
    row: &ResultRow,
) -> Result<(), SimError> {
    let mut rec = Recorder::create(path, human2nav_core::planner::DEFAULT_FRAME)?;
    rec.static_scene(0.0, &robot.footprint, episode.goal, &episode.obstacles)?;
    let replay = CrowdReplay::new(episode);
    let mut plans = run.plans.iter().peekable();
    for (n, state) in run.states.iter().enumerate() {
        let t = (n as f64 * run.dt).min(run.end_time);
        rec.robot(t, state.pose)?;
        let people = match &run.crowd {
            Some(steps) => steps.get(n).cloned().unwrap_or_default(),
            None => replay.at(t),
        };
        rec.pedestrians(t, &people, &[])?;
        while let Some(p) = plans.next_if(|p| p.t0 <= t + 0.5 * run.dt) {
            rec.plan(p.t0, &p.poses, &p.candidates)?;
        }
    }
    let m = &row.metrics;
    let (level, message) = match m.outcome {
        Outcome::Success => (2, format!("success: goal reached at {:.2} s", run.end_time)),
        Outcome::Timeout => (
            3,
            format!(
                "timeout: the budget of {:.1} s ran out {:.2} m from the goal",
                run.budget, run.end_goal_distance
            ),
        ),
        Outcome::Collision => (
            4,
            match (run.contact, run.obstacle_hit) {
                (Some(c), _) => format!(
                    "collision at {:.2} s with pedestrian {} (robot closing at {:.2} m/s, \
                     pedestrian at {:.2} m/s)",
                    run.end_time, c.pedestrian, c.robot_closing, c.pedestrian_closing
                ),
                (None, Some(k)) => format!("collision at {:.2} s with obstacle {k}", run.end_time),
                (None, None) => format!("collision at {:.2} s", run.end_time),
            },
        ),
    };
    rec.log(run.end_time, level, &message)?;
    for e in &run.planner_errors {
        rec.log(run.end_time, 3, &format!("planner call failed: {e}"))?;
    }
    rec.metadata("run", run_metadata(row))?;
    rec.finish()
}

/// A row's identity and metrics as text, for the `run` metadata record.
fn run_metadata(row: &ResultRow) -> BTreeMap<String, String> {
    let text = crate::report::results_csv_exact(std::slice::from_ref(row));
    let mut lines = text.lines();
    let (Some(header), Some(values)) = (lines.next(), lines.next()) else {
        return BTreeMap::new();
    };
    // A value with a comma (a quoted name) would split wrongly: read it with the CSV reader.
    let mut reader = csv::ReaderBuilder::new()
        .has_headers(false)
        .from_reader(values.as_bytes());
    let values: Vec<String> = reader
        .records()
        .next()
        .and_then(Result::ok)
        .map(|r| r.iter().map(str::to_string).collect())
        .unwrap_or_default();
    header.split(',').map(str::to_string).zip(values).collect()
}

/// Writes one planning call to `path`: the robot at the observation's time, the people with
/// their recent positions, the obstacles, the goal, the plan and the candidates, and a line on
/// `/outcome` saying what the plan is (frame: the observation's).
pub fn record_plan(
    path: &Path,
    obs: &Observation,
    plan: &Plan,
    footprint: &[FootprintShape],
    robot: &str,
) -> Result<(), SimError> {
    let mut rec = Recorder::create(path, &obs.frame_id)?;
    let t = obs.time;
    rec.static_scene(t, footprint, obs.goal, &obs.obstacles)?;
    rec.robot(t, obs.ego)?;
    rec.observed_people(t, &obs.agents)?;
    let candidates = if plan.info.guided.is_empty() {
        &plan.info.candidates
    } else {
        &plan.info.guided
    };
    rec.plan(t, &plan.poses, candidates)?;
    let what = if plan.info.fallback {
        "a fallback (stop in place)"
    } else {
        "a plan"
    };
    rec.log(
        t,
        2,
        &format!(
            "{robot}: {what} of {} poses at {} s steps, from {} candidates",
            plan.poses.len(),
            plan.dt,
            candidates.len()
        ),
    )?;
    let mut meta = BTreeMap::new();
    meta.insert("robot".to_string(), robot.to_string());
    meta.insert("time".to_string(), format!("{t}"));
    meta.insert("candidates".to_string(), candidates.len().to_string());
    rec.metadata("plan", meta)?;
    rec.finish()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn times_and_orientations_are_foxglove_s() {
        assert_eq!(stamp(1.25), json!({"sec": 1, "nsec": 250_000_000}));
        assert_eq!(stamp(-1.0), json!({"sec": 0, "nsec": 0}));
        let q = yaw_quat(std::f64::consts::PI);
        assert!((q["z"].as_f64().unwrap_or(0.0) - 1.0).abs() < 1e-12);
        assert!(q["w"].as_f64().unwrap_or(1.0).abs() < 1e-12);
    }

    #[test]
    fn a_recording_reads_back_with_its_schemas_topics_and_json_messages() {
        let path = std::env::temp_dir().join(format!("h2n-record-{}.mcap", std::process::id()));
        let mut rec = Recorder::create(&path, "map").expect("created");
        let shapes = [FootprintShape::Disc {
            center: [0.0, 0.0],
            radius: 0.3,
        }];
        let wall = Obstacle::Segment {
            a: [0.0, 2.0],
            b: [4.0, 2.0],
        };
        rec.static_scene(0.0, &shapes, [5.0, 0.0], &[wall])
            .expect("scene");
        rec.robot(0.0, Pose2::new(0.0, 0.0, 0.0)).expect("robot");
        let ped = PedestrianSample {
            id: 4,
            position: [2.0, 1.0],
            velocity: [0.0, -1.0],
            radius: 0.3,
        };
        rec.pedestrians(0.0, &[ped], &[]).expect("people");
        let poses: Vec<Pose2> = (0..4)
            .map(|k| Pose2::new(0.1 * k as f64, 0.0, 0.0))
            .collect();
        rec.plan(0.0, &poses, std::slice::from_ref(&poses))
            .expect("plan");
        rec.robot(0.05, Pose2::new(0.05, 0.0, 0.0)).expect("robot");
        rec.log(0.05, 2, "success").expect("log");
        rec.metadata("run", BTreeMap::from([("suite".into(), "s".into())]))
            .expect("metadata");
        rec.finish().expect("finished");

        let bytes = std::fs::read(&path).expect("read");
        let mut topics: BTreeMap<String, (String, usize)> = BTreeMap::new();
        for m in mcap::MessageStream::new(&bytes).expect("an MCAP file") {
            let m = m.expect("a message");
            let schema = m.channel.schema.as_ref().expect("a schema");
            assert_eq!(schema.encoding, "jsonschema");
            assert_eq!(m.channel.message_encoding, "json");
            let _: Value = serde_json::from_slice(&schema.data).expect("schema JSON");
            let v: Value = serde_json::from_slice(&m.data).expect("message JSON");
            if m.channel.topic == "/tf" {
                assert_eq!(v["parent_frame_id"], "map");
                assert_eq!(v["child_frame_id"], ROBOT_FRAME);
            }
            let e = topics
                .entry(m.channel.topic.clone())
                .or_insert((schema.name.clone(), 0));
            e.1 += 1;
        }
        let expect = |topic: &str, schema: &str, n: usize| {
            assert_eq!(topics.get(topic), Some(&(schema.to_string(), n)), "{topic}")
        };
        expect("/tf", "foxglove.FrameTransform", 2);
        expect("/robot/pose", "foxglove.PoseInFrame", 2);
        expect("/plan", "foxglove.PosesInFrame", 1);
        expect("/scene/static", "foxglove.SceneUpdate", 1);
        expect("/scene/people", "foxglove.SceneUpdate", 1);
        expect("/scene/plan", "foxglove.SceneUpdate", 1);
        expect("/outcome", "foxglove.Log", 1);
        let _ = std::fs::remove_file(&path);
    }
}
