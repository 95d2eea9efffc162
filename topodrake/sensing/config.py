"""Sensor configurations (typed dataclasses, loadable from YAML)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class CameraConfig:
    """Pinhole RGB camera on the car.

    The optical axis is horizontal, along the car's heading; pixels are square
    so the vertical field of view follows from the horizontal one and the
    aspect ratio.
    """

    width: int = 64
    height: int = 64
    hfov_deg: float = 120.0
    forward_m: float = 0.065   # ahead of the car's reference point
    height_m: float = 0.228    # above the floor
    max_depth_m: float = 30.0

    @property
    def fx(self) -> float:
        """Focal length in pixels (fx == fy)."""
        return 0.5 * self.width / np.tan(0.5 * np.radians(self.hfov_deg))

    @property
    def cx(self) -> float:
        return 0.5 * self.width - 0.5

    @property
    def cy(self) -> float:
        return 0.5 * self.height - 0.5

    @property
    def vfov_rad(self) -> float:
        return 2.0 * np.arctan(0.5 * self.height / self.fx)


@dataclass
class LidarConfig:
    """Planar 1-D lidar: evenly spread beams centred on the heading."""

    beams: int = 64
    fov_deg: float = 240.0
    range_m: float = 10.0
    forward_m: float = 0.08

    def beam_angles(self) -> np.ndarray:
        """(beams,) beam angles relative to the heading, right to left."""
        half = 0.5 * np.radians(self.fov_deg)
        return np.linspace(-half, half, self.beams)
