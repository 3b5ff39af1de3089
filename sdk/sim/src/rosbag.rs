//! ROS 2 bags in MCAP storage (rosbag2's default since Iron): the messages of chosen topics
//! read as a stream, in log-time order, and decoded from CDR with the definitions the bag
//! carries ([`BagReader`], [`msgdef`], [`cdr`]), each checked against the fields the reader
//! needs; transforms between frames ([`tf`]); what `human2nav replay` gives the planner
//! ([`inputs`]); and a writer of CDR messages with their definitions, as rosbag2 writes them
//! (schema encoding `ros2msg`, message encoding `cdr`).
//!
//! A bag is an `.mcap` file or a rosbag2 folder holding one (its `metadata.yaml` is not
//! needed). Errors name the file, the topic and the message's index on its topic (from 0, in the
//! order read): a message that does not decode (truncated, malformed), a definition without a
//! needed field or with another type for it, a topic of another message type, header stamps
//! going backwards, a file cut short.

pub mod cdr;
pub mod inputs;
pub mod msgdef;
mod reader;
pub mod tf;

pub use reader::{BagMessage, BagReader};

use cdr::Value;
use msgdef::Definitions;
use std::collections::BTreeMap;
use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};

/// What went wrong with a bag; the message names the file, and the topic and message where
/// there is one.
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct BagError(pub String);

pub(crate) fn err(s: impl Into<String>) -> BagError {
    BagError(s.into())
}

/// The `.mcap` file of a bag: `path` itself, or the one `.mcap` file in the folder `path`.
pub fn mcap_file(path: &Path) -> Result<PathBuf, BagError> {
    if !path.is_dir() {
        return if path.is_file() {
            Ok(path.to_path_buf())
        } else {
            Err(err(format!("`{}`: no such bag", path.display())))
        };
    }
    let read = std::fs::read_dir(path).map_err(|e| err(format!("`{}`: {e}", path.display())))?;
    let mut files: Vec<PathBuf> = read
        .filter_map(Result::ok)
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|x| x == "mcap"))
        .collect();
    files.sort();
    match files.len() {
        1 => Ok(files.remove(0)),
        0 => Err(err(format!(
            "`{}` holds no .mcap file (only MCAP storage is read; convert an sqlite3 bag with \
             `ros2 bag convert`)",
            path.display()
        ))),
        n => Err(err(format!(
            "`{}` holds {n} .mcap files: give the one to replay",
            path.display()
        ))),
    }
}

/// A topic to read: its name, the message types it may carry (`pkg/msg/Type`) and for each the
/// fields needed (`(path, type)` as [`Definitions::require`] takes them).
#[derive(Clone, Debug)]
pub struct TopicSpec {
    /// The topic's name.
    pub topic: String,
    /// Accepted types with the fields the reader uses.
    pub types: Vec<(&'static str, Vec<(&'static str, &'static str)>)>,
}

/// A decoded message.
#[derive(Clone, Debug)]
pub struct Message {
    /// Its index on its topic, from 0.
    pub index: usize,
    /// When it was logged (ns).
    pub log_time: u64,
    /// Its header stamp (ns), when it has a header.
    pub stamp: Option<i128>,
    /// Its fields.
    pub value: Value,
}

/// A topic read: its message type (`pkg/msg/Type`) and messages in the file's order.
#[derive(Clone, Debug)]
pub struct Topic {
    /// The message type.
    pub msgtype: String,
    /// The messages.
    pub messages: Vec<Message>,
}

/// A header stamp in nanoseconds.
pub(crate) fn stamp_of(v: &Value) -> Option<i128> {
    let sec = v.number("header.stamp.sec")?;
    let nsec = v.number("header.stamp.nanosec")?;
    Some(sec as i128 * 1_000_000_000 + nsec as i128)
}

/// Reads the topics of `specs` from the MCAP file `path` whole (other topics are skipped):
/// every message decoded, checked as the module docs say, held in memory. A topic of `specs`
/// the bag lacks is simply absent from the result. For a bag of any size, read it message by
/// message with [`BagReader`] instead.
pub fn read_topics(path: &Path, specs: &[TopicSpec]) -> Result<BTreeMap<String, Topic>, BagError> {
    let mut out: BTreeMap<String, Topic> = BTreeMap::new();
    for m in BagReader::open(path, specs)? {
        let m = m?;
        out.entry(m.topic.to_string())
            .or_insert_with(|| Topic {
                msgtype: m.msgtype.to_string(),
                messages: Vec::new(),
            })
            .messages
            .push(m.message);
    }
    Ok(out)
}

/// The definitions of a channel of `spec`'s topic, checked: ROS 2 message definitions, CDR, one
/// of the accepted types, with the needed fields.
pub(crate) fn definitions_of(
    channel: &mcap::Channel<'_>,
    spec: &TopicSpec,
) -> Result<(String, Definitions), BagError> {
    let topic = &channel.topic;
    let Some(schema) = &channel.schema else {
        return Err(err(format!("topic `{topic}` has no message definition")));
    };
    if channel.message_encoding != "cdr" || schema.encoding != "ros2msg" {
        return Err(err(format!(
            "topic `{topic}`: messages in `{}` with `{}` definitions; a ROS 2 bag has `cdr` \
             messages and `ros2msg` definitions",
            channel.message_encoding, schema.encoding
        )));
    }
    let name = msgdef::normalize(&schema.name);
    let Some((msgtype, fields)) = spec
        .types
        .iter()
        .find(|(t, _)| msgdef::normalize(t) == name)
    else {
        let accepted: Vec<&str> = spec.types.iter().map(|(t, _)| *t).collect();
        return Err(err(format!(
            "topic `{topic}` carries `{}`, expected {}",
            schema.name,
            accepted.join(" or ")
        )));
    };
    let text = String::from_utf8_lossy(&schema.data);
    let defs = msgdef::parse(&schema.name, &text).map_err(|e| {
        err(format!(
            "topic `{topic}`: its definition of `{}`: {e}",
            schema.name
        ))
    })?;
    defs.require(fields)
        .map_err(|e| err(format!("topic `{topic}`: {e} (definition mismatch)")))?;
    Ok((msgtype.to_string(), defs))
}

/// A ROS 2 bag being written as one MCAP file (`ros2` profile, `ros2msg` definitions, CDR
/// messages), readable by rosbag2 and rosbags.
pub struct BagWriter {
    writer: mcap::Writer<BufWriter<File>>,
    path: PathBuf,
    channels: BTreeMap<String, u16>,
    sequence: u32,
}

impl std::fmt::Debug for BagWriter {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("BagWriter")
            .field("path", &self.path)
            .field("topics", &self.channels.keys().collect::<Vec<_>>())
            .finish_non_exhaustive()
    }
}

impl BagWriter {
    /// Creates (or replaces) the bag at `path` (its folder created when missing).
    pub fn create(path: &Path) -> Result<Self, BagError> {
        let file = path.display();
        if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir).map_err(|e| err(format!("`{}`: {e}", dir.display())))?;
        }
        let f = File::create(path).map_err(|e| err(format!("`{file}`: {e}")))?;
        let writer = mcap::WriteOptions::new()
            .profile("ros2")
            .library(concat!("human2nav ", env!("CARGO_PKG_VERSION")))
            .create(BufWriter::new(f))
            .map_err(|e| err(format!("`{file}`: {e}")))?;
        Ok(Self {
            writer,
            path: path.to_path_buf(),
            channels: BTreeMap::new(),
            sequence: 0,
        })
    }

    fn failed(&self, e: impl std::fmt::Display) -> BagError {
        err(format!("writing `{}`: {e}", self.path.display()))
    }

    /// Adds `topic` carrying `msgtype` (`pkg/msg/Type`) defined by `definition` (`ros2msg`).
    pub fn add_topic(
        &mut self,
        topic: &str,
        msgtype: &str,
        definition: &str,
    ) -> Result<(), BagError> {
        let schema = self
            .writer
            .add_schema(msgtype, "ros2msg", definition.as_bytes())
            .map_err(|e| self.failed(e))?;
        let metadata = BTreeMap::from([("offered_qos_profiles".to_string(), String::new())]);
        let id = self
            .writer
            .add_channel(schema, topic, "cdr", &metadata)
            .map_err(|e| self.failed(e))?;
        self.channels.insert(topic.to_string(), id);
        Ok(())
    }

    /// Writes one CDR message on `topic` (added before) at `time` (ns).
    pub fn write(&mut self, topic: &str, time: u64, data: &[u8]) -> Result<(), BagError> {
        let Some(&channel_id) = self.channels.get(topic) else {
            return Err(self.failed(format!("topic `{topic}` was not added")));
        };
        self.sequence += 1;
        let header = mcap::records::MessageHeader {
            channel_id,
            sequence: self.sequence,
            log_time: time,
            publish_time: time,
        };
        self.writer
            .write_to_known_channel(&header, data)
            .map_err(|e| self.failed(e))
    }

    /// Finishes the file.
    pub fn finish(mut self) -> Result<(), BagError> {
        self.writer.finish().map_err(|e| self.failed(e))?;
        Ok(())
    }
}

/// The definition of `nav_msgs/msg/Path` with the types it uses.
pub const PATH_DEFINITION: &str = "std_msgs/Header header
geometry_msgs/PoseStamped[] poses
================================================================================
MSG: std_msgs/Header
builtin_interfaces/Time stamp
string frame_id
================================================================================
MSG: builtin_interfaces/Time
int32 sec
uint32 nanosec
================================================================================
MSG: geometry_msgs/PoseStamped
std_msgs/Header header
Pose pose
================================================================================
MSG: geometry_msgs/Pose
Point position
Quaternion orientation
================================================================================
MSG: geometry_msgs/Point
float64 x
float64 y
float64 z
================================================================================
MSG: geometry_msgs/Quaternion
float64 x 0
float64 y 0
float64 z 0
float64 w 1
";

/// The definition of `geometry_msgs/msg/Twist` with the type it uses.
pub const TWIST_DEFINITION: &str = "Vector3 linear
Vector3 angular
================================================================================
MSG: geometry_msgs/Vector3
float64 x
float64 y
float64 z
";

/// A header (stamp in ns, frame).
fn header(w: &mut cdr::Writer, stamp: u64, frame: &str) {
    let sec = i32::try_from(stamp / 1_000_000_000).unwrap_or(i32::MAX);
    let nanosec = (stamp % 1_000_000_000) as u32;
    w.i32(sec).u32(nanosec).string(frame);
}

/// A `nav_msgs/msg/Path` of planar `poses` `(x, y, yaw)` in `frame` stamped `stamp` (ns).
pub fn path_message(stamp: u64, frame: &str, poses: &[[f64; 3]]) -> Vec<u8> {
    let mut w = cdr::Writer::new();
    header(&mut w, stamp, frame);
    w.u32(u32::try_from(poses.len()).unwrap_or(u32::MAX));
    for p in poses {
        header(&mut w, stamp, frame);
        let h = 0.5 * p[2];
        w.f64(p[0]).f64(p[1]).f64(0.0);
        w.f64(0.0).f64(0.0).f64(h.sin()).f64(h.cos());
    }
    w.finish()
}

/// A `geometry_msgs/msg/Twist`: forward `vx`, sideways `vy` (m/s), yaw rate `wz` (rad/s).
pub fn twist_message(vx: f64, vy: f64, wz: f64) -> Vec<u8> {
    let mut w = cdr::Writer::new();
    w.f64(vx).f64(vy).f64(0.0).f64(0.0).f64(0.0).f64(wz);
    w.finish()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn written_paths_and_twists_read_back_with_their_definitions() {
        let path = std::env::temp_dir().join(format!("h2n-rosbag-{}.mcap", std::process::id()));
        let mut bag = BagWriter::create(&path).unwrap();
        bag.add_topic("/plan", "nav_msgs/msg/Path", PATH_DEFINITION)
            .unwrap();
        bag.add_topic("/cmd", "geometry_msgs/msg/Twist", TWIST_DEFINITION)
            .unwrap();
        let poses = [[0.0, 0.0, 0.0], [0.1, 0.02, 0.2]];
        bag.write(
            "/plan",
            1_500_000_000,
            &path_message(1_500_000_000, "odom", &poses),
        )
        .unwrap();
        bag.write("/cmd", 1_500_000_000, &twist_message(1.0, 0.0, 2.0))
            .unwrap();
        // Logged after the first plan, but stamped before it.
        bag.write(
            "/plan",
            1_600_000_000,
            &path_message(1_400_000_000, "odom", &poses),
        )
        .unwrap();
        bag.finish().unwrap();
        let specs = [
            TopicSpec {
                topic: "/cmd".into(),
                types: vec![("geometry_msgs/msg/Twist", vec![("angular.z", "float64")])],
            },
            TopicSpec {
                topic: "/plan".into(),
                types: vec![(
                    "nav_msgs/msg/Path",
                    vec![("poses", "geometry_msgs/PoseStamped[]")],
                )],
            },
        ];
        // The second plan's stamp is earlier: refused, naming the topic and the message.
        let e = read_topics(&path, &specs).unwrap_err().to_string();
        assert!(
            e.contains("topic `/plan`, message 1") && e.contains("going backwards"),
            "{e}"
        );
        let topics = read_topics(&path, &specs[..1]).unwrap();
        assert_eq!(
            topics["/cmd"].messages[0].value.number("angular.z"),
            Some(2.0)
        );
        // A field of another type than expected.
        let wrong = [TopicSpec {
            topic: "/cmd".into(),
            types: vec![("geometry_msgs/msg/Twist", vec![("linear", "float64")])],
        }];
        let e = read_topics(&path, &wrong).unwrap_err().to_string();
        assert!(
            e.contains("topic `/cmd`") && e.contains("definition mismatch"),
            "{e}"
        );
        // Another type.
        let other = [TopicSpec {
            topic: "/cmd".into(),
            types: vec![("nav_msgs/msg/Odometry", vec![])],
        }];
        let e = read_topics(&path, &other).unwrap_err().to_string();
        assert!(
            e.contains("carries `geometry_msgs/msg/Twist`, expected nav_msgs/msg/Odometry"),
            "{e}"
        );
        // Cut short.
        let bytes = std::fs::read(&path).unwrap();
        std::fs::write(&path, &bytes[..bytes.len() / 2]).unwrap();
        assert!(read_topics(&path, &specs[..1]).is_err());
        let _ = std::fs::remove_file(&path);
    }
}
