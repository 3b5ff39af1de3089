//! What `human2nav replay` gives the planner from a bag, streamed: the odometry, the goal, the
//! people a tracker saw and the occupancy grid at each planning time, in the odometry's frame.
//!
//! The bag is read message by message ([`BagReader`]). Planning times are header stamps: from
//! the first time both an odometry message and a goal are known, every `1 / rate` s, to the last
//! odometry message. A call at time `t` takes the latest odometry, goal, people message (if at
//! most 1 s old) and map stamped at or before `t`. It is made once the odometry read has passed
//! `t + max_delay`, so a message may be logged up to `max_delay` after the odometry of its stamp
//! and still count; what is held is about that many seconds of messages, however long the bag.
//! A message logged later than that is *late*: it counts from the next call on.
//!
//! Frames: the goal, the people and the map are brought into the odometry's frame
//! (`header.frame_id` of `nav_msgs/msg/Odometry`) through the transforms of `/tf` and
//! `/tf_static` ([`super::tf`]), each at its own stamp: positions moved, velocities rotated, the
//! grid's origin moved (the grid turns with it). A message in the odometry's frame, or with an
//! empty `frame_id`, is taken as it is. A frame with no chain of transforms to the odometry's
//! is an error naming the frame, the topic and the message; a message stamped before the first
//! transform of a link of its chain is left out and counted.
//!
//! People come from `people_msgs/msg/People` (id: the order in which each `name` first
//! appears; position and velocity as given) or from SPENCER's
//! `spencer_tracking_msgs/msg/TrackedPersons` (id: `track_id`; position `pose.pose.position`,
//! velocity `twist.twist.linear`); each person's recent positions are those of their earlier
//! messages at 0.1 s steps (those of the last 2 s), and every person gets one disc radius.

use super::cdr::Value;
use super::tf::{self, TfBuffer, TfError};
use super::{BagError, BagMessage, BagReader, TopicSpec, err};
use human2nav_core::obstacle::OccupancyGrid;
use human2nav_core::{AgentState, Pose2, Twist2};
use std::collections::{BTreeMap, VecDeque};
use std::path::{Path, PathBuf};

/// The topics read.
#[derive(Clone, Debug)]
pub struct InputTopics {
    /// `nav_msgs/msg/Odometry` (required).
    pub odom: String,
    /// `geometry_msgs/msg/PoseStamped` (required).
    pub goal: String,
    /// `people_msgs/msg/People` or `spencer_tracking_msgs/msg/TrackedPersons` (optional).
    pub people: String,
    /// `nav_msgs/msg/OccupancyGrid` (optional).
    pub map: String,
    /// `tf2_msgs/msg/TFMessage`, moving transforms (optional).
    pub tf: String,
    /// `tf2_msgs/msg/TFMessage`, static transforms (optional).
    pub tf_static: String,
}

impl Default for InputTopics {
    fn default() -> Self {
        Self {
            odom: "/odom".into(),
            goal: "/goal_pose".into(),
            people: "/people".into(),
            map: "/map".into(),
            tf: "/tf".into(),
            tf_static: "/tf_static".into(),
        }
    }
}

/// How the inputs are sampled.
#[derive(Clone, Copy, Debug)]
pub struct InputSettings {
    /// Planning calls per second of recorded time.
    pub rate: f64,
    /// Disc radius given to every person (m).
    pub person_radius: f64,
    /// How long after the odometry of its stamp a message may be logged and still count for
    /// the calls at or after its stamp (s).
    pub max_delay: f64,
}

impl Default for InputSettings {
    fn default() -> Self {
        Self {
            rate: 10.0,
            person_radius: 0.3,
            max_delay: 1.0,
        }
    }
}

/// A person's positions older than this before a call are not used as their history (ns).
const HISTORY_KEEP: i128 = 2_000_000_000;
/// The people message of a call is at most this old (ns).
const PEOPLE_FRESH: i128 = 1_000_000_000;
/// Moving transforms are kept this much longer than `max_delay` behind the latest message
/// applied (ns).
const TF_KEEP: i128 = 1_000_000_000;

const STAMP: [(&str, &str); 3] = [
    ("header.stamp.sec", "int32"),
    ("header.stamp.nanosec", "uint32"),
    ("header.frame_id", "string"),
];

fn with_stamp(fields: &[(&'static str, &'static str)]) -> Vec<(&'static str, &'static str)> {
    STAMP.iter().chain(fields).copied().collect()
}

/// What is read from each topic: the accepted types with the fields used.
pub fn specs(topics: &InputTopics) -> Vec<TopicSpec> {
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
        "info.origin.orientation.x",
        "info.origin.orientation.y",
        "info.origin.orientation.z",
        "info.origin.orientation.w",
    ]));
    let tf_message = || vec![("tf2_msgs/msg/TFMessage", tf::TF_FIELDS.to_vec())];
    vec![
        TopicSpec {
            topic: topics.odom.clone(),
            types: vec![("nav_msgs/msg/Odometry", with_stamp(&odom))],
        },
        TopicSpec {
            topic: topics.goal.clone(),
            types: vec![(
                "geometry_msgs/msg/PoseStamped",
                with_stamp(&f64s(&["pose.position.x", "pose.position.y"])),
            )],
        },
        TopicSpec {
            topic: topics.people.clone(),
            types: vec![
                ("people_msgs/msg/People", with_stamp(&people)),
                (
                    "spencer_tracking_msgs/msg/TrackedPersons",
                    with_stamp(&tracks),
                ),
            ],
        },
        TopicSpec {
            topic: topics.map.clone(),
            types: vec![("nav_msgs/msg/OccupancyGrid", with_stamp(&map))],
        },
        TopicSpec {
            topic: topics.tf.clone(),
            types: tf_message(),
        },
        TopicSpec {
            topic: topics.tf_static.clone(),
            types: tf_message(),
        },
    ]
}

/// A number the spec guarantees (checked against the definition; 0 if it is somehow absent).
fn num(v: &Value, path: &str) -> f64 {
    v.number(path).unwrap_or(0.0)
}

fn yaw(v: &Value, prefix: &str) -> f64 {
    let q = |c: &str| num(v, &format!("{prefix}.{c}"));
    tf::yaw_of(q("x"), q("y"), q("z"), q("w"))
}

/// One person seen in a tracker message.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Seen {
    /// The person's id.
    pub id: u64,
    /// Position (m).
    pub position: [f64; 2],
    /// Velocity (m/s).
    pub velocity: [f64; 2],
}

/// The people of a tracker message (`names` numbers people_msgs' names).
fn people_of(v: &Value, msgtype: &str, names: &mut BTreeMap<String, u64>) -> Vec<Seen> {
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

/// A `nav_msgs/OccupancyGrid` message as the planner's grid, in the message's frame.
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

/// The topics the planner's state comes from, in the order of [`ReplayInputs::pending`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Kind {
    Odom = 0,
    Goal = 1,
    People = 2,
    Map = 3,
}

/// What a message says, in its own frame.
#[derive(Clone, Debug)]
enum Payload {
    Odom { pose: Pose2, velocity: Twist2 },
    Goal([f64; 2]),
    People(Vec<Seen>),
    Map(OccupancyGrid),
}

/// A message read and not applied yet.
#[derive(Clone, Debug)]
struct Pending {
    stamp: i128,
    index: usize,
    frame: String,
    payload: Payload,
}

/// One planning call's inputs, in the odometry's frame.
#[derive(Clone, Debug)]
pub struct Call {
    /// The planning time: a header stamp (ns).
    pub stamp: i128,
    /// The odometry's frame (`odom` when its `frame_id` is empty).
    pub frame: String,
    /// The robot's pose.
    pub ego: Pose2,
    /// The robot's velocity in its own frame (the odometry's twist).
    pub ego_velocity: Twist2,
    /// The goal's position.
    pub goal: [f64; 2],
    /// The goal message's index on its topic.
    pub goal_index: usize,
    /// The people, with their recent positions.
    pub agents: Vec<AgentState>,
    /// The latest occupancy grid.
    pub occupancy: Option<OccupancyGrid>,
}

/// What a replay read, held and set aside.
#[derive(Clone, Debug, Default)]
pub struct InputStats {
    /// Messages waiting to be applied plus transforms held, now.
    pub held: usize,
    /// The most held at once.
    pub peak_held: usize,
    /// Messages logged after a call at or after their stamp was made: counted from the next.
    pub late: usize,
    /// Messages left out: stamped before the first transform of their frame's chain.
    pub untransformed: usize,
    /// The first of those, as `topic `T`, message I: why`.
    pub first_untransformed: Option<String>,
}

/// The planner's inputs from a bag, streamed (module docs): [`ReplayInputs::next_call`] until
/// `None`.
#[derive(Debug)]
pub struct ReplayInputs {
    file: PathBuf,
    reader: BagReader,
    topics: InputTopics,
    step: i128,
    max_delay: i128,
    person_radius: f64,
    /// The odometry's frame, from its first message.
    frame: Option<String>,
    pending: [VecDeque<Pending>; 4],
    tf: TfBuffer,
    odom: Option<(i128, Pose2, Twist2)>,
    goal: Option<(usize, [f64; 2])>,
    people: Option<(i128, Vec<Seen>)>,
    map: Option<OccupancyGrid>,
    tracks: BTreeMap<u64, VecDeque<(i128, [f64; 2])>>,
    names: BTreeMap<String, u64>,
    /// The latest odometry stamp read.
    watermark: Option<i128>,
    /// The latest stamp applied.
    applied: Option<i128>,
    first_odom: Option<i128>,
    first_goal: Option<i128>,
    start: Option<i128>,
    next_call: Option<i128>,
    last_call: Option<i128>,
    calls: usize,
    ended: bool,
    stats: InputStats,
}

impl ReplayInputs {
    /// Opens the bag `file` (an `.mcap` file) to read `topics`; its definitions are checked
    /// as [`BagReader::open`] does.
    pub fn open(
        file: &Path,
        topics: &InputTopics,
        settings: InputSettings,
    ) -> Result<Self, BagError> {
        Ok(Self {
            file: file.to_path_buf(),
            reader: BagReader::open(file, &specs(topics))?,
            topics: topics.clone(),
            step: ((1e9 / settings.rate).round() as i128).max(1),
            max_delay: ((settings.max_delay * 1e9).round() as i128).max(0),
            person_radius: settings.person_radius,
            frame: None,
            pending: Default::default(),
            tf: TfBuffer::new(),
            odom: None,
            goal: None,
            people: None,
            map: None,
            tracks: BTreeMap::new(),
            names: BTreeMap::new(),
            watermark: None,
            applied: None,
            first_odom: None,
            first_goal: None,
            start: None,
            next_call: None,
            last_call: None,
            calls: 0,
            ended: false,
            stats: InputStats::default(),
        })
    }

    /// The reader (what it has read, per topic; whether the file is indexed).
    pub fn reader(&self) -> &BagReader {
        &self.reader
    }

    /// What was held and set aside so far.
    pub fn stats(&self) -> &InputStats {
        &self.stats
    }

    /// The first planning time: the later of the first odometry's and the first goal's stamps.
    pub fn start(&self) -> Option<i128> {
        self.start
    }

    /// The stamp of the first and the last odometry message read.
    pub fn odometry_span(&self) -> Option<(i128, i128)> {
        Some((self.first_odom?, self.watermark?))
    }

    /// The stamp of the first goal applied.
    pub fn first_goal(&self) -> Option<i128> {
        self.first_goal
    }

    /// Calls made so far.
    pub fn calls(&self) -> usize {
        self.calls
    }

    fn fail(&self, topic: &str, index: usize, what: impl std::fmt::Display) -> BagError {
        err(format!(
            "`{}`: topic `{topic}`, message {index}: {what}",
            self.file.display()
        ))
    }

    fn topic(&self, kind: Kind) -> &str {
        match kind {
            Kind::Odom => &self.topics.odom,
            Kind::Goal => &self.topics.goal,
            Kind::People => &self.topics.people,
            Kind::Map => &self.topics.map,
        }
    }

    fn count_held(&mut self) {
        let held = self.pending.iter().map(VecDeque::len).sum::<usize>() + self.tf.len();
        self.stats.held = held;
        self.stats.peak_held = self.stats.peak_held.max(held);
    }

    /// The next planning call's inputs; `None` after the last. An error names the file, the
    /// topic and the message (and the frame, for one that cannot be brought in).
    pub fn next_call(&mut self) -> Result<Option<Call>, BagError> {
        loop {
            let (apply_to, call_to) = if self.ended {
                (Some(i128::MAX), self.watermark)
            } else {
                // Strictly before: a message logged just after the odometry of its stamp
                // counts even with no delay allowed.
                let bound = self.watermark.map(|w| w - self.max_delay - 1);
                (bound, bound)
            };
            if let Some(call) = self.advance(apply_to, call_to)? {
                return Ok(Some(call));
            }
            if self.ended {
                return Ok(None);
            }
            match self.reader.next_message() {
                None => self.ended = true,
                Some(m) => self.take(m?)?,
            }
            self.count_held();
        }
    }

    /// A message read: transforms go into the buffer, the rest waits to be applied.
    fn take(&mut self, m: BagMessage) -> Result<(), BagError> {
        let topic = &*m.topic;
        let v = &m.message.value;
        let index = m.message.index;
        let fixed = topic == self.topics.tf_static;
        if fixed || topic == self.topics.tf {
            for t in tf::transforms_of(v) {
                self.tf.insert(t, fixed);
            }
            return Ok(());
        }
        let kind = if topic == self.topics.odom {
            Kind::Odom
        } else if topic == self.topics.goal {
            Kind::Goal
        } else if topic == self.topics.people {
            Kind::People
        } else if topic == self.topics.map {
            Kind::Map
        } else {
            return Ok(());
        };
        let stamp = m.message.stamp.unwrap_or(0);
        let frame = tf::frame_name(v.text("header.frame_id").unwrap_or("")).to_string();
        let payload = match kind {
            Kind::Odom => {
                if let Some(f) = &self.frame {
                    if *f != frame {
                        return Err(self.fail(
                            topic,
                            index,
                            format!(
                                "frame `{frame}`, but the odometry's first message was in \
                                 `{f}` (its frame must not change)"
                            ),
                        ));
                    }
                } else {
                    self.frame = Some(frame.clone());
                }
                self.watermark = Some(self.watermark.map_or(stamp, |w| w.max(stamp)));
                self.first_odom.get_or_insert(stamp);
                Payload::Odom {
                    pose: Pose2::new(
                        num(v, "pose.pose.position.x"),
                        num(v, "pose.pose.position.y"),
                        yaw(v, "pose.pose.orientation"),
                    ),
                    velocity: Twist2::new(
                        num(v, "twist.twist.linear.x"),
                        num(v, "twist.twist.linear.y"),
                        num(v, "twist.twist.angular.z"),
                    ),
                }
            }
            Kind::Goal => Payload::Goal([num(v, "pose.position.x"), num(v, "pose.position.y")]),
            Kind::People => Payload::People(people_of(v, &m.msgtype, &mut self.names)),
            Kind::Map => Payload::Map(grid_of(v)),
        };
        if self.last_call.is_some_and(|c| stamp <= c) {
            self.stats.late += 1;
        }
        self.pending[kind as usize].push_back(Pending {
            stamp,
            index,
            frame,
            payload,
        });
        Ok(())
    }

    /// Applies the waiting messages stamped up to `apply_to` in stamp order, and returns the
    /// first call due up to `call_to` once every message stamped at or before it is applied.
    fn advance(
        &mut self,
        apply_to: Option<i128>,
        call_to: Option<i128>,
    ) -> Result<Option<Call>, BagError> {
        // Nothing is applied before the odometry gives the frame (a bag without it is
        // refused once read).
        let (Some(apply_to), Some(_)) = (apply_to, &self.frame) else {
            return Ok(None);
        };
        loop {
            let next = (0..4)
                .filter_map(|k| self.pending[k].front().map(|p| (p.stamp, k)))
                .filter(|(s, _)| *s <= apply_to)
                .min();
            if let (Some(t), Some(to)) = (self.next_call, call_to)
                && t <= to
                && next.is_none_or(|(s, _)| t < s)
            {
                self.next_call = Some(t + self.step);
                self.last_call = Some(t);
                self.calls += 1;
                return Ok(Some(self.call(t)));
            }
            let Some((_, k)) = next else {
                return Ok(None);
            };
            let Some(p) = self.pending[k].pop_front() else {
                return Ok(None);
            };
            self.apply(k, p)?;
        }
    }

    /// Brings a message into the odometry's frame and makes it the latest of its topic.
    fn apply(&mut self, k: usize, p: Pending) -> Result<(), BagError> {
        let kind = [Kind::Odom, Kind::Goal, Kind::People, Kind::Map][k];
        let topic = self.topic(kind).to_string();
        let frame = self.frame.clone().unwrap_or_default();
        let applied = self.applied.map_or(p.stamp, |a| a.max(p.stamp));
        self.applied = Some(applied);
        let to_odom = if kind == Kind::Odom || p.frame.is_empty() || p.frame == frame {
            Pose2::IDENTITY
        } else {
            match self.tf.lookup(&p.frame, &frame, p.stamp) {
                Ok(t) => t,
                Err(e @ TfError::NotYet { .. }) => {
                    self.stats.untransformed += 1;
                    if self.stats.first_untransformed.is_none() {
                        self.stats.first_untransformed =
                            Some(format!("topic `{topic}`, message {}: {e}", p.index));
                    }
                    return Ok(());
                }
                Err(e) => {
                    return Err(self.fail(
                        &topic,
                        p.index,
                        format!(
                            "{e}; give them on `{}` or `{}` (--tf, --tf-static)",
                            self.topics.tf, self.topics.tf_static
                        ),
                    ));
                }
            }
        };
        match p.payload {
            Payload::Odom { pose, velocity } => {
                self.odom = Some((p.stamp, pose, velocity));
            }
            Payload::Goal(xy) => {
                self.goal = Some((p.index, to_odom.act(xy)));
                self.first_goal.get_or_insert(p.stamp);
            }
            Payload::People(seen) => {
                let seen: Vec<Seen> = seen
                    .into_iter()
                    .map(|s| Seen {
                        id: s.id,
                        position: to_odom.act(s.position),
                        velocity: to_odom.rotate(s.velocity),
                    })
                    .collect();
                for s in &seen {
                    self.tracks
                        .entry(s.id)
                        .or_default()
                        .push_back((p.stamp, s.position));
                }
                self.people = Some((p.stamp, seen));
            }
            Payload::Map(mut grid) => {
                grid.origin = to_odom.compose(grid.origin);
                if let Err(e) = grid.validate() {
                    return Err(self.fail(&topic, p.index, format!("the occupancy grid's {e}")));
                }
                self.map = Some(grid);
            }
        }
        if self.start.is_none()
            && let (Some(o), Some(g)) = (self.first_odom_applied(), self.first_goal)
        {
            let start = o.max(g);
            let mut next = start;
            // A late goal: the calls before what is applied already are past.
            while next < applied {
                next += self.step;
            }
            self.start = Some(start);
            self.next_call = Some(next);
        }
        // Let go of what no later call needs.
        for track in self.tracks.values_mut() {
            while track
                .front()
                .is_some_and(|(s, _)| *s < applied - HISTORY_KEEP)
            {
                track.pop_front();
            }
        }
        self.tracks.retain(|_, t| !t.is_empty());
        self.tf.prune(applied - self.max_delay - TF_KEEP);
        Ok(())
    }

    /// The stamp of the first odometry applied.
    fn first_odom_applied(&self) -> Option<i128> {
        self.odom.as_ref().and(self.first_odom)
    }

    /// The inputs of the call at `t`: the latest of each topic.
    fn call(&self, t: i128) -> Call {
        let (ego, ego_velocity) = self.odom.map_or(
            (Pose2::IDENTITY, Twist2::new(0.0, 0.0, 0.0)),
            |(_, p, v)| (p, v),
        );
        let (goal_index, goal) = self.goal.unwrap_or((0, [ego.x, ego.y]));
        let seen: &[Seen] = match &self.people {
            Some((s, seen)) if t - s <= PEOPLE_FRESH => seen,
            _ => &[],
        };
        let agents = seen
            .iter()
            .map(|s| AgentState {
                id: s.id,
                position: s.position,
                velocity: s.velocity,
                radius: self.person_radius,
                history: self.history_at(s.id, t),
            })
            .collect();
        let frame = self.frame.clone().unwrap_or_default();
        Call {
            stamp: t,
            frame: if frame.is_empty() {
                "odom".into()
            } else {
                frame
            },
            ego,
            ego_velocity,
            goal,
            goal_index,
            agents,
            occupancy: self.map.clone(),
        }
    }

    /// A person's positions 0.8 to 0.1 s before `t`, oldest first: at each, their latest
    /// position at or before it, if from the last [`HISTORY_KEEP`].
    fn history_at(&self, id: u64, t: i128) -> Vec<[f64; 2]> {
        let Some(track) = self.tracks.get(&id) else {
            return Vec::new();
        };
        (1..=8)
            .rev()
            .filter_map(|k| {
                let at = t - k * 100_000_000;
                let n = track.partition_point(|(s, _)| *s <= at);
                n.checked_sub(1)
                    .and_then(|i| track.get(i))
                    .filter(|(s, _)| *s >= t - HISTORY_KEEP)
                    .map(|(_, p)| *p)
            })
            .collect()
    }
}

#[cfg(test)]
mod tests;
