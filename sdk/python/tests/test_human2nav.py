"""The Python package: robot profiles, both planners from numpy arrays, one closed-loop episode,
bad input, and living in one process with torch."""

import math
import re
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

import human2nav

ROOT = Path(__file__).resolve().parents[3]
DIABLO = ROOT / "robots" / "diablo" / "robot.toml"
MODEL = ROOT / "models" / "human2nav-cfm"
CONFIG = ROOT / "sdk" / "configs" / "planner.toml"
PEOPLE = np.array([[2.5, 0.4, -1.0, 0.0, 0.3], [3.5, -0.8, -0.8, 0.3, 0.3]])


def shipped_setting(key):
    """An integer setting of the shipped planner.toml (`key = N` at the start of a line)."""
    match = re.search(rf"^{key} = (\d+)", CONFIG.read_text(), re.MULTILINE)
    assert match, f"{CONFIG} has no `{key}`"
    return int(match.group(1))


@pytest.fixture(scope="module")
def robot():
    return human2nav.RobotProfile.load(DIABLO)


@pytest.fixture(scope="module")
def planner(robot):
    return human2nav.Human2NavPlanner(robot, MODEL, config=CONFIG)


def test_a_robot_profile_reports_its_limits_and_where_they_came_from(robot):
    assert robot.name == "diablo"
    assert robot.embodiment == "differential_drive"
    assert not robot.holonomic
    assert 0.1 < robot.footprint_radius < 1.0
    limits = robot.limits
    assert limits["v_max"] > 0 and limits["a_max"] > 0
    assert limits["kappa_max"] is None
    names = [row[0] for row in robot.limit_table()]
    assert "v_max" in names and all(len(row) == 4 for row in robot.limit_table())


def test_a_profile_and_urdf_given_as_text_load_like_the_files(robot):
    text = DIABLO.read_text()
    urdf = (DIABLO.parent / "diablo.urdf").read_text()
    same = human2nav.RobotProfile.from_strings(text, urdf, source="/param_server/robot.toml")
    assert same.limits == robot.limits
    assert same.footprint_radius == robot.footprint_radius


def test_human2nav_plans_from_numpy_arrays(planner):
    plan = planner.plan(ego=(1.0, 2.0, 0.3), goal=(6.0, 2.0), agents=PEOPLE)
    assert plan.poses.shape == (33, 3)
    assert np.all(np.isfinite(plan.poses))
    np.testing.assert_allclose(plan.poses[0], [1.0, 2.0, 0.3])
    assert plan.dt == pytest.approx(0.1)
    assert plan.times[-1] == pytest.approx(3.2)
    assert plan.candidates.shape == (shipped_setting("samples"), 33, 3)
    # The shipped planner runs no Algorithm 1: no guided samples.
    assert plan.guided.shape[0] == 0
    assert not plan.info["fallback"]
    stages = plan.info["stages"]
    assert stages["sampling"] == (5, 5) and stages["cut_short"] is None


def test_the_same_seed_gives_the_same_plan_and_guidance_can_be_turned_on(robot, planner):
    planner.reset()
    a = planner.plan(ego=(0, 0, 0), goal=(5, 0), agents=PEOPLE)
    planner.reset()
    b = planner.plan(ego=(0, 0, 0), goal=(5, 0), agents=PEOPLE)
    np.testing.assert_array_equal(a.poses, b.poses)
    # The shipped planner runs no Algorithm 1; guidance=True switches it on, nothing else.
    assert a.guided.shape[0] == 0 and a.info["guidance_iterations"] is None
    on = human2nav.Human2NavPlanner(robot, MODEL, guidance=True)
    assert on.name == "human2nav"
    plan = on.plan(ego=(0, 0, 0), goal=(5, 0), agents=PEOPLE)
    assert plan.guided.shape[0] > 0 and plan.info["guidance_iterations"] is not None


def test_a_budget_cuts_the_call_short_and_the_plan_stays_finite(planner):
    planner.reset()
    plan = planner.plan(ego=(0, 0, 0), goal=(5, 0), agents=PEOPLE, budget_ms=0.001)
    stages = plan.info["stages"]
    assert stages["cut_short"] == "sampling"
    assert np.all(np.isfinite(plan.poses))
    assert not plan.info["fallback"]


def test_orca_plans_from_the_same_observation(robot):
    orca = human2nav.OrcaPlanner(robot, "time_horizon = 3.0")
    plan = orca.plan(ego=(0, 0, 0), goal=(5, 0), agents=PEOPLE, agent_ids=[7, 9])
    assert orca.name == "orca"
    assert plan.poses.shape[1] == 3 and len(plan.poses) > 1
    assert np.all(np.isfinite(plan.poses))
    assert plan.candidates.shape == (0, 0, 3)


def test_one_episode_runs_closed_loop_with_either_planner(robot, planner):
    for p in (planner, human2nav.OrcaPlanner(robot)):
        result = human2nav.run_episode(p, robot, index=1)
        m = result.metrics
        assert m["outcome"] in ("success", "collision", "timeout")
        assert 0.0 <= m["tfs"] <= 1.0
        assert result.states.shape[1] == 6 and len(result.states) == len(result.clearance)
        assert result.commands.shape == (len(result.states) - 1, 3)
        assert np.all(np.isfinite(result.states))
        np.testing.assert_allclose(result.states[-1, :2], result.states[-1, :2])
    reactive = human2nav.run_episode(planner, robot, index=0, crowd="reactive")
    assert reactive.episode_id


def test_bad_input_is_a_clear_error(robot, planner, tmp_path):
    with pytest.raises(ValueError, match="goal"):
        planner.plan(ego=(0, 0, 0), goal=(math.nan, 0), agents=PEOPLE)
    with pytest.raises(ValueError, match=r"\(n, 5\)"):
        planner.plan(ego=(0, 0, 0), goal=(5, 0), agents=np.zeros((2, 4)))
    with pytest.raises(ValueError, match="ego must hold 3 numbers"):
        planner.plan(ego=(0, 0), goal=(5, 0))
    with pytest.raises(ValueError, match="agent 1"):
        planner.plan(ego=(0, 0, 0), goal=(5, 0), agents=[[1, 1, 0, 0, -0.3]], agent_ids=[1])
    with pytest.raises(ValueError, match="ego pose is more than"):
        planner.plan(ego=(1e300, 0, 0), goal=(5, 0))
    for budget in (-1, 1e22, float("nan")):
        with pytest.raises(ValueError, match="budget_ms"):
            planner.plan(ego=(0, 0, 0), goal=(5, 0), budget_ms=budget)
    bad = tmp_path / "planner.toml"
    bad.write_text("[human2nav]\nsamplez = 4\n")
    with pytest.raises(ValueError, match="samplez"):
        human2nav.Human2NavPlanner(robot, MODEL, config=bad)
    with pytest.raises(ValueError, match="backend"):
        human2nav.Human2NavPlanner(robot, MODEL, backend="gpu")
    with pytest.raises(human2nav.Human2NavError, match="no-such-model"):
        human2nav.Human2NavPlanner(robot, ROOT / "models" / "no-such-model")
    with pytest.raises(FileNotFoundError):
        human2nav.RobotProfile.load(tmp_path / "missing.toml")
    with pytest.raises(ValueError, match="urdf"):
        human2nav.RobotProfile.from_strings(DIABLO.read_text(), "<robot")
    with pytest.raises(ValueError, match="unknown field"):
        human2nav.OrcaPlanner(robot, "neighbour_dist = 3")
    with pytest.raises(ValueError, match="crowd"):
        human2nav.run_episode(planner, robot, crowd="panicking")
    with pytest.raises(ValueError, match="episode"):
        human2nav.run_episode(planner, robot, index=99)


@pytest.mark.parametrize("torch_first", [True, False])
def test_it_shares_a_process_and_libtorch_with_torch(torch_first):
    torch = pytest.importorskip("torch")
    assert torch.__version__.split("+")[0] == "2.13.0"
    imports = ["import torch", "import human2nav"]
    if not torch_first:
        imports.reverse()
    script = "\n".join(imports) + textwrap.dedent(
        f"""
        import numpy as np
        robot = human2nav.RobotProfile.load({str(DIABLO)!r})
        planner = human2nav.Human2NavPlanner(robot, {str(MODEL)!r}, backend="torch")
        plan = planner.plan(ego=(0, 0, 0), goal=(5, 0), agents=np.array([[2, 0.5, -1, 0, 0.3]]))
        assert np.all(np.isfinite(plan.poses)) and not plan.info["fallback"]
        x = torch.randn(64, 64)
        assert torch.allclose(x @ torch.eye(64), x)
        print("ok", torch.__version__)
        """
    )
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True)
    assert out.returncode == 0, out.stdout + out.stderr
    assert out.stdout.startswith("ok 2.13.0")


def test_obstacles_and_occupancy_keep_the_plan_off_a_wall(robot, planner):
    planner.reset()
    free = planner.plan(ego=(0, 0, 0), goal=(5, 0))
    assert free.poses[:, 0].max() > 1.2, "without the wall the plan runs where it would be"
    planner.reset()
    walled = planner.plan(
        ego=(0, 0, 0), goal=(5, 0), obstacles=[human2nav.Segment((1.2, -5), (1.2, 5))]
    )
    assert walled.poses[:, 0].max() < 1.2
    grid = np.zeros((100, 60), dtype=np.int8)
    grid[:, 32] = 100                       # x from 1.2 to 1.3 with the origin at (-2, -5)
    planner.reset()
    mapped = planner.plan(
        ego=(0, 0, 0),
        goal=(5, 0),
        occupancy=human2nav.OccupancyGrid(grid, 0.1, origin=(-2.0, -5.0, 0.0)),
        obstacles=[human2nav.Circle((0, 3), 0.5), human2nav.Polygon([[3, 3], [4, 3], [4, 4]])],
    )
    assert mapped.poses[:, 0].max() < 1.2
    with pytest.raises(ValueError, match="obstacles"):
        planner.plan(ego=(0, 0, 0), goal=(5, 0), obstacles=[human2nav.Polygon([[0, 0], [1, 0]])])
    with pytest.raises(ValueError, match="occupancy"):
        bad = human2nav.OccupancyGrid(grid, -0.1)
        planner.plan(ego=(0, 0, 0), goal=(5, 0), occupancy=bad)
    with pytest.raises(TypeError):
        planner.plan(ego=(0, 0, 0), goal=(5, 0), obstacles=[(1, 2)])


def test_the_python_example_runs():
    example = ROOT / "examples" / "python" / "plan_and_run.py"
    out = subprocess.run([sys.executable, str(example)], capture_output=True, text=True)
    assert out.returncode == 0, out.stdout + out.stderr
    assert "Human2Nav: 33 poses" in out.stdout
    assert "episode " in out.stdout
