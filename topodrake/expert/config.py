"""Expert configuration, the per-car memory layout, packed paths and the
parameter vector the compiled kernels read."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from topodrake.sensing.config import LidarConfig
from topodrake.vehicle import VehicleConfig


@dataclass(frozen=True)
class ExpertConfig:
    lookahead_m: float = 5.0
    search_ahead_m: float = 2.0   # how far ahead the progress index may jump per step
    # The line of sight to a waypoint must keep this much more than the car's
    # radius from walls, so the car does not cut door jambs and corners it
    # cannot turn around (its turning radius is 0.43 m).
    sight_margin_m: float = 0.1
    # Closed-loop prediction and manoeuvres (module docstring). predict=False
    # gives the plain farthest-visible-waypoint expert.
    predict: bool = True
    horizon_s: float = 3.0          # prediction horizon of the path-following check
    recheck_s: float = 0.3          # a passed check is trusted this long
    body_margin_m: float = 0.0      # predicted body keeps this beyond the collision clearance
    imminent_s: float = 1.0         # forward collisions predicted later than this are ignored
    rescan_s: float = 0.5           # the prediction re-renders the lidar this often (0: never)
    obstacle_range_m: float = 1.0   # lidar hits farther from the car are left out of the prediction
    turn_cost_m: float = 0.5        # progress lost per radian of heading away from the path
    min_progress_m: float = 0.25    # path progress the prediction must show over the horizon
    final_m: float = 1.0            # closer than this (path length) the goal must be reached
    reach_m: float = 0.2            # predicted "reached" (the success tolerance is 0.27 m)
    manoeuvre_s: float = 1.0        # length of a committed manoeuvre leg
    manoeuvre_radius_m: float = 2.0  # distance of the auxiliary waypoints
    manoeuvre_directions: int = 6   # auxiliary waypoints on a ring around the car
    manoeuvre_gain_m: float = 0.3   # a manoeuvre must beat following by this much progress
    # No check (the plain expert is safe) when the car has this clearance,
    # this speed, its waypoint within this bearing and this much path
    # beyond final_m left.
    open_clearance_m: float = 0.5
    open_speed: float = 0.2
    open_bearing_deg: float = 45.0
    open_goal_m: float = 1.0


#: Per-car memory of the expert (float64 columns).
MEMORY_COLUMNS = ("mode", "steps_left", "aux_x", "aux_y", "next_angle", "prev_x", "prev_y",
                  "prev_theta", "steer_estimate", "trusted_steps")
MEMORY_SIZE = len(MEMORY_COLUMNS)
_M_MODE, _M_LEFT, _M_AX, _M_AY, _M_NEXT, _M_PX, _M_PY, _M_PT, _M_STEER, _M_TRUST = \
    range(MEMORY_SIZE)


def initial_memory(poses: np.ndarray) -> np.ndarray:
    """(N, MEMORY_SIZE) expert memory of cars at rest at ``poses`` (N, 3)."""
    poses = np.asarray(poses, np.float64).reshape(-1, 3)
    mem = np.zeros((len(poses), MEMORY_SIZE))
    mem[:, _M_PX:_M_PT + 1] = poses
    mem[:, _M_NEXT] = np.nan
    return mem


@dataclass
class PackedPaths:
    """Paths (K_i, 2) packed as ``points`` with ``offsets`` (N + 1,) and arc length."""

    points: np.ndarray
    offsets: np.ndarray
    arclen: np.ndarray

    @classmethod
    def pack(cls, paths: list[np.ndarray]) -> "PackedPaths":
        offsets = np.zeros(len(paths) + 1, np.int64)
        offsets[1:] = np.cumsum([len(p) for p in paths])
        points = np.ascontiguousarray(np.concatenate(paths), np.float64)
        arclen = np.concatenate([np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))])
                                 for p in paths])
        return cls(points, offsets, arclen)

    def goals(self) -> np.ndarray:
        return self.points[self.offsets[1:] - 1]


# Layout of the expert parameter vector.
_E_LOOK, _E_SEARCH, _E_SIGHT, _E_CSPACE, _E_H, _E_TRUST, _E_BODY, _E_OBSR, _E_PROG, \
    _E_FINAL, _E_REACH, _E_MSTEPS, _E_MRAD, _E_MDIRS, _E_DT, _E_PREDICT, _E_LFWD, \
    _E_LCOS, _E_OPEN, _E_VOPEN, _E_COSOPEN, _E_OPENFIN, _E_MGAIN, _E_IMM, _E_TURN, _E_RESCAN, _E_COUNT = range(27)
#: The predicted expert re-selects its waypoint every this many periods.
_RESELECT = 10


def _expert_params(config: ExpertConfig, vehicle: VehicleConfig, lidar: LidarConfig,
                   car_radius: float) -> np.ndarray:
    e = np.zeros(_E_COUNT)
    e[_E_LOOK] = config.lookahead_m
    e[_E_SEARCH] = config.search_ahead_m
    e[_E_SIGHT] = car_radius + config.sight_margin_m
    e[_E_CSPACE] = car_radius
    e[_E_H] = max(1, round(config.horizon_s / vehicle.dt))
    e[_E_TRUST] = max(0, round(config.recheck_s / vehicle.dt))
    e[_E_BODY] = vehicle.collision_clearance + config.body_margin_m
    e[_E_OBSR] = config.obstacle_range_m
    e[_E_PROG] = config.min_progress_m
    e[_E_FINAL] = config.final_m
    e[_E_REACH] = config.reach_m
    e[_E_MSTEPS] = max(1, round(config.manoeuvre_s / vehicle.dt))
    e[_E_MRAD] = config.manoeuvre_radius_m
    e[_E_MDIRS] = config.manoeuvre_directions
    e[_E_DT] = vehicle.dt
    e[_E_PREDICT] = float(config.predict)
    e[_E_LFWD] = lidar.forward_m
    e[_E_LCOS] = math.cos(0.5 * math.radians(min(lidar.fov_deg, 360.0)))
    e[_E_OPEN] = config.open_clearance_m
    e[_E_VOPEN] = config.open_speed
    e[_E_COSOPEN] = math.cos(math.radians(config.open_bearing_deg))
    e[_E_OPENFIN] = config.open_goal_m
    e[_E_MGAIN] = config.manoeuvre_gain_m
    e[_E_IMM] = round(config.imminent_s / vehicle.dt)
    e[_E_TURN] = config.turn_cost_m
    e[_E_RESCAN] = max(0, round(config.rescan_s / vehicle.dt))
    return e
