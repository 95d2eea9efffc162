"""DriveRecorder: a drive's sensor readings, one sample per control period.

A thin sink: each period it copies its inputs (the car's true state, the
pose the follower reads, the lidar's ranges, the camera's image where wired
and the follower's mode) into :meth:`DriveRecorder.frames`; the bag is made
from them by :mod:`topodrake.bag`. A publish event at ``t`` runs before the
samples of ``t`` are taken, so it sees those of the period before: each
record is stamped ``t - period``, and none is made at ``t = 0``.
"""

from __future__ import annotations

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import LeafSystem


class DriveRecorder(LeafSystem):
    """Inputs ``state`` (5), ``odometry`` (5), ``ranges`` (beams), ``mode`` (1)
    and ``image`` ((H, W, 3) uint8; leave it unconnected without a camera)."""

    def __init__(self, beams: int, period: float = 0.1):
        super().__init__()
        self.state_port = self.DeclareVectorInputPort("state", 5)
        self.odometry_port = self.DeclareVectorInputPort("odometry", 5)
        self.ranges_port = self.DeclareVectorInputPort("ranges", beams)
        self.mode_port = self.DeclareVectorInputPort("mode", 1)
        self.image_port = self.DeclareAbstractInputPort(
            "image", AbstractValue.Make(np.zeros((1, 1, 3), np.uint8)))
        self.period = float(period)
        self.DeclarePeriodicPublishEvent(period, 0.0, self._record)
        self.clear()

    def clear(self) -> None:
        """Forget what was recorded (a new run, or the end of a warm-up)."""
        self.samples = []

    def _record(self, context):
        t = context.get_time() - self.period
        if t < -1e-9:                   # nothing sampled yet
            return
        image = self.image_port.Eval(context).copy() if self.image_port.HasValue(context) \
            else None
        self.samples.append((max(t, 0.0), self.state_port.Eval(context).copy(),
                             self.odometry_port.Eval(context).copy(),
                             self.ranges_port.Eval(context).copy(),
                             int(round(self.mode_port.Eval(context)[0])), image))

    def frames(self) -> dict:
        """The samples as arrays: ``t``, ``state``, ``odometry``, ``ranges``,
        ``mode`` and ``image`` (None without a camera)."""
        s = self.samples
        images = [x[5] for x in s]
        return {"t": np.array([x[0] for x in s]),
                "state": np.array([x[1] for x in s]).reshape(-1, 5),
                "odometry": np.array([x[2] for x in s]).reshape(-1, 5),
                "ranges": np.array([x[3] for x in s]).reshape(len(s), -1),
                "mode": np.array([x[4] for x in s], np.int64),
                "image": np.stack(images) if images and images[0] is not None else None}
