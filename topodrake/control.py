"""One control step of the laser RMP toward a world-frame waypoint, batched.

Shared by the Drake ``RmpController`` (a batch of one) and the batched
rollout engine, so both compute exactly the same controls.
"""

from __future__ import annotations

import numpy as np

from topodrake.rmp import RmpConfig, rmp_controls
from topodrake.sensing.config import LidarConfig
from topodrake.vehicle import VehicleConfig, world_to_car


def lidar_points_car_frame(ranges: np.ndarray, lidar: LidarConfig) -> tuple[np.ndarray, np.ndarray]:
    """Lidar ranges (N, B) -> hit points (N, B, 2) in the car frame and a hit mask."""
    ranges = np.asarray(ranges, dtype=np.float64)
    ang = lidar.beam_angles()
    hit = np.isfinite(ranges)
    r = np.where(hit, ranges, 0.0)
    pts = np.stack([lidar.forward_m + r * np.cos(ang), r * np.sin(ang)], axis=-1)
    return pts, hit


def controls_toward(state: np.ndarray, waypoint_world: np.ndarray, ranges: np.ndarray,
                    lidar: LidarConfig, rmp: RmpConfig, vehicle: VehicleConfig) -> np.ndarray:
    """Controls (N, 2) driving each car toward its world-frame waypoint while
    avoiding its lidar hits."""
    state = np.asarray(state, dtype=np.float64).reshape(-1, 5)
    wp_local = world_to_car(np.asarray(waypoint_world, np.float64).reshape(-1, 1, 2), state)[:, 0]
    pts, hit = lidar_points_car_frame(ranges, lidar)
    return rmp_controls(state, wp_local, pts, hit, rmp, vehicle)
