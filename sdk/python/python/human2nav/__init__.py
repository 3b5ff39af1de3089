"""Crowd-navigation planning learned from human trajectories, from Python.

Load a robot, build the Human2Nav planner (or ORCA), plan from numpy arrays, run one episode of
the closed-loop benchmark::

    import numpy as np
    import human2nav

    robot = human2nav.RobotProfile.load("robots/diablo/robot.toml")
    planner = human2nav.Human2NavPlanner(robot, "models/human2nav-cfm")
    people = np.array([[2.5, 0.4, -1.0, 0.0, 0.3]])          # x, y, vx, vy, radius
    plan = planner.plan(ego=(0, 0, 0), goal=(5, 0), agents=people)
    plan.poses                                                 # (T + 1, 3): x, y, theta

    result = human2nav.run_episode(planner, robot)             # an embedded synthetic episode
    result.metrics["success"], result.states[:, :2]

Units are SI. Poses, goals and pedestrians are in one world-fixed frame; the robot's velocity is
in its body frame (forward, leftward, yaw rate). Bad arguments raise ``ValueError`` (a missing
file ``FileNotFoundError``); other failures of the SDK raise :class:`Human2NavError`.

A plain build (``pip install sdk/python`` or ``pip wheel sdk/python``) needs no torch: the
planner runs its network on the SDK's own kernels. Built with the ``torch`` feature
(``sdk/dev.sh python``), the package also offers ``backend="torch"`` and links the libtorch of
the torch 2.13 installation it was built against, so it works in the same process as
``import torch``, before or after it. Asking a plain build for the torch backend raises
``ValueError`` saying how to get it.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Dict, List, Optional, Sequence, Tuple, Union

import numpy as np

from ._human2nav import Human2NavError, RobotProfile, version
from ._human2nav import Planner as _NativePlanner
from ._human2nav import run_episode as _run_episode

__all__ = [
    "Circle",
    "EpisodeResult",
    "Human2NavError",
    "Human2NavPlanner",
    "OccupancyGrid",
    "OrcaPlanner",
    "Plan",
    "Polygon",
    "Planner",
    "RobotProfile",
    "Segment",
    "run_episode",
    "version",
]

__version__ = version()

PathLike = Union[str, Path]
ArrayLike = Union[np.ndarray, Sequence[Sequence[float]]]


@dataclass(frozen=True)
class Circle:
    """A round static obstacle (a pillar, a bin), world frame."""

    center: Tuple[float, float]
    radius: float

    def _json(self) -> Dict[str, Any]:
        return {
            "kind": "circle",
            "center": _point(self.center),
            "radius": _float("Circle radius", self.radius),
        }


@dataclass(frozen=True)
class Polygon:
    """A static obstacle bounded by a simple polygon (a table, a parked cart), world frame."""

    vertices: ArrayLike
    """``(n, 2)``, n ≥ 3, either orientation."""

    def _json(self) -> Dict[str, Any]:
        v = _array("Polygon vertices", self.vertices)
        if v.ndim != 2 or v.shape[1] != 2:
            raise ValueError(f"Polygon vertices must be an (n, 2) array, got shape {v.shape}")
        return {"kind": "polygon", "vertices": v.tolist()}


@dataclass(frozen=True)
class Segment:
    """A wall or railing from ``a`` to ``b`` (no thickness), world frame."""

    a: Tuple[float, float]
    b: Tuple[float, float]

    def _json(self) -> Dict[str, Any]:
        return {"kind": "segment", "a": _point(self.a), "b": _point(self.b)}


@dataclass(frozen=True)
class OccupancyGrid:
    """A static map in the layout of ``nav_msgs/OccupancyGrid``: ``data`` is ``(height, width)``
    with −1 unknown (treated as free), 0 free to 100 occupied; cell ``(row, col)`` covers
    ``[col, col + 1) × [row, row + 1)`` cells of ``resolution`` metres from ``origin``
    (``x, y, theta`` of the corner of cell ``(0, 0)`` in the world frame)."""

    data: np.ndarray
    resolution: float
    origin: Tuple[float, float, float] = (0.0, 0.0, 0.0)
    occupied_threshold: int = 65

    def _json(self) -> Dict[str, Any]:
        grid = np.asarray(self.data)
        if grid.ndim != 2:
            raise ValueError(f"OccupancyGrid data must be 2-D (height, width), got {grid.shape}")
        if grid.size and not np.isfinite(grid).all():
            raise ValueError("OccupancyGrid data must be finite (-1, 0 … 100)")
        if grid.size and (grid.min() < -128 or grid.max() > 127):
            raise ValueError("OccupancyGrid data must fit in int8 (-1, 0 … 100)")
        x, y, theta = _vector("origin", self.origin, 3)
        return {
            "origin": {"x": x, "y": y, "theta": theta},
            "resolution": _float("OccupancyGrid resolution", self.resolution),
            "width": int(grid.shape[1]),
            "height": int(grid.shape[0]),
            "data": grid.astype(np.int64).ravel().tolist(),
            "occupied_threshold": _integer(
                "OccupancyGrid occupied_threshold", self.occupied_threshold
            ),
        }


Obstacle = Union[Circle, Polygon, Segment]


def _point(p: Sequence[float]) -> List[float]:
    return list(_vector("point", p, 2))


def _scene(
    obstacles: Optional[Sequence[Obstacle]], occupancy: Optional[OccupancyGrid]
) -> Optional[str]:
    if not obstacles and occupancy is None:
        return None
    items = []
    for i, o in enumerate(obstacles or ()):
        if not isinstance(o, (Circle, Polygon, Segment)):
            raise TypeError(f"obstacles[{i}] must be a Circle, Polygon or Segment, got {o!r}")
        items.append(o._json())
    scene: Dict[str, Any] = {"obstacles": items}
    if occupancy is not None:
        if not isinstance(occupancy, OccupancyGrid):
            raise TypeError("occupancy must be a human2nav.OccupancyGrid")
        scene["occupancy"] = occupancy._json()
    return json.dumps(scene, allow_nan=True)


@dataclass(frozen=True)
class Plan:
    """A planned trajectory in the world frame and the planner's diagnostics."""

    t0: float
    """Time of the first pose (the observation's time), s."""
    dt: float
    """Time between poses, s."""
    poses: np.ndarray
    """``(T + 1, 3)``: ``x, y, theta`` at ``t0 + k * dt``; row 0 is the robot's pose."""
    candidates: np.ndarray
    """``(K, T + 1, 3)``: the flow model's samples before guidance (empty for ORCA)."""
    guided: np.ndarray
    """``(G, T + 1, 3)``: the guided samples (empty when guidance is off)."""
    info: Dict[str, Any]
    """``selected``, ``phi_before``, ``phi_after``, ``guidance_iterations``, ``fallback``,
    ``notes``, ``warnings`` (the robot started inside an obstacle or beyond its limits) and
    ``stages`` (how far sampling, guidance and correction got, as ``(done, planned)``, and
    which stage a budget cut short)."""

    @property
    def times(self) -> np.ndarray:
        """The time of every pose, s."""
        return self.t0 + self.dt * np.arange(len(self.poses))


def _trajectories(value: List[List[Tuple[float, float, float]]]) -> np.ndarray:
    if not value:
        return np.zeros((0, 0, 3))
    return np.asarray(value, dtype=np.float64)


def _float(name: str, value: Any) -> float:
    """``float(value)``; an integer too large for a float is a ``ValueError`` naming ``name``
    (Python raises ``OverflowError``)."""
    try:
        return float(value)
    except OverflowError:
        raise ValueError(f"{name} is too large for a float") from None


def _integer(name: str, value: Any) -> int:
    """``int(value)``; an infinite float is a ``ValueError`` naming ``name`` (Python raises
    ``OverflowError``)."""
    try:
        return int(value)
    except OverflowError:
        raise ValueError(f"{name} must be an integer, got {value!r}") from None


def _unsigned(name: str, value: Any) -> int:
    """``int(value)`` checked to fit the SDK's unsigned 64-bit integers (a seed, a count, an
    index, an id): out of range, or infinite, is a ``ValueError`` naming ``name``."""
    number = _integer(name, value)
    if not 0 <= number < 2**64:
        raise ValueError(f"{name} must be an integer in 0 … 2^64 − 1, got {value!r}")
    return number


def _array(name: str, value: Any) -> np.ndarray:
    """``value`` as a float64 array; complex numbers are a ``TypeError`` (numpy would drop their
    imaginary part) and an integer too large for a float a ``ValueError``."""
    if np.iscomplexobj(value):
        raise TypeError(f"{name} holds complex numbers")
    try:
        return np.asarray(value, dtype=np.float64)
    except OverflowError:
        raise ValueError(f"{name} holds a number too large for a float") from None


def _vector(name: str, value: Sequence[float], n: int) -> Tuple[float, ...]:
    array = _array(name, value)
    if array.shape != (n,):
        raise ValueError(f"{name} must hold {n} numbers, got shape {array.shape}")
    return tuple(float(v) for v in array)


def _agents(agents: Optional[ArrayLike], ids: Optional[Sequence[int]]) -> List[Tuple[Any, ...]]:
    if agents is None:
        return []
    array = _array("agents", agents)
    if array.size == 0:
        return []
    if array.ndim != 2 or array.shape[1] != 5:
        raise ValueError(
            "agents must be an (n, 5) array of x, y, vx, vy, radius per pedestrian, "
            f"got shape {array.shape}"
        )
    if ids is None:
        ids = range(len(array))
    ids = [_unsigned(f"agent_ids[{k}]", i) for k, i in enumerate(ids)]
    if len(ids) != len(array):
        raise ValueError(f"agent_ids holds {len(ids)} ids for {len(array)} agents")
    return [(i, *map(float, row)) for i, row in zip(ids, array)]


class Planner:
    """A planner behind the SDK's planner interface; see :class:`Human2NavPlanner` and
    :class:`OrcaPlanner`."""

    def __init__(self, native: _NativePlanner) -> None:
        self._native = native

    @property
    def name(self) -> str:
        """``human2nav`` or ``orca``."""
        return self._native.name

    def reset(self) -> None:
        """Forgets the previous plan: call it at the start of a new navigation task."""
        self._native.reset()

    def plan(
        self,
        ego: Sequence[float],
        goal: Sequence[float],
        agents: Optional[ArrayLike] = None,
        ego_velocity: Sequence[float] = (0.0, 0.0, 0.0),
        time: float = 0.0,
        agent_ids: Optional[Sequence[int]] = None,
        budget_ms: float = 0.0,
        obstacles: Optional[Sequence[Obstacle]] = None,
        occupancy: Optional[OccupancyGrid] = None,
    ) -> Plan:
        """Plans from one observation.

        ``ego`` is the robot's ``(x, y, theta)``, ``goal`` its ``(x, y)``, ``agents`` an
        ``(n, 5)`` array of ``x, y, vx, vy, radius`` per pedestrian (ids ``0 … n − 1`` unless
        ``agent_ids`` gives stable tracker ids), ``ego_velocity`` the body-frame
        ``(vx, vy, omega)``. ``budget_ms > 0`` bounds the call: the best plan found by then,
        always a feasible one (Human2Nav only). ``obstacles`` (:class:`Circle`,
        :class:`Polygon`, :class:`Segment`) and ``occupancy`` (:class:`OccupancyGrid`) are the
        static scene; Human2Nav's selection keeps its candidates off them, ORCA ignores them.
        """
        raw = self._native.plan(
            _float("time", time),
            _vector("ego", ego, 3),
            _vector("ego_velocity", ego_velocity, 3),
            _vector("goal", goal, 2),
            _agents(agents, agent_ids),
            _float("budget_ms", budget_ms),
            _scene(obstacles, occupancy),
        )
        info = {k: raw[k] for k in (
            "selected", "phi_before", "phi_after", "guidance_iterations", "fallback", "notes",
            "warnings", "stages",
        )}
        return Plan(
            t0=raw["t0"],
            dt=raw["dt"],
            poses=np.asarray(raw["poses"], dtype=np.float64),
            candidates=_trajectories(raw["candidates"]),
            guided=_trajectories(raw["guided"]),
            info=info,
        )


class Human2NavPlanner(Planner):
    """The Human2Nav planner: flow-matching samples, feasibility guidance (Algorithm 1), the
    last-step correction and the selection.

    ``model_dir`` is a model folder (``model.toml`` and its weights); ``config`` a
    ``planner.toml`` (None: the built-in defaults, equal to the shipped
    ``sdk/configs/planner.toml``; a ``[prediction]`` model it names is loaded, a relative path
    from the current directory). ``guidance=True`` runs Algorithm 1 (the shipped
    planner does not) and switches nothing else;
    ``seed``, ``samples`` and ``backend`` (``"native"``, or ``"torch"`` in a build with the
    ``torch`` feature) override the configuration.
    """

    def __init__(
        self,
        robot: RobotProfile,
        model_dir: PathLike,
        config: Optional[PathLike] = None,
        guidance: Optional[bool] = None,
        seed: Optional[int] = None,
        samples: Optional[int] = None,
        backend: Optional[str] = None,
    ) -> None:
        super().__init__(
            _NativePlanner.human2nav(
                robot,
                Path(model_dir),
                None if config is None else Path(config),
                guidance,
                None if seed is None else _unsigned("seed", seed),
                None if samples is None else _unsigned("samples", samples),
                backend,
            )
        )


class OrcaPlanner(Planner):
    """ORCA with RVO2's semantics. ``config`` is the TOML text of its settings (RVO2 names:
    ``neighbor_dist``, ``max_neighbors``, ``time_horizon``, ...); the robot's footprint radius
    and ``v_max`` are used for ``radius`` and ``max_speed`` unless it sets them."""

    def __init__(self, robot: RobotProfile, config: Optional[str] = None) -> None:
        super().__init__(_NativePlanner.orca(robot, config))


@dataclass(frozen=True)
class EpisodeResult:
    """One closed-loop episode."""

    episode_id: str
    metrics: Dict[str, Any]
    """``outcome``, ``success``, ``collision``, ``timeout``, ``tfs``, ``path_length``,
    ``time_to_goal``, ``min_clearance``, ``plans``, ``fallbacks``, ... (the benchmark's
    per-run metrics)."""
    states: np.ndarray
    """``(N + 1, 6)``: ``x, y, theta, vx, vy, omega`` of the robot every simulation step."""
    commands: np.ndarray
    """``(N, 3)``: the executed body-frame commands ``vx, vy, omega``."""
    clearance: np.ndarray
    """``(N + 1,)``: the smallest footprint-to-pedestrian distance, m (inf with nobody near)."""


def run_episode(
    planner: Planner,
    robot: RobotProfile,
    episodes: Optional[PathLike] = None,
    index: int = 0,
    episode_id: Optional[str] = None,
    crowd: str = "replay",
    replan_hz: float = 10.0,
) -> EpisodeResult:
    """Runs one benchmark episode closed loop with ``planner`` driving ``robot``.

    ``episodes`` is an episode file (``human2nav data episodes``; None: the embedded synthetic
    episodes, one per scenario class); ``index`` or ``episode_id`` picks the episode; ``crowd``
    is ``"replay"`` (the recording as it walked) or ``"reactive"`` (pedestrians that respond to
    the robot). The simulator steps at 20 Hz and replans at ``replan_hz``.
    """
    if not isinstance(planner, Planner):
        raise TypeError("planner must be a human2nav.Planner (Human2NavPlanner, OrcaPlanner)")
    ident, metrics, states, commands, clearance = _run_episode(
        planner._native,
        robot,
        None if episodes is None else Path(episodes),
        _unsigned("index", index),
        episode_id,
        crowd,
        _float("replan_hz", replan_hz),
    )
    return EpisodeResult(
        episode_id=ident,
        metrics=json.loads(metrics),
        states=np.asarray(states, dtype=np.float64).reshape(-1, 6),
        commands=np.asarray(commands, dtype=np.float64).reshape(-1, 3),
        clearance=np.asarray(clearance, dtype=np.float64),
    )
