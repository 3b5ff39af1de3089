//! Transforms between frames as a bag's `/tf` and `/tf_static` carry them
//! (`tf2_msgs/msg/TFMessage`: `geometry_msgs/msg/TransformStamped[]`), in the plane: each
//! transform's x, y and its rotation's yaw. A frame's transform to its parent (`header.frame_id`
//! → `child_frame_id`) is looked up at a stamp as the latest one at or before it (a static one
//! at any stamp; stamp 0, tf2's "latest", the latest held), and a frame is brought into another
//! by chaining the transforms up to their common ancestor, as tf2 does. Frame names are taken
//! without a leading `/`.

use super::cdr::Value;
use human2nav_core::Pose2;
use std::collections::{BTreeMap, BTreeSet, VecDeque};

/// The fields of a `tf2_msgs/msg/TFMessage` the buffer reads, as
/// [`super::TopicSpec`] takes them.
pub const TF_FIELDS: [(&str, &str); 11] = [
    ("transforms", "geometry_msgs/TransformStamped[]"),
    ("transforms.header.stamp.sec", "int32"),
    ("transforms.header.stamp.nanosec", "uint32"),
    ("transforms.header.frame_id", "string"),
    ("transforms.child_frame_id", "string"),
    ("transforms.transform.translation.x", "float64"),
    ("transforms.transform.translation.y", "float64"),
    ("transforms.transform.rotation.x", "float64"),
    ("transforms.transform.rotation.y", "float64"),
    ("transforms.transform.rotation.z", "float64"),
    ("transforms.transform.rotation.w", "float64"),
];

/// A frame's name as tf2 compares it: without a leading `/`.
pub fn frame_name(f: &str) -> &str {
    f.trim_start_matches('/')
}

/// The yaw of the quaternion `(x, y, z, w)` (rad).
pub fn yaw_of(x: f64, y: f64, z: f64, w: f64) -> f64 {
    (2.0 * (w * z + x * y)).atan2(1.0 - 2.0 * (y * y + z * z))
}

/// One transform: `child`'s pose in `parent` at `stamp` (ns).
#[derive(Clone, Debug, PartialEq)]
pub struct Transform {
    /// `header.frame_id`.
    pub parent: String,
    /// `child_frame_id`.
    pub child: String,
    /// `header.stamp` (ns).
    pub stamp: i128,
    /// The child frame's origin and heading in the parent frame.
    pub pose: Pose2,
}

/// The transforms of a decoded `tf2_msgs/msg/TFMessage` (fields checked by [`TF_FIELDS`]).
pub fn transforms_of(v: &Value) -> Vec<Transform> {
    let num = |t: &Value, path: &str| t.number(path).unwrap_or(0.0);
    v.list("transforms")
        .unwrap_or_default()
        .iter()
        .map(|t| {
            let q = |c: &str| num(t, &format!("transform.rotation.{c}"));
            Transform {
                parent: frame_name(t.text("header.frame_id").unwrap_or("")).to_string(),
                child: frame_name(t.text("child_frame_id").unwrap_or("")).to_string(),
                stamp: num(t, "header.stamp.sec") as i128 * 1_000_000_000
                    + num(t, "header.stamp.nanosec") as i128,
                pose: Pose2::new(
                    num(t, "transform.translation.x"),
                    num(t, "transform.translation.y"),
                    yaw_of(q("x"), q("y"), q("z"), q("w")),
                ),
            }
        })
        .collect()
}

/// Why a frame could not be brought into another.
#[derive(Clone, Debug, PartialEq)]
pub enum TfError {
    /// The frames are not connected by the transforms held.
    NoPath {
        /// The frame to bring in.
        from: String,
        /// The frame wanted.
        to: String,
        /// Every frame the transforms name.
        known: Vec<String>,
    },
    /// They are, but a moving link has no transform at or before the stamp yet.
    NotYet {
        /// That link's parent frame.
        parent: String,
        /// Its child frame.
        child: String,
        /// The stamp of its earliest transform held (ns).
        first: Option<i128>,
    },
    /// The transforms form a loop through this frame.
    Loop(String),
}

impl std::fmt::Display for TfError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            TfError::NoPath { from, to, known } => {
                let known = if known.is_empty() {
                    "no transforms were read".to_string()
                } else {
                    format!("the transforms read connect {}", known.join(", "))
                };
                write!(
                    f,
                    "no transform path from frame `{from}` to frame `{to}` ({known})"
                )
            }
            TfError::NotYet {
                parent,
                child,
                first,
            } => {
                write!(
                    f,
                    "no transform `{parent}` → `{child}` at or before this stamp"
                )?;
                match first {
                    Some(s) => write!(f, " (the first is at {:.3} s)", *s as f64 * 1e-9),
                    None => Ok(()),
                }
            }
            TfError::Loop(frame) => write!(f, "the transforms form a loop through `{frame}`"),
        }
    }
}

/// One frame's link to its parent.
#[derive(Clone, Debug)]
struct Link {
    parent: String,
    /// From `/tf_static`: valid at any stamp.
    fixed: Option<Pose2>,
    /// From `/tf`, by stamp.
    samples: VecDeque<(i128, Pose2)>,
    /// Whether older samples were let go.
    pruned: bool,
}

/// The transforms held, by child frame.
#[derive(Clone, Debug, Default)]
pub struct TfBuffer {
    links: BTreeMap<String, Link>,
}

impl TfBuffer {
    /// An empty buffer.
    pub fn new() -> Self {
        Self::default()
    }

    /// Adds a transform, static (`/tf_static`: any stamp) or not. A frame given a new parent
    /// forgets the old one's transforms.
    pub fn insert(&mut self, mut t: Transform, fixed: bool) {
        t.parent = frame_name(&t.parent).to_string();
        t.child = frame_name(&t.child).to_string();
        let link = self.links.entry(t.child).or_insert_with(|| Link {
            parent: t.parent.clone(),
            fixed: None,
            samples: VecDeque::new(),
            pruned: false,
        });
        if link.parent != t.parent {
            *link = Link {
                parent: t.parent,
                fixed: None,
                samples: VecDeque::new(),
                pruned: false,
            };
        }
        if fixed {
            link.fixed = Some(t.pose);
            link.samples.clear();
        } else {
            link.fixed = None;
            let at = link.samples.partition_point(|(s, _)| *s < t.stamp);
            match link.samples.get_mut(at) {
                Some(same) if same.0 == t.stamp => same.1 = t.pose,
                _ => link.samples.insert(at, (t.stamp, t.pose)),
            }
        }
    }

    /// Lets go of the moving transforms no lookup at or after `before` (ns) needs: of each
    /// link, those older than its latest at or before `before`.
    pub fn prune(&mut self, before: i128) {
        for link in self.links.values_mut() {
            while link.samples.len() >= 2 && link.samples[1].0 <= before {
                link.samples.pop_front();
                link.pruned = true;
            }
        }
    }

    /// How many transforms are held (static ones included).
    pub fn len(&self) -> usize {
        self.links
            .values()
            .map(|l| l.samples.len() + usize::from(l.fixed.is_some()))
            .sum()
    }

    /// Whether none is held.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// `child`'s link at `stamp`.
    fn link_at(&self, child: &str, stamp: i128) -> Result<Pose2, TfError> {
        let Some(link) = self.links.get(child) else {
            return Ok(Pose2::IDENTITY);
        };
        if let Some(p) = link.fixed {
            return Ok(p);
        }
        let latest = if stamp == 0 {
            link.samples.back()
        } else {
            let n = link.samples.partition_point(|(s, _)| *s <= stamp);
            match n.checked_sub(1) {
                Some(i) => link.samples.get(i),
                // Older samples were let go: the earliest held is the best there is.
                None if link.pruned => link.samples.front(),
                None => None,
            }
        };
        latest.map(|(_, p)| *p).ok_or_else(|| TfError::NotYet {
            parent: link.parent.clone(),
            child: child.to_string(),
            first: link.samples.front().map(|(s, _)| *s),
        })
    }

    /// `frame` and its ancestors, up to the root.
    fn chain<'a>(&'a self, frame: &'a str) -> Result<Vec<&'a str>, TfError> {
        let mut out = vec![frame];
        let mut at = frame;
        while let Some(link) = self.links.get(at) {
            at = &link.parent;
            if out.contains(&at) {
                return Err(TfError::Loop(at.to_string()));
            }
            out.push(at);
        }
        Ok(out)
    }

    /// The pose of `frame` in its ancestor `chain.last()` at `stamp`.
    fn up(&self, chain: &[&str], stamp: i128) -> Result<Pose2, TfError> {
        let mut pose = Pose2::IDENTITY;
        for child in chain[..chain.len() - 1].iter().rev() {
            pose = pose.compose(self.link_at(child, stamp)?);
        }
        Ok(pose)
    }

    /// The transform that brings coordinates in `from` into `to` at `stamp` (ns): the pose of
    /// `from` in `to`, so that `lookup(..).act(p)` is `p` (given in `from`) in `to`.
    pub fn lookup(&self, from: &str, to: &str, stamp: i128) -> Result<Pose2, TfError> {
        let (from, to) = (frame_name(from), frame_name(to));
        if from == to {
            return Ok(Pose2::IDENTITY);
        }
        let up_from = self.chain(from)?;
        let up_to = self.chain(to)?;
        let Some((i, j)) = up_from
            .iter()
            .enumerate()
            .find_map(|(i, f)| up_to.iter().position(|g| g == f).map(|j| (i, j)))
        else {
            let mut known: BTreeSet<&str> = BTreeSet::new();
            for (child, link) in &self.links {
                known.insert(child);
                known.insert(&link.parent);
            }
            return Err(TfError::NoPath {
                from: from.to_string(),
                to: to.to_string(),
                known: known.into_iter().map(|s| format!("`{s}`")).collect(),
            });
        };
        let common_from = self.up(&up_from[..=i], stamp)?;
        let common_to = self.up(&up_to[..=j], stamp)?;
        Ok(common_to.inverse().compose(common_from))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn t(parent: &str, child: &str, stamp: i128, x: f64, y: f64, yaw: f64) -> Transform {
        Transform {
            parent: parent.into(),
            child: child.into(),
            stamp,
            pose: Pose2::new(x, y, yaw),
        }
    }

    fn close(a: [f64; 2], b: [f64; 2]) -> bool {
        (a[0] - b[0]).abs() < 1e-12 && (a[1] - b[1]).abs() < 1e-12
    }

    #[test]
    fn chains_meet_at_the_common_ancestor_latest_at_or_before_the_stamp() {
        let mut tf = TfBuffer::new();
        // map → odom moves; odom → base_link; map → marker static.
        tf.insert(t("map", "odom", 10, 1.0, 0.0, 0.0), false);
        tf.insert(t("map", "odom", 20, 2.0, 0.0, 0.0), false);
        tf.insert(
            t(
                "odom",
                "base_link",
                10,
                0.5,
                0.0,
                std::f64::consts::FRAC_PI_2,
            ),
            false,
        );
        tf.insert(t("/map", "marker", 0, 0.0, 3.0, 0.0), true);
        // A point at (5, 0) in map is at (4, 0) in odom at 15, (3, 0) at 20 and after.
        let p = [5.0, 0.0];
        assert!(close(
            tf.lookup("map", "odom", 15).unwrap().act(p),
            [4.0, 0.0]
        ));
        assert!(close(
            tf.lookup("map", "/odom", 25).unwrap().act(p),
            [3.0, 0.0]
        ));
        // Stamp 0: the latest.
        assert!(close(
            tf.lookup("map", "odom", 0).unwrap().act(p),
            [3.0, 0.0]
        ));
        // Up and down: the marker's origin, (0, 3) in map, in base_link at 15 (base_link at
        // (1.5, 0) in map, facing +y): 3 m ahead and 1.5 m to the left.
        let q = tf
            .lookup("marker", "base_link", 15)
            .unwrap()
            .act([0.0, 0.0]);
        assert!(close(q, [3.0, 1.5]), "{q:?}");
        // Before the first map → odom: not yet; an unknown frame: no path.
        let e = tf.lookup("map", "odom", 5).unwrap_err();
        assert!(
            matches!(
                &e,
                TfError::NotYet {
                    first: Some(10),
                    ..
                }
            ),
            "{e:?}"
        );
        assert!(e.to_string().contains("`map` → `odom`"), "{e}");
        let e = tf.lookup("laser", "odom", 15).unwrap_err();
        assert!(
            e.to_string()
                .contains("no transform path from frame `laser` to frame `odom`"),
            "{e}"
        );
        assert!(
            e.to_string()
                .contains("`base_link`, `map`, `marker`, `odom`"),
            "{e}"
        );
    }

    #[test]
    fn pruning_keeps_the_latest_before_the_horizon_and_loops_are_named() {
        let mut tf = TfBuffer::new();
        for k in 0..10 {
            tf.insert(t("map", "odom", k * 10, k as f64, 0.0, 0.0), false);
        }
        assert_eq!(tf.len(), 10);
        tf.prune(55);
        assert_eq!(
            tf.len(),
            5,
            "50 (the latest at or before 55), 60, 70, 80, 90"
        );
        assert!(close(
            tf.lookup("map", "odom", 55).unwrap().act([0.0, 0.0]),
            [-5.0, 0.0]
        ));
        // A stamp before what is held: the earliest held.
        assert!(close(
            tf.lookup("map", "odom", 5).unwrap().act([0.0, 0.0]),
            [-5.0, 0.0]
        ));
        tf.insert(t("odom", "map", 0, 0.0, 0.0, 0.0), false);
        let e = tf.lookup("odom", "base_link", 1).unwrap_err();
        assert!(matches!(e, TfError::Loop(_)), "{e:?}");
    }
}
