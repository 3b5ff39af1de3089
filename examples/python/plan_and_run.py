"""The Python package in a few lines: load a robot, plan one step past two pedestrians in a
corridor, compare with ORCA, then run one closed-loop benchmark episode and summarise it.

Install the package once, then run this from the repository root with that environment's
python3: either into any virtualenv, without torch (`pip install numpy sdk/python`), or with
`sdk/dev.sh python` into the torch virtualenv the SDK's tests use:

    ~/.cache/human2nav/torch-2.13.0/bin/python3 examples/python/plan_and_run.py
"""

import sys
from pathlib import Path

import numpy as np

import human2nav

ROOT = Path(__file__).resolve().parents[2]


def main() -> int:
    robot = human2nav.RobotProfile.load(ROOT / "robots" / "diablo" / "robot.toml")
    print(f"{robot.name}: {robot.embodiment}, footprint radius {robot.footprint_radius:.2f} m")
    for name, value, unit, source in robot.limit_table():
        shown = "none" if value is None else f"{value:.2f} {unit}"
        print(f"  {name:18} {shown:12} {source}")

    planner = human2nav.Human2NavPlanner(robot, ROOT / "models" / "human2nav-cfm")
    people = np.array([[2.5, 0.4, -1.0, 0.0, 0.3],     # x, y, vx, vy, radius
                       [3.5, -0.8, -0.8, 0.3, 0.3]])
    walls = [human2nav.Segment((-2, 1.6), (12, 1.6)), human2nav.Segment((-2, -1.6), (12, -1.6))]
    plan = planner.plan(ego=(0, 0, 0), goal=(5, 0), agents=people, obstacles=walls)
    end = plan.poses[-1]
    print(f"Human2Nav: {len(plan.poses)} poses over {plan.times[-1]:.1f} s, ends at "
          f"({end[0]:.2f}, {end[1]:.2f}); stages {plan.info['stages']}")

    quick = planner.plan(ego=(0, 0, 0), goal=(5, 0), agents=people, obstacles=walls,
                         budget_ms=5.0)
    print(f"within 5 ms: cut short in {quick.info['stages']['cut_short']}, "
          f"fallback {quick.info['fallback']}")

    orca = human2nav.OrcaPlanner(robot)
    first = orca.plan(ego=(0, 0, 0), goal=(5, 0), agents=people).poses[1]
    print(f"ORCA's first step: ({first[0]:.3f}, {first[1]:.3f})")

    result = human2nav.run_episode(planner, robot, index=1)   # an embedded synthetic episode
    m = result.metrics
    print(f"episode {result.episode_id}: {m['outcome']} after {m['duration']:.1f} s, "
          f"path {m['path_length']:.1f} m, TFS {m['tfs']:.3f}, "
          f"closest pedestrian {np.min(result.clearance):.2f} m")
    return 0 if np.all(np.isfinite(result.states)) else 1


if __name__ == "__main__":
    sys.exit(main())
