"""BARN, the Benchmark for Autonomous Robot Navigation, read from its own files and scored
its way (``scenario=barn``).

BARN (Perille, Truong, Xiao, Stone, "Benchmarking Metric Ground Navigation", IEEE SSRR 2020;
the ICRA BARN Challenge) is 300 worlds of a robot crossing a field of static cylinders. A
world is the challenge's Gazebo file ``world_N.world`` (SDF: one ``unit_cylinder_*`` model of
radius 0.075 m per occupied cell of a 30 x 30 grid of 0.15 m cells, and a containment
corridor before the field) with its A* path ``path_files/path_N.npy`` (grid cells ``(r, c)``;
cell ``(r, c)`` is at ``x = -4.425 + 0.15 r``, ``y = 5.175 + 0.15 c`` in Gazebo's frame).
The robot (a Clearpath Jackal, 0.43 m wide, 2 m/s) starts at (-2.25, 3.0) facing +y; the goal
is 10 m further in +y. A run succeeds within 1 m of the goal, without a collision, before
100 s; its score is ``success * OT / clip(T, 2 OT, 8 OT)``, ``T`` the traversal time and
``OT`` the optimal time: the length of the A* path (from the start, through its cells, to the
goal) over the top speed.

Here the world is placed for the plant at ``scale`` (Gazebo metres to the plant's; default
0.25, about the Zumo's 0.10 m against the Jackal's 0.43 m): positions and radii times
``scale``, the success radius too; times by ``scale * 2 / top_speed`` (the plant's top speed
against the Jackal's 2 m/s), the time limit and ``OT`` alike, so the score compares as the
challenge's does. A run that stalls is a time-out for the score (the challenge would have run
on to its limit).
"""

from __future__ import annotations

import itertools
import math
import xml.etree.ElementTree as ET
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional

import numpy as np

from mpclab.config.registry import component
from mpclab.config.root import CONF_DIR
from mpclab.core.errors import ConfigError, number
from mpclab.plants.base import FloatArray, Plant
from mpclab.world.sensor import SensorConf
from mpclab.world.zumo_world import ObstacleScenario, StallConf

#: the challenge's facts, in Gazebo metres and seconds
CELL = 0.15
CYLINDER_RADIUS = 0.075
START = (-2.25, 3.0)
GOAL = (-2.25, 13.0)
SUCCESS_RADIUS = 1.0
TIME_LIMIT = 100.0
JACKAL_SPEED = 2.0
#: the challenge's test worlds (its ``test.sh``): held out, refused unless asked for
TEST_WORLDS = frozenset(range(0, 300, 6))
#: the training worlds: every other index
TRAIN_WORLDS = tuple(n for n in range(300) if n not in TEST_WORLDS)
#: the shipped worlds' folder (three training worlds and the licence), relative to conf/
SHIPPED = "barn"


@dataclass(frozen=True)
class BarnWorld:
    """One BARN world in Gazebo's frame: its cylinders and its A* path."""

    index: int
    #: cylinders ``(n, 3)``: centre x, centre y, radius [m]
    cylinders: FloatArray
    #: the A* path ``(m, 2)`` [m], from the start through the path's cells to the goal
    path: FloatArray

    @property
    def path_length(self) -> float:
        """The A* path's length [m], as the challenge measures it."""
        return float(np.sum(np.linalg.norm(np.diff(self.path, axis=0), axis=1)))


def read_world(barn_dir: str | Path, index: int) -> BarnWorld:
    """World ``index`` of the BARN folder ``barn_dir`` (``world_N.world`` and
    ``path_files/path_N.npy``; a relative folder from the working folder, else from the
    config folder); :class:`ConfigError` naming the file for one that is missing, truncated
    or not a BARN world."""
    given = Path(str(barn_dir)).expanduser()
    folder = next((f for f in (given, CONF_DIR / given) if f.is_dir()), None)
    if folder is None:
        raise ConfigError(f"scenario.barn_dir: no folder {str(given)!r} (unpack the BARN "
                          "worlds there: world_N.world and path_files/path_N.npy)")
    return BarnWorld(index, _cylinders(folder / f"world_{index}.world"),
                     _path(folder / "path_files" / f"path_{index}.npy"))


def _cylinders(file: Path) -> FloatArray:
    if not file.is_file():
        raise ConfigError(f"scenario.world: no world file {str(file)!r}")
    try:
        root = ET.parse(file).getroot()
    except ET.ParseError as exc:
        raise ConfigError(f"scenario.world: {str(file)!r} is not a complete SDF file "
                          f"({exc})") from None
    world = root.find("world") if root.tag == "sdf" else None
    if world is None:
        raise ConfigError(f"scenario.world: {str(file)!r} is not a Gazebo SDF world "
                          f"(root <{root.tag}>, no <world>)")
    # the world's saved state places its models where Gazebo loads them (in BARN's files the
    # same poses as the models' own)
    placed = {m.get("name"): m.find("pose") for m in world.findall("state/model")}
    found = []
    for model in world.findall("model"):
        radius = model.find("link/collision/geometry/cylinder/radius")
        if radius is None:
            continue
        pose = placed.get(model.get("name"))
        pose = model.find("pose") if pose is None else pose
        if pose is None or pose.text is None or radius.text is None:
            raise ConfigError(f"scenario.world: {str(file)!r}: the cylinder "
                              f"{model.get('name')!r} has no pose or radius")
        x, y = (float(v) for v in pose.text.split()[:2])
        found.append((x, y, float(radius.text)))
    if not found:
        raise ConfigError(f"scenario.world: {str(file)!r} holds no cylinder: not a BARN world")
    return np.asarray(found, dtype=float)


def _path(file: Path) -> FloatArray:
    if not file.is_file():
        raise ConfigError(f"scenario.world: no A* path file {str(file)!r}")
    try:
        cells = np.load(file, allow_pickle=False)
    except (ValueError, OSError, EOFError) as exc:
        raise ConfigError(f"scenario.world: {str(file)!r} is not a NumPy array file "
                          f"({exc})") from None
    if cells.ndim != 2 or cells.shape[1] != 2 or len(cells) == 0 \
            or not np.issubdtype(cells.dtype, np.integer):
        raise ConfigError(f"scenario.world: {str(file)!r} holds {cells.dtype} {cells.shape}, "
                          "not BARN's path of grid cells (m, 2) of integers")
    xy = np.c_[-4.425 + CELL * cells[:, 0], 5.175 + CELL * cells[:, 1]]
    return np.vstack([START, xy, GOAL])


def plant_top_speed(plant: Plant, x: FloatArray) -> float:
    """The plant's top speed [m/s] at state ``x``: the largest speed of its position over the
    corners of its input bounds (a kinematic plant's; 0 for one whose inputs set no speed)."""
    ip = [plant.state_index(s) for s in plant.position]
    corners = itertools.product(*zip(plant.u_lb, plant.u_ub, strict=True))
    speeds = [float(np.linalg.norm(np.asarray(plant.f(x, u)).ravel()[ip]))
              for u in corners if all(math.isfinite(v) for v in u)]
    return max(speeds, default=0.0)


def score(success: bool, time_s: float | None, optimal_s: float) -> float:
    """The challenge's score of one run: ``success * OT / clip(T, 2 OT, 8 OT)``."""
    if not success or time_s is None:
        return 0.0
    return optimal_s / min(max(time_s, 2 * optimal_s), 8 * optimal_s)


#: the stall rule's window on BARN [s] (:class:`BarnConf`)
STALL_WINDOW_S = 10.0


@dataclass
class BarnConf:
    _target_: str = "mpclab.world.barn.BarnScenario"
    name: str = "barn"
    barn_dir: str = SHIPPED
    world: int = 1
    scale: float = 0.25
    top_speed: Optional[float] = None  # noqa: UP045  (a typing object OmegaConf reads)
    t_max: Optional[float] = None  # noqa: UP045
    test_worlds: bool = False
    robot_radius: float = 0.05
    sensor: SensorConf = field(default_factory=SensorConf)
    #: BARN has no stall rule, only its time limit; a run that makes no way for this long
    #: ends early as a time-out (longer than the obstacle scenarios' 4 s: backing out of a
    #: pocket between BARN's cylinders can take that long)
    stall: StallConf = field(default_factory=lambda: StallConf(window_s=STALL_WINDOW_S))


@component("scenario", "barn", BarnConf)
class BarnScenario(ObstacleScenario):
    """A BARN world (module docstring) for a plant with a heading and a range sensor.

    Parameters
    ----------
    plant
        Injected; its ``position`` and ``heading`` labels place the robot.
    name
        Scenario name in the run record (``barn``; the world's index is ``barn_world``).
    barn_dir
        The folder of ``world_N.world`` and ``path_files/path_N.npy``: the challenge's
        unpacked, or ``barn`` (the three training worlds shipped in ``conf/barn``). A
        relative path is read from the working folder, else from the config folder.
    world
        The world's index ``N``.
    scale
        Gazebo metres to the plant's (0.25: about the Zumo's width against the Jackal's).
    top_speed
        The plant's top speed [m/s]; None: from the plant (:func:`plant_top_speed`).
    t_max
        The time limit [s]; None: the challenge's 100 s, scaled (a shorter one for quick
        runs: ``+ci=smoke``).
    test_worlds
        Allow the challenge's test worlds (0, 6, ..., 294: :data:`TEST_WORLDS`), held out
        from every design choice; false (default): refused.
    robot_radius, sensor
        As :class:`~mpclab.world.zumo_world.ObstacleScenario`.
    stall
        As :class:`~mpclab.world.zumo_world.ObstacleScenario`, over a window of
        :data:`STALL_WINDOW_S` unless given (BARN itself ends a run at its time limit only).
    """

    def __init__(
        self,
        plant: Plant,
        name: str = "barn",
        barn_dir: str = SHIPPED,
        world: int = 1,
        scale: float = 0.25,
        top_speed: float | None = None,
        t_max: float | None = None,
        test_worlds: bool = False,
        robot_radius: float = 0.05,
        sensor: Mapping[str, Any] | None = None,
        stall: Mapping[str, Any] | None = None,
    ) -> None:
        s = number(scale, "scenario.scale", above=0)
        if isinstance(world, bool) or int(world) != world or not 0 <= int(world) < 300:
            raise ConfigError(f"scenario.world: expected a world index 0..299, got {world!r}")
        if int(world) in TEST_WORLDS and not test_worlds:
            raise ConfigError(
                f"scenario.world={world}: one of the challenge's test worlds (0, 6, ..., 294), "
                "held out from tuning; the training worlds are those not a multiple of 6 "
                "(scenario.test_worlds=true to evaluate on a test world)")
        found = read_world(barn_dir, int(world))
        if plant.heading is None:
            raise ConfigError(f"scenario=barn needs a plant with a heading (the start faces +y); "
                              f"{type(plant).__name__} has none")
        px, py = plant.position
        heading = plant.heading
        start = {px: s * START[0], py: s * START[1], heading: math.pi / 2}
        goal = {px: s * GOAL[0], py: s * GOAL[1], heading: math.pi / 2}
        x0 = np.zeros(plant.nx)
        for label, v in start.items():
            x0[plant.state_index(label)] = v
        speed = (plant_top_speed(plant, x0) if top_speed is None
                 else number(top_speed, "scenario.top_speed", above=0))
        if speed <= 0:
            raise ConfigError("scenario.top_speed: the plant's inputs set no speed; give the "
                              "plant's top speed [m/s]")
        #: Gazebo seconds to the plant's
        self.time_scale = s * JACKAL_SPEED / speed
        self.barn_world, self.barn_scale, self.top_speed = found.index, s, speed
        #: the A* path in the plant's frame [m] and its optimal time OT [s]
        self.path = s * found.path
        self.optimal_time_s = s * found.path_length / speed
        cyl = found.cylinders
        radius = float(np.max(cyl[:, 2]))
        lo = np.minimum(cyl[:, :2].min(axis=0), self.path.min(axis=0) / s) - 1.0
        hi = np.maximum(cyl[:, :2].max(axis=0), self.path.max(axis=0) / s) + 1.0
        super().__init__(
            plant, name, start, goal,
            arrival={"weights": {px: 1.0, py: 1.0}, "threshold": (s * SUCCESS_RADIUS) ** 2},
            t_max=TIME_LIMIT * self.time_scale if t_max is None else t_max,
            layout={"obstacle_radius": s * radius, "discs": (s * cyl[:, :2]).tolist(),
                    "extent": [s * lo[0], s * hi[0], s * lo[1], s * hi[1]]},
            robot_radius=robot_radius, sensor=sensor,
            stall={"window_s": STALL_WINDOW_S, **(stall or {})},
        )

    def metrics(self, steps: Any, outcome: Mapping[str, Any]) -> dict[str, Any]:
        """The obstacle scenario's figures and BARN's: success, collision, time-out (a stall
        included), traversal time, optimal time and score."""
        status = outcome.get("status")
        success = status == "arrived"
        time_s = outcome.get("arrival_time_s") if success else None
        return {
            **super().metrics(steps, outcome),
            "barn_world": self.barn_world,
            "barn_scale": self.barn_scale,
            "barn_top_speed": self.top_speed,
            "barn_success": success,
            "barn_collision": status == "collision",
            "barn_timeout": status in ("timeout", "stalled"),
            "barn_time_s": time_s,
            "barn_optimal_time_s": self.optimal_time_s,
            "barn_score": score(success, time_s, self.optimal_time_s),
        }

