//! Tests of the replay inputs on bags written here: a long bag streamed into the odometry's
//! frame, and a frame without transforms refused.

use super::super::{BagWriter, cdr, header};
use super::*;

const SEP: &str =
    "\n================================================================================\n";

/// Definitions with the fields the replay reads (a subset of the ROS ones: the reader
/// checks the fields it uses, not the rest).
fn definitions(types: &[&str]) -> String {
    types.join(SEP)
}

const HEADER: &str = "MSG: std_msgs/Header\nbuiltin_interfaces/Time stamp\nstring frame_id";
const POSE: &str = "MSG: geometry_msgs/Pose\nPoint position\nQuaternion orientation";
const POINT: &str = "MSG: geometry_msgs/Point\nfloat64 x\nfloat64 y\nfloat64 z";
const QUAT: &str = "MSG: geometry_msgs/Quaternion\nfloat64 x\nfloat64 y\nfloat64 z\nfloat64 w";
const VEC3: &str = "MSG: geometry_msgs/Vector3\nfloat64 x\nfloat64 y\nfloat64 z";

fn quaternion(w: &mut cdr::Writer, yaw: f64) {
    w.f64(0.0)
        .f64(0.0)
        .f64((0.5 * yaw).sin())
        .f64((0.5 * yaw).cos());
}

/// `seconds` of a robot driving +x at 0.5 m/s (odometry at 20 Hz in `odom`, a moving
/// `odom → base_link` on /tf), its goal and one person walking +y at 1 m/s past x = 3 (10
/// Hz), both given in `map`, with `map → odom` on /tf_static: `map` is `odom` moved by
/// (1, 0). People messages are logged `people_lag` after their stamp.
fn write_bag(path: &Path, seconds: i128, people_lag: u64) -> usize {
    let mut bag = BagWriter::create(path).unwrap();
    let odom = definitions(&[
        "std_msgs/Header header\ngeometry_msgs/PoseWithCovariance pose\n\
         geometry_msgs/TwistWithCovariance twist",
        HEADER,
        "MSG: geometry_msgs/PoseWithCovariance\nPose pose",
        POSE,
        POINT,
        QUAT,
        "MSG: geometry_msgs/TwistWithCovariance\nTwist twist",
        "MSG: geometry_msgs/Twist\nVector3 linear\nVector3 angular",
        VEC3,
    ]);
    bag.add_topic("/odom", "nav_msgs/msg/Odometry", &odom)
        .unwrap();
    let goal = definitions(&[
        "std_msgs/Header header\nPose pose",
        HEADER,
        POSE,
        POINT,
        QUAT,
    ]);
    bag.add_topic("/goal_pose", "geometry_msgs/msg/PoseStamped", &goal)
        .unwrap();
    let people = definitions(&[
        "std_msgs/Header header\npeople_msgs/Person[] people",
        HEADER,
        "MSG: people_msgs/Person\nstring name\ngeometry_msgs/Point position\n\
         geometry_msgs/Point velocity",
        POINT,
    ]);
    bag.add_topic("/people", "people_msgs/msg/People", &people)
        .unwrap();
    let tf = definitions(&[
        "geometry_msgs/TransformStamped[] transforms",
        "MSG: geometry_msgs/TransformStamped\nstd_msgs/Header header\nstring child_frame_id\n\
         Transform transform",
        HEADER,
        "MSG: geometry_msgs/Transform\nVector3 translation\nQuaternion rotation",
        VEC3,
        QUAT,
    ]);
    bag.add_topic("/tf", "tf2_msgs/msg/TFMessage", &tf).unwrap();
    bag.add_topic("/tf_static", "tf2_msgs/msg/TFMessage", &tf)
        .unwrap();
    let transform = |stamp: u64, parent: &str, child: &str, x: f64| {
        let mut w = cdr::Writer::new();
        w.u32(1);
        header(&mut w, stamp, parent);
        w.string(child).f64(x).f64(0.0).f64(0.0);
        quaternion(&mut w, 0.0);
        w.finish()
    };
    let start: u64 = 1_700_000_000_000_000_000;
    let mut msgs: Vec<(u64, &str, Vec<u8>)> = Vec::new();
    msgs.push((start, "/tf_static", transform(start, "map", "odom", 1.0)));
    let mut g = cdr::Writer::new();
    header(&mut g, start, "map");
    g.f64(7.0).f64(0.0).f64(0.0);
    quaternion(&mut g, 0.0);
    msgs.push((start, "/goal_pose", g.finish()));
    for k in 0..=(seconds * 20) as u64 {
        let ns = start + k * 50_000_000;
        let x = 0.025 * k as f64;
        let mut o = cdr::Writer::new();
        header(&mut o, ns, "odom");
        o.f64(x).f64(0.0).f64(0.0);
        quaternion(&mut o, 0.0);
        o.f64(0.5).f64(0.0).f64(0.0).f64(0.0).f64(0.0).f64(0.0);
        msgs.push((ns, "/odom", o.finish()));
        msgs.push((ns, "/tf", transform(ns, "odom", "base_link", x)));
        if k % 2 == 0 {
            let t = 0.05 * k as f64;
            let mut p = cdr::Writer::new();
            header(&mut p, ns, "map");
            p.u32(1).string("ann");
            // In map: x = 3 in odom is 4.
            p.f64(4.0).f64(-1.5 + t % 3.0).f64(0.0);
            p.f64(0.0).f64(1.0).f64(0.0);
            msgs.push((ns + people_lag, "/people", p.finish()));
        }
    }
    msgs.sort_by_key(|(t, ..)| *t);
    for (t, topic, data) in &msgs {
        bag.write(topic, *t, data).unwrap();
    }
    bag.finish().unwrap();
    msgs.len()
}

fn temp(name: &str) -> PathBuf {
    std::env::temp_dir().join(format!("h2n-inputs-{name}-{}.mcap", std::process::id()))
}

#[test]
fn a_long_bag_is_streamed_holding_a_window_and_people_come_into_the_odometry_frame() {
    let path = temp("long");
    // 60 s: 3,000 messages and more; the people 0.3 s behind their stamps.
    let written = write_bag(&path, 60, 300_000_000);
    assert!(written > 3_000, "{written}");
    let mut inputs =
        ReplayInputs::open(&path, &InputTopics::default(), InputSettings::default()).unwrap();
    assert!(inputs.reader().indexed());
    let mut calls = 0;
    while let Some(call) = inputs.next_call().unwrap() {
        let k = (call.stamp - 1_700_000_000_000_000_000) / 100_000_000;
        assert_eq!(calls, k as usize, "a call every 0.1 s from the start");
        calls += 1;
        assert_eq!(call.frame, "odom");
        assert!(
            (call.ego.x - 0.05 * k as f64).abs() < 1e-9,
            "{:?}",
            call.ego
        );
        // The goal, 7 m along map's x, is at 6 m in odom.
        assert!((call.goal[0] - 6.0).abs() < 1e-12, "{:?}", call.goal);
        let ann = &call.agents[0];
        assert!((ann.position[0] - 3.0).abs() < 1e-12, "{:?}", ann.position);
        let y = -1.5 + (0.1 * k as f64) % 3.0;
        assert!(
            (ann.position[1] - y).abs() < 1e-9,
            "{} against {y}",
            ann.position[1]
        );
        assert_eq!(ann.velocity, [0.0, 1.0]);
        if k >= 8 {
            assert_eq!(ann.history.len(), 8);
        }
    }
    assert_eq!(calls, 601);
    let stats = inputs.stats().clone();
    assert_eq!(inputs.reader().seen() as usize, written);
    eprintln!("read {written} messages, held at most {}", stats.peak_held);
    // About a second of messages (20 odometry, 10 people, 20 + 20 transforms ahead and
    // behind) at a time, not the bag's thousands.
    assert!(
        stats.peak_held < 120,
        "held at most {} of {written}",
        stats.peak_held
    );
    assert_eq!(stats.late, 0);
    assert_eq!(stats.untransformed, 0);

    // With a shorter wait than the people's lag, each of them is late.
    let settings = InputSettings {
        max_delay: 0.1,
        ..InputSettings::default()
    };
    let mut inputs = ReplayInputs::open(&path, &InputTopics::default(), settings).unwrap();
    let mut calls = 0;
    while inputs.next_call().unwrap().is_some() {
        calls += 1;
    }
    assert_eq!(calls, 601);
    // All but the last two, read before the odometry ends and the last calls are made.
    assert_eq!(inputs.stats().late, 601 - 2);
    let _ = std::fs::remove_file(&path);
}

#[test]
fn a_frame_without_transforms_is_refused_naming_it_and_the_message() {
    let path = temp("notf");
    write_bag(&path, 2, 0);
    let topics = InputTopics {
        tf_static: "/none".into(),
        ..InputTopics::default()
    };
    let mut inputs = ReplayInputs::open(&path, &topics, InputSettings::default()).unwrap();
    let e = loop {
        match inputs.next_call() {
            Ok(Some(_)) => continue,
            Ok(None) => panic!("replayed without map → odom"),
            Err(e) => break e.to_string(),
        }
    };
    assert!(
        e.contains(
            "topic `/goal_pose`, message 0: no transform path from frame `map` to frame `odom`"
        ) && e.contains("(the transforms read connect `base_link`, `odom`)"),
        "{e}"
    );
    // Without odometry there is no frame to bring anything into: no call, and no error
    // about frames (the caller says the topic is empty).
    let topics = InputTopics {
        odom: "/nothing".into(),
        ..InputTopics::default()
    };
    let mut inputs = ReplayInputs::open(&path, &topics, InputSettings::default()).unwrap();
    assert!(inputs.next_call().unwrap().is_none());
    assert_eq!(inputs.calls(), 0);
    let _ = std::fs::remove_file(&path);
}
