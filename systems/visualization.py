"""MeshcatCar and MeshcatChanges: the car, its lidar hits and what changed
in its world (boxes, a closed door, walkers), drawn in Meshcat at 10 Hz.

Meshcat is a viewer, not part of the dynamics: these sinks only publish, and
when the Meshcat object is recording, every frame lands in the recording
(``meshcat.StaticHtml()`` then saves it as one HTML file).
"""

from __future__ import annotations

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.geometry import Box, Cylinder, Rgba
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.systems.framework import LeafSystem

from topodrake.control import lidar_points_car_frame
from topodrake.sensing.config import LidarConfig
from topodrake.sensing.scenegraph import texture_rgba
from topodrake.vehicle import car_to_world
from topodrake.world.changes import BLOCK_TEXTURE, WALKER_TEXTURE, CarChanges


class MeshcatCar(LeafSystem):
    def __init__(self, meshcat, period: float = 0.1, lidar: LidarConfig | None = None,
                 path: str = "/topodrake/car"):
        super().__init__()
        self.meshcat = meshcat
        self.lidar = lidar or LidarConfig()
        self.path = path
        self.pose_port = self.DeclareVectorInputPort("pose", 3)
        self.ranges_port = self.DeclareVectorInputPort("ranges", self.lidar.beams)
        meshcat.SetObject(f"{path}/body", Box(0.31, 0.16, 0.1), Rgba(0.85, 0.15, 0.1, 1.0))
        meshcat.SetTransform(f"{path}/body", RigidTransform([0.025, 0.0, 0.05]))
        meshcat.SetObject(f"{path}/nose", Box(0.06, 0.06, 0.06), Rgba(1.0, 0.9, 0.1, 1.0))
        meshcat.SetTransform(f"{path}/nose", RigidTransform([0.16, 0.0, 0.12]))
        self.DeclarePeriodicPublishEvent(period, 0.0, self._publish)

    def _publish(self, context):
        x, y, theta = self.pose_port.Eval(context)
        t = context.get_time()
        X = RigidTransform(RotationMatrix.MakeZRotation(theta), [x, y, 0.0])
        self.meshcat.SetTransform(self.path, X, t)
        ranges = self.ranges_port.Eval(context)
        pts, hit = lidar_points_car_frame(ranges[None], self.lidar)
        world = car_to_world(pts[0][hit[0]], np.array([[x, y, theta, 0.0, 0.0]]))[0]
        if len(world):
            xyz = np.vstack([world.T, np.full(len(world), 0.15)])
            self.meshcat.SetLine("/topodrake/lidar", xyz, 2.0, Rgba(0.1, 0.8, 0.2, 1.0))


#: how tall the viewer draws a box left on the floor, and a walker (m)
BOX_HEIGHT_M = 0.5
WALKER_HEIGHT_M = 1.7


class MeshcatChanges(LeafSystem):
    """Draws what changed in the car's world at 10 Hz: still changes as
    boxes (a closed passage wall-high, ``wall_height``), walkers as
    cylinders that move (their transforms land in a recording). Input
    ``changes`` (a :class:`~topodrake.world.changes.CarChanges` of one car,
    a :class:`~topodrake.systems.changes.WorldChangesSource`'s)."""

    def __init__(self, meshcat, period: float = 0.1, wall_height: float = 2.5,
                 path: str = "/topodrake/changes"):
        super().__init__()
        self.meshcat = meshcat
        self.wall_height = float(wall_height)
        self.path = path
        self.changes_port = self.DeclareAbstractInputPort(
            "changes", AbstractValue.Make(CarChanges(np.zeros((1, 0, 8)))))
        self._drawn = None          # the still faces and walker radii drawn (the viewer's own)
        self.DeclarePeriodicPublishEvent(period, 0.0, self._publish)

    def _publish(self, context):
        changes = self.changes_port.Eval(context)
        xy, radius = changes.walkers.discs([0]) if changes.moving else \
            (np.zeros((1, 0, 2)), np.zeros((1, 0)))
        if self._drawn is None or not (np.array_equal(self._drawn[0], changes.fixed, True)
                                       and np.array_equal(self._drawn[1], radius)):
            self._draw(changes, radius[0])
            self._drawn = (changes.fixed.copy(), radius.copy())
        t = context.get_time()
        for w, (x, y) in enumerate(xy[0]):
            self.meshcat.SetTransform(f"{self.path}/walkers/{w}",
                                      RigidTransform([float(x), float(y), 0.0]), t)

    def _draw(self, changes, radius: np.ndarray) -> None:
        self.meshcat.Delete(self.path)
        corners, textures = changes.solids(0)
        for i, (c, tid) in enumerate(zip(corners, textures)):
            e1, e2 = c[1] - c[0], c[2] - c[1]
            h = self.wall_height if tid == BLOCK_TEXTURE else BOX_HEIGHT_M
            p = f"{self.path}/still/{i}"
            self.meshcat.SetObject(p, Box(float(np.hypot(*e1)), float(np.hypot(*e2)), h),
                                   Rgba(*texture_rgba(int(tid)), 1.0))
            self.meshcat.SetTransform(p, RigidTransform(
                RotationMatrix.MakeZRotation(float(np.arctan2(e1[1], e1[0]))),
                [*map(float, c.mean(axis=0)), 0.5 * h]))
        for w, r in enumerate(radius):
            body = f"{self.path}/walkers/{w}/body"
            self.meshcat.SetObject(body, Cylinder(float(r), WALKER_HEIGHT_M),
                                   Rgba(*texture_rgba(WALKER_TEXTURE), 1.0))
            self.meshcat.SetTransform(body, RigidTransform([0.0, 0.0, 0.5 * WALKER_HEIGHT_M]))
