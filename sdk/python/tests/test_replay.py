"""`human2nav replay`: ROS 2 bags written with the `rosbags` package from PyPI (odometry, a goal,
people as people_msgs/People or SPENCER's TrackedPersons, an occupancy grid) are replayed, and
the bag written back is read with `rosbags` too; bad bags are refused naming the topic and the
message."""

import json
import os
import re
import subprocess
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from rosbags.rosbag2 import Reader, StoragePlugin, Writer
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

ROOT = Path(__file__).resolve().parents[3]
DIABLO = ROOT / "robots" / "diablo" / "robot.toml"

PEOPLE_MSGS = {
    "people_msgs/msg/Person": "string name\ngeometry_msgs/Point position\n"
    "geometry_msgs/Point velocity\nfloat64 reliability\nstring[] tagnames\nstring[] tags\n",
    "people_msgs/msg/People": "std_msgs/Header header\npeople_msgs/Person[] people\n",
    "spencer_tracking_msgs/msg/TrackedPerson": "uint64 track_id\nbool is_occluded\n"
    "bool is_matched\nuint64 detection_id\nbuiltin_interfaces/Duration age\n"
    "geometry_msgs/PoseWithCovariance pose\ngeometry_msgs/TwistWithCovariance twist\n",
    "spencer_tracking_msgs/msg/TrackedPersons": "std_msgs/Header header\n"
    "spencer_tracking_msgs/TrackedPerson[] tracks\n",
}


def typestore(people_msgs=PEOPLE_MSGS):
    store = get_typestore(Stores.ROS2_HUMBLE)
    types = {}
    for name, text in people_msgs.items():
        types.update(get_types_from_msg(text, name))
    store.register(types)
    return store


def binary():
    path = Path(os.environ.get("HUMAN2NAV_BIN", ROOT / "target" / "debug" / "human2nav"))
    assert path.is_file(), f"no {path}: build it with `cargo build -p human2nav-cli`"
    return path


def replay(bag, out, *extra):
    return subprocess.run(
        [str(binary()), "replay", str(bag), "--robot", str(DIABLO), "--out", str(out), *extra],
        cwd=ROOT, capture_output=True, text=True,
    )


def T(store, name):
    return store.types[name]


def header(store, ns, frame="odom"):
    Time = T(store, "builtin_interfaces/msg/Time")
    return T(store, "std_msgs/msg/Header")(stamp=Time(sec=ns // 10**9, nanosec=ns % 10**9), frame_id=frame)


def pose(store, x, y, yaw=0.0):
    x, y, yaw = float(x), float(y), float(yaw)
    g = "geometry_msgs/msg/"
    return T(store, g + "Pose")(
        position=T(store, g + "Point")(x=x, y=y, z=0.0),
        orientation=T(store, g + "Quaternion")(x=0.0, y=0.0, z=np.sin(yaw / 2), w=np.cos(yaw / 2)),
    )


def odometry(store, ns, x):
    g = "geometry_msgs/msg/"
    V = T(store, g + "Vector3")
    return T(store, "nav_msgs/msg/Odometry")(
        header=header(store, ns), child_frame_id="base_link",
        pose=T(store, g + "PoseWithCovariance")(pose=pose(store, x, 0.0), covariance=np.zeros(36)),
        twist=T(store, g + "TwistWithCovariance")(
            twist=T(store, g + "Twist")(linear=V(x=0.5, y=0.0, z=0.0), angular=V(x=0.0, y=0.0, z=0.0)),
            covariance=np.zeros(36),
        ),
    )


def people_message(store, ns, t, kind, frame="odom", place=None):
    """One person crossing the robot's way at x = 3 m, walking +y at 1 m/s; `place(x, y, vx, vy)`
    gives them in `frame` instead of the odometry's."""
    g = "geometry_msgs/msg/"
    x, y, vx, vy = (place or (lambda *a: a))(3.0, -1.5 + t, 0.0, 1.0)
    if kind == "people":
        P = T(store, g + "Point")
        person = T(store, "people_msgs/msg/Person")(
            name="ann", position=P(x=x, y=y, z=0.0), velocity=P(x=vx, y=vy, z=0.0),
            reliability=1.0, tagnames=[], tags=[],
        )
        return T(store, "people_msgs/msg/People")(header=header(store, ns, frame), people=[person])
    V = T(store, g + "Vector3")
    track = T(store, "spencer_tracking_msgs/msg/TrackedPerson")(
        track_id=42, is_occluded=False, is_matched=True, detection_id=7,
        age=T(store, "builtin_interfaces/msg/Duration")(sec=1, nanosec=0),
        pose=T(store, g + "PoseWithCovariance")(pose=pose(store, x, y), covariance=np.zeros(36)),
        twist=T(store, g + "TwistWithCovariance")(
            twist=T(store, g + "Twist")(linear=V(x=vx, y=vy, z=0.0), angular=V(x=0.0, y=0.0, z=0.0)),
            covariance=np.zeros(36),
        ),
    )
    return T(store, "spencer_tracking_msgs/msg/TrackedPersons")(header=header(store, ns, frame), tracks=[track])


def grid(store, ns, frame="odom", origin=(-5.0, -5.0, 0.0)):
    g = "nav_msgs/msg/"
    data = np.zeros(40 * 40, dtype=np.int8)
    data[20 * 40 + 30] = 100
    info = T(store, g + "MapMetaData")(
        map_load_time=header(store, ns).stamp, resolution=np.float32(0.25), width=40, height=40,
        origin=pose(store, *origin),
    )
    return T(store, g + "OccupancyGrid")(header=header(store, ns, frame), info=info, data=data)


def moved(frame_pose, x, y):
    """(x, y) of a frame posed at `frame_pose` = (x0, y0, yaw) given in that frame's parent."""
    x0, y0, yaw = frame_pose
    c, s = np.cos(yaw), np.sin(yaw)
    return x0 + c * x - s * y, y0 + s * x + c * y


def seen_from(frame_pose, x, y, vx, vy):
    """A point and a velocity of the parent frame given in the frame posed at `frame_pose`."""
    x0, y0, yaw = frame_pose
    c, s = np.cos(yaw), np.sin(yaw)
    dx, dy = x - x0, y - y0
    return c * dx + s * dy, -s * dx + c * dy, c * vx + s * vy, -s * vx + c * vy


def tf_message(store, ns, transforms):
    """A tf2_msgs/TFMessage of (parent, child, (x, y, yaw))."""
    g = "geometry_msgs/msg/"
    V, Q = T(store, g + "Vector3"), T(store, g + "Quaternion")
    return T(store, "tf2_msgs/msg/TFMessage")(transforms=[
        T(store, g + "TransformStamped")(
            header=header(store, ns, parent), child_frame_id=child,
            transform=T(store, g + "Transform")(
                translation=V(x=x, y=y, z=0.0),
                rotation=Q(x=0.0, y=0.0, z=np.sin(yaw / 2), w=np.cos(yaw / 2)),
            ),
        )
        for parent, child, (x, y, yaw) in transforms
    ])


# Where `odom` lies in `map` (the transform `map → odom`), and a laser on the robot, 0.2 m ahead,
# turned left.
ODOM_IN_MAP = (1.0, -2.0, 0.3)
LASER_ON_BASE = (0.2, 0.0, np.pi / 2)


START = 1_700_000_000 * 10**9


def write_bag(path, kind="people", store=None, odom_type="nav_msgs/msg/Odometry", edit=None,
              goal=True, frames=False, seconds=2, goal_x=6.0):
    """`seconds` of odometry at 20 Hz (0.5 m/s along x), the goal `goal_x` ahead, people at 10 Hz,
    a map. `edit(topic, index, bytes) -> bytes` may spoil a message. With `frames`, the goal and
    the map are given in `map` (`map → odom` on /tf_static) and the people in `laser` (a moving
    `odom → base_link` on /tf, `base_link → laser` on /tf_static): the same scene."""
    store = store or typestore()
    people_type = "people_msgs/msg/People" if kind == "people" else "spencer_tracking_msgs/msg/TrackedPersons"
    tf_type = "tf2_msgs/msg/TFMessage"
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        conns = {
            "/odom": w.add_connection("/odom", odom_type, typestore=store),
            "/people": w.add_connection("/people", people_type, typestore=store),
            "/map": w.add_connection("/map", "nav_msgs/msg/OccupancyGrid", typestore=store),
        }
        if goal:
            conns["/goal_pose"] = w.add_connection("/goal_pose", "geometry_msgs/msg/PoseStamped", typestore=store)
        msgs = []
        if frames:
            conns["/tf"] = w.add_connection("/tf", tf_type, typestore=store)
            conns["/tf_static"] = w.add_connection("/tf_static", tf_type, typestore=store)
            static = tf_message(store, START, [("map", "odom", ODOM_IN_MAP), ("base_link", "laser", LASER_ON_BASE)])
            msgs.append(("/tf_static", START, static, tf_type))
            map_frame, origin = "map", (*moved(ODOM_IN_MAP, -5.0, -5.0), ODOM_IN_MAP[2])
        else:
            map_frame, origin = "odom", (-5.0, -5.0, 0.0)
        msgs.append(("/map", START, grid(store, START, map_frame, origin), "nav_msgs/msg/OccupancyGrid"))
        if goal:
            gx, gy = moved(ODOM_IN_MAP, goal_x, 0.0) if frames else (goal_x, 0.0)
            stamped = T(store, "geometry_msgs/msg/PoseStamped")(
                header=header(store, START, map_frame), pose=pose(store, gx, gy))
            msgs.append(("/goal_pose", START, stamped, "geometry_msgs/msg/PoseStamped"))
        for k in range(20 * seconds + 1):
            ns = START + k * 50_000_000
            if odom_type == "nav_msgs/msg/Odometry":
                msgs.append(("/odom", ns, odometry(store, ns, 0.025 * k), odom_type))
            else:
                m = T(store, odom_type)(header=header(store, ns), pose=pose(store, 0.025 * k, 0.0))
                msgs.append(("/odom", ns, m, odom_type))
            if frames:
                msgs.append(("/tf", ns, tf_message(store, ns, [("odom", "base_link", (0.025 * k, 0.0, 0.0))]), tf_type))
            if k % 2 == 0:
                if frames:
                    laser = moved((0.025 * k, 0.0, 0.0), LASER_ON_BASE[0], LASER_ON_BASE[1]) + (LASER_ON_BASE[2],)
                    person = people_message(store, ns, 0.05 * k, kind, "laser",
                                            lambda x, y, vx, vy, f=laser: seen_from(f, x, y, vx, vy))
                else:
                    person = people_message(store, ns, 0.05 * k, kind)
                msgs.append(("/people", ns, person, people_type))
        counts = {}
        for topic, ns, msg, msgtype in sorted(msgs, key=lambda m: m[1]):
            data = bytes(store.serialize_cdr(msg, msgtype))
            index = counts.get(topic, 0)
            counts[topic] = index + 1
            if edit:
                data = edit(topic, index, data)
            w.write(conns[topic], ns, data)
    return path


def read_output(path):
    store = get_typestore(Stores.ROS2_HUMBLE)
    out = {}
    with Reader(path) as r:
        for conn, ns, raw in r.messages():
            out.setdefault(conn.topic, []).append((ns, conn.msgtype, store.deserialize_cdr(raw, conn.msgtype)))
    return out


@pytest.mark.parametrize("kind", ["people", "tracked"])
def test_a_bag_is_replayed_into_plans_and_commands_rosbags_reads(tmp_path, kind):
    bag = write_bag(tmp_path / "in", kind)
    out = tmp_path / "replayed.mcap"
    done = replay(bag, out, "--rate", "5")
    assert done.returncode == 0, done.stdout + done.stderr
    assert "11 planning calls at 5 Hz over 2.0 s" in done.stdout, done.stdout
    topics = read_output(out)
    plans, cmds = topics["/human2nav/plan"], topics["/human2nav/cmd_vel"]
    assert len(plans) == len(cmds) == 11
    assert {m[1] for m in plans} == {"nav_msgs/msg/Path"}
    assert {m[1] for m in cmds} == {"geometry_msgs/msg/Twist"}
    for k, (ns, _, path) in enumerate(plans):
        assert ns == START + k * 200_000_000
        assert path.header.stamp.sec * 10**9 + path.header.stamp.nanosec == ns
        assert path.header.frame_id == "odom" and len(path.poses) > 1
        # The plan starts where the odometry had the robot then (0.5 m/s along x).
        first = path.poses[0].pose.position
        assert first.x == pytest.approx(0.1 * k, abs=1e-9) and first.y == pytest.approx(0.0, abs=1e-9)
        q = path.poses[-1].pose.orientation
        assert q.x**2 + q.y**2 + q.z**2 + q.w**2 == pytest.approx(1.0)
    # The commands move the robot toward the goal, within diablo's speed.
    speeds = [c.linear.x for _, _, c in cmds]
    assert max(speeds) > 0.1 and max(abs(s) for s in speeds) < 2.5
    # The scene beside it: the person as a cylinder near x = 3.
    with open(tmp_path / "replayed.scene.mcap", "rb") as f:
        people = [
            json.loads(m.data)
            for _, c, m in make_reader(f).iter_messages(topics=["/scene/people"])
        ]
    xs = [c["pose"]["position"]["x"] for u in people for e in u["entities"] if e["id"] == "pedestrians" for c in e["cylinders"]]
    assert xs and all(x == pytest.approx(3.0) for x in xs)


def refused(tmp_path, bag, *extra):
    done = replay(bag, tmp_path / "never.mcap", *extra)
    assert done.returncode != 0, done.stdout
    return done.stderr


def test_a_bag_without_the_goal_topic_is_refused_naming_it(tmp_path):
    e = refused(tmp_path, write_bag(tmp_path / "in", goal=False))
    assert "no messages on topic `/goal_pose`" in e, e
    e = refused(tmp_path, write_bag(tmp_path / "in2"), "--odom", "/odometry")
    assert "no messages on topic `/odometry`" in e, e


def test_a_definition_that_does_not_match_is_refused_naming_the_topic(tmp_path):
    # people_msgs/Person with float32 positions (geometry_msgs/Point32).
    wrong = dict(PEOPLE_MSGS)
    wrong["people_msgs/msg/Person"] = wrong["people_msgs/msg/Person"].replace(
        "geometry_msgs/Point position", "geometry_msgs/Point32 position")
    store = typestore(wrong)
    orig = people_message

    def with_point32(store_, ns, t, kind):
        m = orig(store_, ns, t, kind)
        P32 = T(store_, "geometry_msgs/msg/Point32")
        m.people[0].position = P32(x=np.float32(3.0), y=np.float32(-1.5 + t), z=np.float32(0.0))
        return m

    globals()["people_message"] = with_point32
    try:
        bag = write_bag(tmp_path / "in", store=store)
    finally:
        globals()["people_message"] = orig
    e = refused(tmp_path, bag)
    assert "topic `/people`" in e and "people.position.x" in e and "definition mismatch" in e, e
    # A topic of another type.
    e = refused(tmp_path, write_bag(tmp_path / "in2", odom_type="geometry_msgs/msg/PoseStamped"))
    assert "topic `/odom` carries `geometry_msgs/msg/PoseStamped`, expected nav_msgs/msg/Odometry" in e, e


def test_timestamps_going_backwards_and_truncated_messages_name_the_topic_and_index(tmp_path):
    store = typestore()

    def backwards(topic, index, data):
        if topic == "/odom" and index == 5:
            ns = START  # message 5 stamped at the start again
            return bytes(store.serialize_cdr(odometry(store, ns, 0.125), "nav_msgs/msg/Odometry"))
        return data

    e = refused(tmp_path, write_bag(tmp_path / "in", store=store, edit=backwards))
    assert "topic `/odom`, message 5" in e and "going backwards" in e, e

    def truncated(topic, index, data):
        return data[:60] if topic == "/people" and index == 3 else data

    e = refused(tmp_path, write_bag(tmp_path / "in2", store=store, edit=truncated))
    assert "topic `/people`, message 3" in e and "truncated" in e, e

    # The file itself cut short.
    bag = write_bag(tmp_path / "in3", store=store)
    mcap_file = next(Path(bag).glob("*.mcap"))
    data = mcap_file.read_bytes()
    mcap_file.write_bytes(data[: len(data) // 2])
    e = refused(tmp_path, mcap_file)
    assert "truncated or malformed" in e, e


@pytest.mark.parametrize("kind", ["people", "tracked"])
def test_people_goal_and_map_in_other_frames_are_brought_into_the_odometry_frame(tmp_path, kind):
    """The scene of the first test with the goal and the map in `map` and the people in a
    laser's frame, joined to the odometry's by /tf and /tf_static: the same plans."""
    plain, framed = tmp_path / "plain.mcap", tmp_path / "framed.mcap"
    done = replay(write_bag(tmp_path / "in", kind), plain, "--rate", "5")
    assert done.returncode == 0, done.stdout + done.stderr
    done = replay(write_bag(tmp_path / "in-tf", kind, frames=True), framed, "--rate", "5")
    assert done.returncode == 0, done.stdout + done.stderr
    assert "11 planning calls at 5 Hz over 2.0 s" in done.stdout, done.stdout
    assert "left out" not in done.stderr and "late" not in done.stderr, done.stderr
    a, b = read_output(plain), read_output(framed)
    for topic in ["/human2nav/plan", "/human2nav/cmd_vel"]:
        assert len(a[topic]) == len(b[topic]) == 11
    for (ns, _, p), (ns2, _, q) in zip(a["/human2nav/plan"], b["/human2nav/plan"]):
        assert ns == ns2 and q.header.frame_id == "odom"
        for u, v in zip(p.poses, q.poses):
            assert v.pose.position.x == pytest.approx(u.pose.position.x, abs=1e-6)
            assert v.pose.position.y == pytest.approx(u.pose.position.y, abs=1e-6)
    # The scene shows the person where the plain bag has them, at x = 3 in odom.
    with open(tmp_path / "framed.scene.mcap", "rb") as f:
        updates = [json.loads(m.data) for _, c, m in make_reader(f).iter_messages(topics=["/scene/people"])]
    xs = [c["pose"]["position"]["x"] for u in updates for e in u["entities"] if e["id"] == "pedestrians" for c in e["cylinders"]]
    assert xs and all(x == pytest.approx(3.0) for x in xs)


def test_a_frame_with_no_transform_path_is_refused_naming_it(tmp_path):
    bag = write_bag(tmp_path / "in", frames=True)
    # Without /tf_static, `laser` and `map` hang on nothing.
    e = refused(tmp_path, bag, "--tf-static", "/none")
    assert "topic `/goal_pose`, message 0: no transform path from frame `map` to frame `odom`" in e, e
    assert "--tf-static" in e, e
    assert not (tmp_path / "never.mcap").exists()


def test_a_long_bag_is_read_as_a_stream(tmp_path):
    """A minute of messages is replayed holding about a second of them at a time."""
    bag = write_bag(tmp_path / "in", frames=True, seconds=60, goal_x=40.0)
    done = replay(bag, tmp_path / "long.mcap", "--rate", "1")
    assert done.returncode == 0, done.stdout + done.stderr
    assert "61 planning calls at 1 Hz over 60.0 s" in done.stdout, done.stdout
    read = re.search(r"read: +(\d+) messages in log-time order, through the file's index; held at most (\d+)", done.stdout)
    assert read, done.stdout
    messages, held = int(read[1]), int(read[2])
    # 1,201 odometry and transforms each, 601 people, the map, the goal and the static ones.
    assert messages == 1201 * 2 + 601 + 3, messages
    # The odometry and people of about a second and the transforms of about three (50 a second),
    # not the bag's 3,006.
    assert held < 150, done.stdout
