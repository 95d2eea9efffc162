"""Observations of either modality for a batch of poses, by name."""

from __future__ import annotations

import numpy as np

from topodrake.sensing.lidar import Lidar


def observe(world, modality: str, poses: np.ndarray, sensor=None) -> np.ndarray:
    """Camera images (N, H, W, 3) uint8 or lidar ranges (N, beams) at ``poses``
    (N, 3); ``sensor`` is the modality's config (default: the default one)."""
    if modality == "camera":
        from topodrake.sensing.camera import Camera
        return Camera(world, sensor).render(poses)
    if modality == "lidar":
        from topodrake.sensing.lidar import Lidar
        return Lidar(world, sensor).scan(poses)
    raise ValueError(f"no observations of modality {modality!r}")


def camera_scans(world, modality: str, poses: np.ndarray, lidar=None) -> np.ndarray | None:
    """The lidar scans (N, beams) a ``modality`` car takes beside its
    observations at ``poses`` (N, 3), which camera routes and maps keep for
    the route tracker (``lidar``: the car's LidarConfig, default the
    default); None for other modalities (a lidar car's observations are its
    scans, a pose oracle takes none)."""
    return lidar_scans(world, poses, lidar) if modality == "camera" else None


def lidar_scans(world, poses: np.ndarray, lidar=None) -> np.ndarray:
    """The lidar scans (N, beams) taken at ``poses`` (N, 3) (``lidar``: a
    LidarConfig, default the default): what camera and pose oracle maps
    keep beside their observations for the route tracker."""
    return Lidar(world, lidar).scan(np.asarray(poses, np.float64).reshape(-1, 3))
