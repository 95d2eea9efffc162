"""CameraSensor and LidarSensor: 10 Hz sample-and-hold wrappers of the batched renderers."""

from __future__ import annotations

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import LeafSystem

from topodrake.sensing.camera import Camera
from topodrake.sensing.config import CameraConfig, LidarConfig
from topodrake.sensing.lidar import Lidar


def _declare_extra(system: LeafSystem):
    """The optional ``extra`` input: (F, 8) render rows of faces the world
    lacks (a :class:`~topodrake.systems.changes.WorldChangesSource`'s
    ``faces``); unconnected, the sensor sees the world alone."""
    return system.DeclareAbstractInputPort("extra", AbstractValue.Make(np.zeros((0, 8))))


def _extra(port, context) -> np.ndarray | None:
    """(1, F, 8) extra faces for the batched sensors, or None (unconnected)."""
    if not port.HasValue(context):
        return None
    return np.asarray(port.Eval(context), np.float64).reshape(1, -1, 8)


class LidarSensor(LeafSystem):
    """Inputs ``pose`` and (optional) ``extra``; output ``ranges`` (beams,),
    held between samples (inf = no hit)."""

    def __init__(self, world, config: LidarConfig | None = None, period: float = 0.1):
        super().__init__()
        self.lidar = Lidar(world, config)
        self.pose_port = self.DeclareVectorInputPort("pose", 3)
        self.extra_port = _declare_extra(self)
        idx = self.DeclareDiscreteState(self.lidar.config.beams)
        self.ranges_port = self.DeclareStateOutputPort("ranges", idx)
        self.DeclarePeriodicDiscreteUpdateEvent(period, 0.0, self._sample)

    def _sample(self, context, discrete_state):
        pose = self.pose_port.Eval(context)
        ranges = self.lidar.scan(pose[None], _extra(self.extra_port, context))[0]
        discrete_state.set_value(0, ranges.astype(np.float64))


class CameraSensor(LeafSystem):
    """Inputs ``pose`` and (optional) ``extra``; output ``image`` (H, W, 3)
    uint8 numpy array, held between samples.

    The output is the cached state value: copy it before changing it.
    """

    def __init__(self, world, config: CameraConfig | None = None, period: float = 0.1):
        super().__init__()
        self.camera = Camera(world, config)
        c = self.camera.config
        self.pose_port = self.DeclareVectorInputPort("pose", 3)
        self.extra_port = _declare_extra(self)
        blank = np.zeros((c.height, c.width, 3), np.uint8)
        idx = self.DeclareAbstractState(AbstractValue.Make(blank))
        self.image_port = self.DeclareStateOutputPort("image", idx)
        self.DeclarePeriodicUnrestrictedUpdateEvent(period, 0.0, self._sample)

    def _sample(self, context, state):
        pose = self.pose_port.Eval(context)
        image = self.camera.render(pose[None], _extra(self.extra_port, context))[0]
        state.get_mutable_abstract_state(0).set_value(image)
