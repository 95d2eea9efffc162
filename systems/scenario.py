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

import numpy as np

from topodrake.errors import TopodrakeError
from topodrake.expert import ExpertConfig
from topodrake.rmp import RmpConfig
from topodrake.sensing.config import CameraConfig, LidarConfig
from topodrake.typed_yaml import load_typed
from topodrake.vehicle import VehicleConfig


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

    def start_pose(self, world) -> np.ndarray:
        return self._endpoint(world, self.start, self.start_place, "start", 3)

    def goal_xy(self, world) -> np.ndarray:
        return self._endpoint(world, self.goal, self.goal_place, "goal", 2)

    @staticmethod
    def _endpoint(world, value, place, what, size) -> np.ndarray:
        if value:
            pose = np.zeros(3)
            pose[:len(value)] = value
            if len(value) not in (2, 3):
                raise TopodrakeError(f"scenario {what} must be [x, y] or [x, y, heading], got {value}")
        else:
            if not 0 <= place < len(world.places):
                raise TopodrakeError(
                    f"scenario {what}_place {place} is not a place of {world.name!r} "
                    f"(0..{len(world.places) - 1})")
            pose = world.places[place].copy()
        world.check_pose(pose, what)
        return pose[:size]


def load_scenario(path) -> Scenario:
    """Read a Scenario YAML; a bad file gives a one-line TopodrakeError."""
    return load_typed(Scenario, path, "scenario")
