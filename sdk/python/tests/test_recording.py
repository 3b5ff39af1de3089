"""`human2nav bench --record` and `human2nav plan --record`: the MCAP files read with the `mcap`
package from PyPI (an implementation nobody here wrote), as Foxglove would read them: JSON
messages in Foxglove's schemas, each channel with its JSON Schema."""

import csv
import json
import os
import subprocess
from collections import Counter
from pathlib import Path

import pytest
from mcap.reader import make_reader

ROOT = Path(__file__).resolve().parents[3]

SCHEMAS = {
    "/tf": "foxglove.FrameTransform",
    "/robot/pose": "foxglove.PoseInFrame",
    "/plan": "foxglove.PosesInFrame",
    "/scene/static": "foxglove.SceneUpdate",
    "/scene/people": "foxglove.SceneUpdate",
    "/scene/plan": "foxglove.SceneUpdate",
    "/outcome": "foxglove.Log",
}
# Which scene topic carries each entity: the static scene, the people and the plan on topics of
# their own, so that a viewer jumping to a time (the latest message of each topic) shows all.
ENTITY_TOPIC = {
    "footprint": "/scene/static",
    "goal": "/scene/static",
    "obstacles": "/scene/static",
    "pedestrians": "/scene/people",
    "plan": "/scene/plan",
    "candidates": "/scene/plan",
}


def binary():
    """The `human2nav` binary `sdk/dev.sh test` builds (or $HUMAN2NAV_BIN)."""
    path = Path(os.environ.get("HUMAN2NAV_BIN", ROOT / "target" / "debug" / "human2nav"))
    assert path.is_file(), f"no {path}: build it with `cargo build -p human2nav-cli`"
    return path


def run(*args, cwd):
    out = subprocess.run([str(binary()), *args], cwd=cwd, capture_output=True, text=True)
    assert out.returncode == 0, out.stdout + out.stderr
    return out.stdout


def read(path):
    """Schemas by topic, the messages as (topic, log time, decoded JSON) and the metadata."""
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        channels = {}
        for c in summary.channels.values():
            schema = summary.schemas[c.schema_id]
            assert c.message_encoding == "json", c.topic
            assert schema.encoding == "jsonschema", c.topic
            assert json.loads(schema.data)["type"] == "object"
            channels[c.topic] = schema.name
        messages = [
            (channel.topic, message.log_time, json.loads(message.data))
            for _, channel, message in reader.iter_messages(log_time_order=False)
        ]
        metadata = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
    return channels, messages, metadata


@pytest.fixture(scope="module")
def bench_run(tmp_path_factory):
    """A small benchmark recorded: the `straight` method on one robot, one synthetic and one
    corridor episode per scenario class."""
    tmp = tmp_path_factory.mktemp("record")
    robot = json.dumps(str(ROOT / "robots" / "diablo" / "robot.toml"))
    (tmp / "bench.toml").write_text(
        f"seed = 5\nrobots = [{robot}]\n\n"
        '[[methods]]\nname = "straight"\nkind = "straight"\n\n'
        '[[suites]]\nname = "synthetic"\nkind = "synthetic"\nper_class = 1\n\n'
        '[[suites]]\nname = "corridor"\nkind = "corridor"\nper_class = 1\n'
    )
    run(
        "bench", "--config", "bench.toml", "--out", "out", "--threads", "1", "--record",
        "--failures", "0", "--data-config", str(ROOT / "sdk" / "configs" / "data.toml"),
        cwd=tmp,
    )
    with open(tmp / "out" / "results.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    return tmp / "out", rows


def test_every_run_is_recorded_in_foxglove_schemas_with_its_outcome(bench_run):
    out, rows = bench_run
    files = sorted((out / "record").rglob("*.mcap"))
    assert len(files) == len(rows) == 8
    levels = {"success": 2, "timeout": 3, "collision": 4}
    for row in rows:
        safe = row["episode"].replace("/", "_")
        path = out / "record" / row["suite"] / row["robot"] / row["method"] / f"{safe}.mcap"
        channels, messages, metadata = read(path)
        assert channels == SCHEMAS
        count = Counter(topic for topic, _, _ in messages)
        # The robot at every step from 0 to the end, a plan at every replanning.
        steps = round(float(row["duration"]) / 0.05) + 1
        assert count["/tf"] == count["/robot/pose"] == steps, (path, count)
        assert count["/plan"] == int(row["plans"])
        assert count["/outcome"] == 1 + int(row["planner_errors"])
        # The run's row as metadata, the outcome as a log line at the end.
        assert metadata["run"]["outcome"] == row["outcome"]
        assert metadata["run"]["seed"] == row["seed"]
        assert float(metadata["run"]["path_length"]) == pytest.approx(float(row["path_length"]), abs=1e-6)
        end = [(t, m) for topic, t, m in messages if topic == "/outcome"][0]
        assert end[1]["level"] == levels[row["outcome"]]
        assert end[1]["message"].startswith(row["outcome"])
        assert end[0] == max(t for _, t, _ in messages)


def test_a_recorded_run_shows_the_robot_people_obstacles_goal_and_plans(bench_run):
    out, rows = bench_run
    row = next(r for r in rows if r["suite"] == "corridor")
    safe = row["episode"].replace("/", "_")
    _, messages, _ = read(out / "record" / "corridor" / row["robot"] / "straight" / f"{safe}.mcap")
    entities = {}
    for topic, t, m in messages:
        if topic.startswith("/scene"):
            for e in m["entities"]:
                assert ENTITY_TOPIC[e["id"]] == topic, (e["id"], topic)
                entities.setdefault(e["id"], []).append((t, e))
    # Once at the start: the footprint in the robot's frame, the goal and the walls.
    (t0, footprint), = entities["footprint"]
    assert t0 == 0 and footprint["frame_id"] == "base_link" and footprint["frame_locked"]
    assert footprint["cylinders"] or footprint["cubes"]
    (_, walls), = entities["obstacles"]
    assert walls["frame_id"] == "world" and (walls["lines"] or walls["cylinders"])
    (_, goal), = entities["goal"]
    assert len(goal["cylinders"]) == 1
    # People every step, as upright cylinders of their diameter.
    people = entities["pedestrians"]
    assert len(people) == round(float(row["duration"]) / 0.05) + 1
    assert any(e["cylinders"] for _, e in people)
    for _, e in people:
        for c in e["cylinders"]:
            assert c["size"]["x"] == c["size"]["y"] > 0 and c["size"]["z"] == pytest.approx(1.7)
    # Each plan as poses and as a line strip; the robot's frame follows its pose.
    plans = [m for topic, _, m in messages if topic == "/plan"]
    assert plans and all(len(p["poses"]) > 1 and p["frame_id"] == "world" for p in plans)
    assert len(entities["plan"]) == len(plans)
    tf = [m for topic, _, m in messages if topic == "/tf"]
    assert {(m["parent_frame_id"], m["child_frame_id"]) for m in tf} == {("world", "base_link")}
    for m in tf:
        q = m["rotation"]
        assert q["x"] ** 2 + q["y"] ** 2 + q["z"] ** 2 + q["w"] ** 2 == pytest.approx(1.0)
    times = [t for _, t, _ in messages]
    assert times == sorted(times)


def test_a_planning_call_is_recorded_with_its_candidates(tmp_path):
    run(
        "plan", "--robot", str(ROOT / "robots" / "diablo" / "robot.toml"),
        "--out", str(tmp_path / "plan.png"), "--record", str(tmp_path / "plan.mcap"),
        cwd=ROOT,
    )
    channels, messages, metadata = read(tmp_path / "plan.mcap")
    assert channels == SCHEMAS
    scene = {}
    for topic, _, m in messages:
        if topic.startswith("/scene"):
            for e in m["entities"]:
                assert ENTITY_TOPIC[e["id"]] == topic, (e["id"], topic)
                scene[e["id"]] = e
    candidates = int(metadata["plan"]["candidates"])
    assert candidates > 0 and len(scene["candidates"]["lines"]) == candidates
    assert len(scene["plan"]["lines"]) == 1
    # People with their recent positions.
    assert scene["pedestrians"]["cylinders"] and scene["pedestrians"]["lines"]
    (plan,) = [m for topic, _, m in messages if topic == "/plan"]
    assert len(plan["poses"]) == len(scene["plan"]["lines"][0]["points"])
