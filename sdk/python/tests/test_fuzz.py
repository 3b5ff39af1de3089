"""A bounded property test of the package's entry points: random and hostile values (NaN,
infinities, 1e300, integers too large for a float or a u64, huge arrays, wrong shapes and
dtypes, objects that are not numbers, None) into ``RobotProfile.load`` and
``RobotProfile.from_strings``, ``Human2NavPlanner(...)``, ``OrcaPlanner(...)``,
``Planner.plan(...)`` and ``run_episode(...)``.

Every call must return or raise ``ValueError``, ``TypeError``, ``FileNotFoundError`` or
``human2nav.Human2NavError`` (never an ``OverflowError``, nor a panic, which PyO3 raises as a
``BaseException`` that ``except Exception`` does not catch); every plan that comes back is
finite; and a valid call still works afterwards. Only the standard library's ``random``, with a
fixed seed, draws the inputs: the same cases every run.
"""

import math
import random
from pathlib import Path

import numpy as np
import pytest

import human2nav

ROOT = Path(__file__).resolve().parents[3]
DIABLO = ROOT / "robots" / "diablo" / "robot.toml"
MODEL = ROOT / "models" / "human2nav-cfm"
CONFIG = ROOT / "sdk" / "configs" / "planner.toml"

ALLOWED = (ValueError, TypeError, FileNotFoundError, human2nav.Human2NavError)

HOSTILE = [
    math.nan,
    math.inf,
    -math.inf,
    1e300,
    -1e300,
    5e-324,
    -0.0,
    10**400,
    -(10**400),
    2**64,
    -1,
    "x",
    "",
    None,
    object(),
    [],
    [1.0, 2.0],
    b"\x00",
    complex(1, 1),
    True,
    np.float32("nan"),
    np.array([np.nan]),
]


def call(what, f):
    """Runs ``f``; returns its result, or None when it raised an allowed error. Anything else
    fails the test with ``what`` (the arguments)."""
    try:
        return f()
    except ALLOWED:
        return None
    except KeyboardInterrupt:
        raise
    except BaseException as e:  # noqa: BLE001 (the point: a panic is a BaseException)
        pytest.fail(f"{what} raised {type(e).__module__}.{type(e).__name__}: {e}")


def number(rng):
    """Mostly an ordinary number, sometimes a hostile value."""
    if rng.random() < 0.25:
        return rng.choice(HOSTILE)
    return rng.uniform(-8.0, 8.0)


def vector(rng, n):
    """A vector of ``n`` numbers, or of the wrong length, shape or dtype, or not one at all."""
    roll = rng.random()
    if roll < 0.6:
        return tuple(number(rng) if rng.random() < 0.3 else rng.uniform(-5, 5) for _ in range(n))
    if roll < 0.7:
        return [rng.uniform(-5, 5) for _ in range(rng.choice([0, 1, n + 1, 1000]))]
    if roll < 0.8:
        return np.zeros((n, 2))
    if roll < 0.85:
        return np.array(["a"] * n)
    if roll < 0.9:
        return np.full(n, 1 + 1j)
    return rng.choice(HOSTILE)


def agents(rng):
    """An (n, 5) array, sometimes with hostile entries, of the wrong shape, dtype or size."""
    roll = rng.random()
    if roll < 0.1:
        return None
    n = rng.choice([0, 1, 3, 8, 20])
    rows = [
        [rng.uniform(-6, 6), rng.uniform(-6, 6), rng.uniform(-1.5, 1.5), rng.uniform(-1.5, 1.5),
         rng.uniform(0.1, 0.5)]
        for _ in range(n)
    ]
    if roll < 0.5:
        return np.array(rows).reshape(n, 5)
    if roll < 0.7 and n:
        rows[rng.randrange(n)][rng.randrange(5)] = rng.choice(HOSTILE)
        return rows
    if roll < 0.75:
        return np.zeros((n, 4))
    if roll < 0.8:
        return np.zeros((2, 5, 1))
    if roll < 0.85:
        return np.full((3, 5), "a")
    if roll < 0.9:
        # Huge: more pedestrians than any scene holds.
        return np.tile(np.array([[50.0, 50.0, 0.0, 0.0, 0.3]]), (20_000, 1))
    return rng.choice(HOSTILE)


def obstacles(rng):
    if rng.random() < 0.4:
        return None
    out = []
    for _ in range(rng.randrange(4)):
        kind = rng.randrange(5)
        if kind == 0:
            out.append(human2nav.Circle(vector(rng, 2), number(rng)))
        elif kind == 1:
            out.append(human2nav.Segment(vector(rng, 2), vector(rng, 2)))
        elif kind == 2:
            n = rng.choice([0, 2, 3, 5, 5000])
            v = np.array([[rng.uniform(-5, 5), rng.uniform(-5, 5)] for _ in range(min(n, 8))])
            if n > 8:
                v = np.resize(v, (n, 2))
            if n and rng.random() < 0.3:
                v = v.copy()
                v[0, 0] = rng.choice([math.nan, math.inf, 1e300])
            out.append(human2nav.Polygon(v))
        elif kind == 3:
            out.append(human2nav.Polygon(rng.choice(HOSTILE)))
        else:
            out.append(rng.choice(HOSTILE))
    return out


def occupancy(rng):
    roll = rng.random()
    if roll < 0.6:
        return None
    if roll < 0.65:
        return rng.choice(HOSTILE)
    shape = rng.choice([(4, 4), (0, 3), (3,), (2, 2, 2), (60, 60)])
    data = np.zeros(shape)
    if rng.random() < 0.3 and data.size:
        data.flat[0] = rng.choice([math.nan, 1e300, -500, 100])
    return human2nav.OccupancyGrid(
        data,
        number(rng) if rng.random() < 0.5 else 0.1,
        vector(rng, 3) if rng.random() < 0.3 else (-1.0, -1.0, 0.0),
        rng.choice([65, -1, 200, 10**30, math.inf]) if rng.random() < 0.3 else 65,
    )


def budget(rng):
    return rng.choice([0.0, 0.0, 0.0, 1.0, 5.0, 0.001, -1.0, math.nan, math.inf, 1e300, 10**400,
                       "x", None])


def assert_finite(plan):
    assert math.isfinite(plan.t0) and math.isfinite(plan.dt) and plan.dt > 0
    assert plan.poses.ndim == 2 and plan.poses.shape[1] == 3 and len(plan.poses) > 0
    assert np.isfinite(plan.poses).all(), plan.poses
    assert np.isfinite(plan.candidates).all() and np.isfinite(plan.guided).all()


def plans_ordinarily(planner):
    plan = planner.plan(ego=(0.0, 0.0, 0.0), goal=(4.0, 0.5),
                        agents=np.array([[2.0, 0.5, -0.8, 0.0, 0.3]]))
    assert_finite(plan)


@pytest.fixture(scope="module")
def robot():
    return human2nav.RobotProfile.load(DIABLO)


@pytest.fixture(scope="module")
def planner(robot):
    return human2nav.Human2NavPlanner(robot, MODEL, config=CONFIG)


def test_robot_profiles_from_bad_paths_and_texts(tmp_path):
    rng = random.Random(5101)
    text = DIABLO.read_text()
    garbage = tmp_path / "garbage.toml"
    garbage.write_bytes(bytes(rng.randrange(256) for _ in range(300)))
    paths = [tmp_path / "missing.toml", tmp_path, garbage, DIABLO.parent / "diablo.urdf", "",
             "a\0b", "x" * 5000, None, 3, b"robot.toml", Path("/"), object()]
    for p in paths:
        call(f"RobotProfile.load({p!r})", lambda: human2nav.RobotProfile.load(p))
    for _ in range(60):
        lines = text.splitlines()
        for _ in range(rng.randrange(1, 4)):
            k = rng.randrange(len(lines))
            lines[k] = rng.choice([
                "", "v_max = nan", "a_max = 1e300", "omega_max = -inf", "[limits]", "x = [[[",
                "kind = \"plugin\"", "urdf = \"/nonexistent.urdf\"", lines[k] * 2,
                "lateral_speed_max = 18446744073709551616", "\0",
            ])
        mutated = "\n".join(lines)
        urdf = rng.choice([None, "", "<robot/>", "<robot name='r'><link name='base_link'/></robot>"])
        call("RobotProfile.from_strings(mutated)",
             lambda: human2nav.RobotProfile.from_strings(mutated, urdf, source=str(DIABLO)))
    assert human2nav.RobotProfile.load(DIABLO).name == "diablo"


def test_planner_constructors_with_hostile_arguments(robot, tmp_path):
    rng = random.Random(5102)
    bad_config = tmp_path / "planner.toml"
    bad_config.write_text("[human2nav]\nsamples = nan\n")
    def pick(good, bad):
        # Each argument is hostile one time in six, so that some planners are made.
        return rng.choice(bad) if rng.random() < 1 / 6 else good

    ints = [-1, 2**64, 10**30, 1.5, math.nan, math.inf, "3", object()]
    for _ in range(40):
        args = dict(
            robot=pick(robot, HOSTILE),
            model_dir=pick(MODEL, [tmp_path, tmp_path / "none", bad_config, None, 3, "", "a\0b"]),
            config=pick(rng.choice([None, CONFIG]), [bad_config, tmp_path, tmp_path / "n", 7]),
            guidance=pick(rng.choice([None, True, False]), ["x", 1, math.nan]),
            seed=pick(rng.choice([None, 0, 7, 2**64 - 1]), ints),
            samples=pick(rng.choice([None, 1, 8]), ints + [0, 2000]),
            backend=pick(rng.choice([None, "native"]), ["torch", "x", "", 3]),
        )
        made = call(f"Human2NavPlanner({args})", lambda: human2nav.Human2NavPlanner(**args))
        if made is not None:
            plans_ordinarily(made)
    orca_configs = ["", "time_horizon = nan", "max_neighbors = -1", "neighbor_dist = 1e300",
                    "radius = inf", "max_speed = 18446744073709551616", "[[[", "x = 1", None, 3,
                    b"", "time_horizon = 0", "max_neighbors = 100000000"]
    for cfg in orca_configs:
        made = call(f"OrcaPlanner({cfg!r})", lambda: human2nav.OrcaPlanner(robot, cfg))
        if made is not None:
            plans_ordinarily(made)
    call("OrcaPlanner(None robot)", lambda: human2nav.OrcaPlanner(None))


@pytest.mark.parametrize("which", ["human2nav", "orca"])
def test_plans_from_hostile_observations_are_finite_or_refused(planner, robot, which):
    rng = random.Random(5103 if which == "human2nav" else 5104)
    p = planner if which == "human2nav" else human2nav.OrcaPlanner(robot)
    cases = 250 if which == "human2nav" else 150
    planned = refused = 0
    for k in range(cases):
        kwargs = dict(
            ego=vector(rng, 3),
            goal=vector(rng, 2),
            agents=agents(rng),
            ego_velocity=vector(rng, 3) if rng.random() < 0.5 else (0.0, 0.0, 0.0),
            time=number(rng) if rng.random() < 0.5 else 0.0,
            budget_ms=budget(rng) if rng.random() < 0.5 else 0.0,
            obstacles=obstacles(rng),
            occupancy=occupancy(rng),
        )
        if rng.random() < 0.1:
            kwargs["agent_ids"] = rng.choice([[-1], [2**64], [None], ["a"], [math.inf], [1, 2]])
        plan = call(f"plan case {k}", lambda: p.plan(**kwargs))
        if plan is None:
            refused += 1
        else:
            planned += 1
            assert_finite(plan)
        if k % 25 == 0:
            plans_ordinarily(p)
    plans_ordinarily(p)
    assert planned > 0 and refused > 0, (planned, refused)


def test_run_episode_with_hostile_arguments(robot, tmp_path):
    rng = random.Random(5105)
    orca = human2nav.OrcaPlanner(robot)
    garbage = tmp_path / "episodes.json"
    garbage.write_text('{"episodes": [{"id": 1}]}')
    for _ in range(30):
        args = dict(
            planner=orca if rng.random() < 0.85 else rng.choice(HOSTILE),
            robot=robot if rng.random() < 0.9 else rng.choice(HOSTILE),
            episodes=rng.choice([None] * 6 + [tmp_path / "none.json", tmp_path, garbage, 3]),
            index=rng.choice([0, 0, 1, 3, -1, 2**64, 10**6, math.inf, math.nan, 1.5, "0", None]),
            episode_id=rng.choice([None] * 5 + ["", "nope", 3]),
            crowd=rng.choice(["replay", "replay", "reactive", "", "x", None]),
            # A high rate makes each episode that runs take long; hostile ones are refused.
            replan_hz=rng.choice([2.0, 5.0, 0.0, -1.0, math.nan, math.inf, 1e300, 1e-300, "x",
                                  10**400]),
        )
        result = call(f"run_episode({args})", lambda: human2nav.run_episode(**args))
        if result is not None:
            assert np.isfinite(result.states).all() and np.isfinite(result.commands).all()
    result = human2nav.run_episode(orca, robot, replan_hz=2.0)
    assert result.states.shape[1] == 6
