"""Wheel odometry that drifts: the car's integrated pose as a real robot would measure it.

Each car gets its own systematic errors, drawn once per run from its seed
(the errors that dominate wheel odometry, Borenstein and Feng 1996,
"Measurement and correction of systematic odometry errors in mobile
robots", IEEE T-RA 12(6)): a scale error of the distance driven, a scale
error of the angle turned, and a heading bias per metre driven (a steering
trim or wheel-diameter mismatch). Each period the car's true motion, in its
own frame, is scaled and biased and integrated onto its odometry pose, so
what a consumer sees is a pose that agrees with the world at the start and
drifts with the distance driven and the angle turned.

:meth:`OdometryConfig.perfect` (all zero) reads the true pose: the
ablation, and the default wherever a config does not name one.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from topodrake.errors import TopodrakeError
from topodrake.se2 import compose, relative
from topodrake.vehicle import car_to_world, world_to_car


@dataclass
class OdometryConfig:
    """Standard deviations of the per-run systematic errors (zero: perfect)."""

    scale_std: float = 0.0                 # distance driven, as a fraction
    turn_scale_std: float = 0.0            # angle turned, as a fraction
    heading_bias_std_deg_per_m: float = 0.0   # heading error per metre driven

    @classmethod
    def perfect(cls) -> "OdometryConfig":
        return cls()

    @classmethod
    def wheel(cls) -> "OdometryConfig":
        """A small car's wheel odometry: 3 % of distance, 5 % of turns, 1 deg/m."""
        return cls(scale_std=0.03, turn_scale_std=0.05, heading_bias_std_deg_per_m=1.0)

    @property
    def is_perfect(self) -> bool:
        return self.scale_std == 0 and self.turn_scale_std == 0 and \
            self.heading_bias_std_deg_per_m == 0

    def check(self) -> "OdometryConfig":
        for name in ("scale_std", "turn_scale_std", "heading_bias_std_deg_per_m"):
            v = getattr(self, name)
            if not (np.isfinite(v) and 0 <= v < 1.0 if name != "heading_bias_std_deg_per_m"
                    else np.isfinite(v) and 0 <= v <= 45.0):
                raise TopodrakeError(f"odometry {name} must be >= 0 and small, got {v}")
        return self


#: the odometry models a drive can read, by name (studies, the demo, ``navigate``)
ODOMETRY_MODELS = ("wheel", "perfect")


def odometry_model(name: str) -> OdometryConfig:
    """The named odometry model (:data:`ODOMETRY_MODELS`)."""
    if name not in ODOMETRY_MODELS:
        raise TopodrakeError(f"odometry must be one of {', '.join(ODOMETRY_MODELS)}, got {name!r}")
    return getattr(OdometryConfig, name)()


def odometry_errors(config: OdometryConfig, seeds) -> np.ndarray:
    """(N, 3) per-car errors (distance scale, turn scale, heading bias rad/m)
    drawn from each car's seed."""
    cfg = config.check()
    seeds = np.atleast_1d(np.asarray(seeds, np.int64))
    out = np.zeros((len(seeds), 3))
    if cfg.is_perfect:
        return out
    for i, s in enumerate(seeds):
        z = np.random.default_rng([int(s), 0x0D0]).standard_normal(3)
        out[i] = z * [cfg.scale_std, cfg.turn_scale_std,
                      np.radians(cfg.heading_bias_std_deg_per_m)]
    return out


def odometry_increment(before: np.ndarray, after: np.ndarray, errors: np.ndarray) -> np.ndarray:
    """What odometry measures (N, 3) of the true motion from poses ``before``
    to ``after`` (N, 3), in the car's frame at ``before``."""
    d = relative(before, after)
    scale, turn, bias = np.asarray(errors, np.float64).reshape(-1, 3).T
    step = np.hypot(d[:, 0], d[:, 1])
    return np.column_stack([d[:, 0] * (1 + scale), d[:, 1] * (1 + scale),
                            d[:, 2] * (1 + turn) + bias * step])


def odometry_step(odometry: np.ndarray, before: np.ndarray, after: np.ndarray,
                  errors: np.ndarray) -> np.ndarray:
    """The odometry poses (N, 3) after the true motion from ``before`` to
    ``after`` (N, 3), measured with ``errors``, from ``odometry`` (N, 3)."""
    return compose(odometry, odometry_increment(before, after, errors))


def odometry_to_world(points: np.ndarray, odometry: np.ndarray, true: np.ndarray) -> np.ndarray:
    """Points (N, M, 2) given in the odometry frame, where they lie in the
    world relative to the cars' true states (N, >= 3): as far and in the
    same direction from the car as from its odometry pose."""
    return car_to_world(world_to_car(points, odometry), true)


class Odometry:
    """The odometry poses of N cars: they start at the cars' true poses and
    integrate each period's measured increment (:meth:`update`)."""
    def __init__(self, config: OdometryConfig, seeds, starts: np.ndarray):
        starts = np.asarray(starts, np.float64).reshape(-1, 3)
        self.errors = odometry_errors(config, np.broadcast_to(np.atleast_1d(seeds), len(starts)))
        self.perfect = config.is_perfect
        self.true = starts.copy()
        self.poses = starts.copy()

    def update(self, cars: np.ndarray, true_poses: np.ndarray) -> None:
        """Cars ``cars`` moved to ``true_poses`` (M, 3)."""
        true_poses = np.asarray(true_poses, np.float64).reshape(-1, 3)
        if self.perfect:
            self.poses[cars] = true_poses
        else:
            self.poses[cars] = odometry_step(self.poses[cars], self.true[cars], true_poses,
                                             self.errors[cars])
        self.true[cars] = true_poses


def odometry_along(poses: np.ndarray, config: OdometryConfig, seed: int) -> np.ndarray:
    """The odometry poses (T, 3) a car with ``seed``'s errors records along
    the true poses ``poses`` (T, 3) (a teach drive's own odometry)."""
    poses = np.asarray(poses, np.float64).reshape(-1, 3)
    odo = Odometry(config, [seed], poses[:1])
    out = np.empty_like(poses)
    out[0] = poses[0]
    one = np.zeros(1, np.int64)
    for t in range(1, len(poses)):
        odo.update(one, poses[t:t + 1])
        out[t] = odo.poses[0]
    return out
