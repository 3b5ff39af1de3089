"""`human2nav replay`: ROS 2 bags written with the `rosbags` package from PyPI (odometry, a goal,
people as people_msgs/People or SPENCER's TrackedPersons, an occupancy grid) are replayed, and
the bag written back is read with `rosbags` too; bad bags are refused naming the topic and the
message."""

import json
import os
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


def people_message(store, ns, t, kind):
    """One person crossing the robot's way at x = 3 m, walking +y at 1 m/s."""
    g = "geometry_msgs/msg/"
    y = -1.5 + t
    if kind == "people":
        P = T(store, g + "Point")
        person = T(store, "people_msgs/msg/Person")(
            name="ann", position=P(x=3.0, y=y, z=0.0), velocity=P(x=0.0, y=1.0, z=0.0),
            reliability=1.0, tagnames=[], tags=[],
        )
        return T(store, "people_msgs/msg/People")(header=header(store, ns), people=[person])
    V = T(store, g + "Vector3")
    track = T(store, "spencer_tracking_msgs/msg/TrackedPerson")(
        track_id=42, is_occluded=False, is_matched=True, detection_id=7,
        age=T(store, "builtin_interfaces/msg/Duration")(sec=1, nanosec=0),
        pose=T(store, g + "PoseWithCovariance")(pose=pose(store, 3.0, y), covariance=np.zeros(36)),
        twist=T(store, g + "TwistWithCovariance")(
            twist=T(store, g + "Twist")(linear=V(x=0.0, y=1.0, z=0.0), angular=V(x=0.0, y=0.0, z=0.0)),
            covariance=np.zeros(36),
        ),
    )
    return T(store, "spencer_tracking_msgs/msg/TrackedPersons")(header=header(store, ns), tracks=[track])


def grid(store, ns):
    g = "nav_msgs/msg/"
    data = np.zeros(40 * 40, dtype=np.int8)
    data[20 * 40 + 30] = 100
    info = T(store, g + "MapMetaData")(
        map_load_time=header(store, ns).stamp, resolution=np.float32(0.25), width=40, height=40,
        origin=pose(store, -5.0, -5.0),
    )
    return T(store, g + "OccupancyGrid")(header=header(store, ns), info=info, data=data)


START = 1_700_000_000 * 10**9


def write_bag(path, kind="people", store=None, odom_type="nav_msgs/msg/Odometry", edit=None,
              goal=True):
    """Two seconds: odometry at 20 Hz (0.5 m/s along x), the goal 6 m ahead, people at 10 Hz, a
    map. `edit(topic, index, bytes) -> bytes` may spoil a message."""
    store = store or typestore()
    people_type = "people_msgs/msg/People" if kind == "people" else "spencer_tracking_msgs/msg/TrackedPersons"
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        conns = {
            "/odom": w.add_connection("/odom", odom_type, typestore=store),
            "/people": w.add_connection("/people", people_type, typestore=store),
            "/map": w.add_connection("/map", "nav_msgs/msg/OccupancyGrid", typestore=store),
        }
        if goal:
            conns["/goal_pose"] = w.add_connection("/goal_pose", "geometry_msgs/msg/PoseStamped", typestore=store)
        msgs = [("/map", START, grid(store, START), "nav_msgs/msg/OccupancyGrid")]
        if goal:
            stamped = T(store, "geometry_msgs/msg/PoseStamped")(header=header(store, START), pose=pose(store, 6.0, 0.0))
            msgs.append(("/goal_pose", START, stamped, "geometry_msgs/msg/PoseStamped"))
        for k in range(41):
            ns = START + k * 50_000_000
            if odom_type == "nav_msgs/msg/Odometry":
                msgs.append(("/odom", ns, odometry(store, ns, 0.025 * k), odom_type))
            else:
                m = T(store, odom_type)(header=header(store, ns), pose=pose(store, 0.025 * k, 0.0))
                msgs.append(("/odom", ns, m, odom_type))
            if k % 2 == 0:
                msgs.append(("/people", ns, people_message(store, ns, 0.05 * k, kind), people_type))
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
            for _, c, m in make_reader(f).iter_messages(topics=["/scene"])
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
