"""Depth parity between our renderer and Drake's RenderEngineVtk."""

from __future__ import annotations

import numpy as np

from topodrake.sensing.camera import Camera
from topodrake.sensing.config import CameraConfig
from topodrake.sensing.scenegraph import vtk_depth_renderer


def depth_errors(world, poses: np.ndarray, camera: CameraConfig | None = None,
                 vtk=None) -> np.ndarray:
    """|ours - VTK| z-depth (m) on every pixel where both see a surface."""
    camera = camera or CameraConfig()
    ours = Camera(world, camera).render_depth(poses)
    vtk = vtk or vtk_depth_renderer(world, camera)
    theirs = vtk.render_depth(poses)
    both = np.isfinite(ours) & np.isfinite(theirs) & (ours < camera.max_depth_m) \
        & (theirs < camera.max_depth_m)
    return np.abs(ours - theirs)[both]


def parity_summary(errors: np.ndarray) -> dict:
    return {"pixels": int(errors.size),
            "depth_parity_median_m": float(np.median(errors)) if errors.size else float("nan"),
            "depth_parity_p99_m": float(np.percentile(errors, 99)) if errors.size else float("nan")}
