"""Scenario: everything a closed-loop run needs, as a dataclass loadable from YAML.

Example YAML (every key optional)::

    world: test-0          # catalogue name or map YAML/JSON path
    start_place: 0         # or start: [x, y, heading]
    goal_place: 3          # or goal: [x, y]
    noise_std: 0.33        # multiplicative actuation noise; 0 = off
    seed: 7
    t_max_s: 120
    camera_enabled: true
    camera: {width: 64, height: 64, hfov_deg: 120}
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from topodrake.errors import TopodrakeError
from topodrake.expert import ExpertConfig
from topodrake.rmp import RmpConfig
from topodrake.sensing.config import CameraConfig, LidarConfig
from topodrake.typed_yaml import load_typed
from topodrake.validate import (check_count, check_finite, check_nonnegative, check_positive,
                                check_seed)
from topodrake.vehicle import VehicleConfig

MAX_HEADING = 2 * np.pi       # a start heading beyond one turn either way is a typo


@dataclass
class Scenario:
    world: str = "test-0"
    start: list[float] = field(default_factory=list)
    goal: list[float] = field(default_factory=list)
    start_place: int = 0
    goal_place: int = 1
    noise_std: float = 0.0
    seed: int = 0
    t_max_s: float = 120.0
    goal_tolerance_m: float = 0.27
    camera_enabled: bool = True
    camera: CameraConfig = field(default_factory=CameraConfig)
    lidar: LidarConfig = field(default_factory=LidarConfig)
    vehicle: VehicleConfig = field(default_factory=VehicleConfig)
    rmp: RmpConfig = field(default_factory=RmpConfig)
    expert: ExpertConfig = field(default_factory=ExpertConfig)

    def __post_init__(self):
        self.validate()

    def validate(self, where: str = "scenario") -> "Scenario":
        """Check the numbers; a bad one raises a one-line TopodrakeError
        naming it and its allowed range."""
        for name in ("start_place", "goal_place"):
            check_count(f"{where}: {name}", getattr(self, name), 0)
        for name, size, shape in (("start", 3, "[x, y, heading]"), ("goal", 2, "[x, y]")):
            value = getattr(self, name)
            if value and len(value) != size:
                raise TopodrakeError(f"{where}: {name} must be {shape} ({size} numbers), "
                                     f"got {list(value)}")
            for v in value:
                check_finite(f"{where}: {name}", v)
        if self.start and not -MAX_HEADING <= self.start[2] <= MAX_HEADING:
            raise TopodrakeError(f"{where}: start heading must be an angle in "
                                 f"[-2pi, 2pi] rad, got {self.start[2]}")
        check_nonnegative(f"{where}: noise_std", self.noise_std)
        check_seed(f"{where}: seed", self.seed)
        check_positive(f"{where}: t_max_s", self.t_max_s)
        check_positive(f"{where}: goal_tolerance_m", self.goal_tolerance_m)
        v = self.vehicle
        for name in ("wheelbase", "steer_limit", "steer_rate_limit", "speed_cap", "accel_limit",
                     "dt", "collision_ray_step"):
            check_positive(f"{where}: vehicle.{name}", getattr(v, name))
        check_finite(f"{where}: vehicle.min_speed", v.min_speed)
        check_nonnegative(f"{where}: vehicle.noise_std", v.noise_std)
        check_nonnegative(f"{where}: vehicle.collision_clearance", v.collision_clearance)
        c = self.camera
        check_count(f"{where}: camera.width", c.width)
        check_count(f"{where}: camera.height", c.height)
        for name in ("hfov_deg", "max_depth_m"):
            check_positive(f"{where}: camera.{name}", getattr(c, name))
        check_count(f"{where}: lidar.beams", self.lidar.beams)
        for name in ("fov_deg", "range_m"):
            check_positive(f"{where}: lidar.{name}", getattr(self.lidar, name))
        return self

    def start_pose(self, world) -> np.ndarray:
        return self._endpoint(world, self.start, self.start_place, "start", 3)

    def goal_xy(self, world) -> np.ndarray:
        return self._endpoint(world, self.goal, self.goal_place, "goal", 2)

    @staticmethod
    def _endpoint(world, value, place, what, size) -> np.ndarray:
        if value:
            if len(value) != size:
                raise TopodrakeError(f"scenario {what} must have {size} numbers, got {value}")
            pose = np.zeros(3)
            pose[:size] = value
        else:
            if not 0 <= place < len(world.places):
                raise TopodrakeError(
                    f"scenario {what}_place {place} is not a place of {world.name!r} "
                    f"(0..{len(world.places) - 1})")
            pose = world.places[place].copy()
        world.check_pose(pose, what)
        return pose[:size]


def load_scenario(path) -> Scenario:
    """Read a Scenario YAML; a bad file or number gives a one-line
    TopodrakeError naming the file (and the key and its line)."""
    scenario = load_typed(Scenario, path, "scenario")
    _check_one_form(path)
    return scenario.validate(f"scenario {path}")


def _check_one_form(path) -> None:
    """An end is given by its place or by its pose (a non-empty list), never both."""
    root = yaml.compose(Path(path).read_text(), Loader=yaml.SafeLoader)
    if not isinstance(root, yaml.MappingNode):
        return
    keys = {k.value: k.start_mark.line + 1 for k, v in root.value
            if not (isinstance(v, yaml.SequenceNode) and not v.value)}   # start: [] is none
    for end in ("start", "goal"):
        if end in keys and f"{end}_place" in keys:
            raise TopodrakeError(
                f"scenario {path} line {keys[end]}: {end}: give {end}_place or {end}, not both "
                f"({end}_place is on line {keys[end + '_place']})")
