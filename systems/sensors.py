"""CameraSensor and LidarSensor: 10 Hz sample-and-hold wrappers of the batched renderers."""

from __future__ import annotations

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import LeafSystem

from topodrake.sensing.camera import Camera
from topodrake.sensing.config import CameraConfig, LidarConfig
from topodrake.sensing.lidar import Lidar


class LidarSensor(LeafSystem):
    """Input ``pose``; output ``ranges`` (beams,), held between samples (inf = no hit)."""

    def __init__(self, world, config: LidarConfig | None = None, period: float = 0.1):
        super().__init__()
        self.lidar = Lidar(world, config)
        self.pose_port = self.DeclareVectorInputPort("pose", 3)
        idx = self.DeclareDiscreteState(self.lidar.config.beams)
        self.ranges_port = self.DeclareStateOutputPort("ranges", idx)
        self.DeclarePeriodicDiscreteUpdateEvent(period, 0.0, self._sample)

    def _sample(self, context, discrete_state):
        pose = self.pose_port.Eval(context)
        discrete_state.set_value(0, self.lidar.scan(pose[None])[0].astype(np.float64))


class CameraSensor(LeafSystem):
    """Input ``pose``; output ``image`` (H, W, 3) uint8 numpy array, held between samples.

    The output is the cached state value: copy it before changing it.
    """

    def __init__(self, world, config: CameraConfig | None = None, period: float = 0.1):
        super().__init__()
        self.camera = Camera(world, config)
        c = self.camera.config
        self.pose_port = self.DeclareVectorInputPort("pose", 3)
        blank = np.zeros((c.height, c.width, 3), np.uint8)
        idx = self.DeclareAbstractState(AbstractValue.Make(blank))
        self.image_port = self.DeclareStateOutputPort("image", idx)
        self.DeclarePeriodicUnrestrictedUpdateEvent(period, 0.0, self._sample)

    def _sample(self, context, state):
        pose = self.pose_port.Eval(context)
        state.get_mutable_abstract_state(0).set_value(self.camera.render(pose[None])[0])
