"""Type stubs of the native module ``human2nav._human2nav`` (use the package ``human2nav``)."""

from pathlib import Path
from typing import Any, Dict, List, Optional, Tuple

Pose = Tuple[float, float, float]

class Human2NavError(RuntimeError):
    """An error of the SDK that is not a bad argument."""

class RobotProfile:
    """A robot: its profile (``robot.toml`` + URDF) and its embodiment."""

    @staticmethod
    def load(path: str | Path) -> RobotProfile: ...
    @staticmethod
    def from_strings(
        robot_toml: str, urdf: Optional[str] = None, source: str = "robot.toml"
    ) -> RobotProfile: ...
    @property
    def name(self) -> str: ...
    @property
    def embodiment(self) -> str: ...
    @property
    def holonomic(self) -> bool: ...
    @property
    def footprint_radius(self) -> float: ...
    @property
    def limits(self) -> Dict[str, Optional[float]]: ...
    def limit_table(self) -> List[Tuple[str, Optional[float], str, str]]: ...

class Planner:
    """A planner (Human2Nav or ORCA) behind the SDK's planner interface."""

    @staticmethod
    def human2nav(
        robot: RobotProfile,
        model_dir: str | Path,
        config: Optional[str | Path] = None,
        guidance: Optional[bool] = None,
        seed: Optional[int] = None,
        samples: Optional[int] = None,
        backend: Optional[str] = None,
    ) -> Planner: ...
    @staticmethod
    def orca(robot: RobotProfile, config: Optional[str] = None) -> Planner: ...
    @property
    def name(self) -> str: ...
    def reset(self) -> None: ...
    def plan(
        self,
        time: float,
        ego: Pose,
        ego_velocity: Pose,
        goal: Tuple[float, float],
        agents: List[Tuple[int, float, float, float, float, float]],
        budget_ms: float = 0.0,
        scene: Optional[str] = None,
    ) -> Dict[str, Any]: ...

def run_episode(
    planner: Planner,
    robot: RobotProfile,
    episodes: Optional[str | Path] = None,
    index: int = 0,
    episode_id: Optional[str] = None,
    crowd: str = "replay",
    replan_hz: float = 10.0,
) -> Tuple[
    str,
    str,
    List[Tuple[float, float, float, float, float, float]],
    List[Pose],
    List[float],
]: ...
def version() -> str: ...
