"""MeshcatCar: draws the car and its lidar hits in Meshcat at 10 Hz.

Meshcat is a viewer, not part of the dynamics: this sink only publishes, and
when the Meshcat object is recording, every frame lands in the recording
(``meshcat.StaticHtml()`` then saves it as one HTML file).
"""

from __future__ import annotations

import numpy as np
from pydrake.geometry import Box, Rgba
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.systems.framework import LeafSystem

from topodrake.control import lidar_points_car_frame
from topodrake.sensing.config import LidarConfig
from topodrake.vehicle import car_to_world


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
