"""OdometrySensor and OdometryFrame: wheel odometry that drifts, in the Drake diagram.

The batched engine's odometry (:class:`topodrake.odometry.Odometry`) as
Drake systems, so the navigation diagram's follower, C_WP and manoeuvres
read what a real car measures rather than its true pose:

* :class:`OdometrySensor` integrates each period's true motion of the held
  car state, scaled and biased by the car's systematic errors
  (:func:`topodrake.odometry.odometry_step`), onto its odometry pose.
  Its ``odometry`` output is the held state with the pose replaced by the
  odometry pose (speed and steering as measured).
* :class:`OdometryFrame` carries a waypoint given in the odometry frame
  (where the follower put it, relative to the odometry pose) over to the
  world frame the RMP drives in, relative to the true pose: the car drives
  toward the waypoint where it sits relative to itself
  (:func:`topodrake.odometry.odometry_to_world`, as the engine does).

Timing (10 Hz, sample and hold, as the ZeroOrderHold): the output during
period k composes the committed odometry pose with the increment from the
last committed true pose to the held state of period k; the periodic
update at the start of period k + 1 (simultaneous with the hold's sample,
so it reads period k's held state) commits it. This integrates exactly the
increments the engine integrates, in the same order.
"""

from __future__ import annotations

import numpy as np
from pydrake.systems.framework import BasicVector, EventStatus, LeafSystem

from topodrake.odometry import OdometryConfig, odometry_errors, odometry_step, odometry_to_world

# discrete state: the committed odometry pose, the true pose it belongs to, the car's errors
_ODO, _TRUE, _ERR = slice(0, 3), slice(3, 6), slice(6, 9)


class OdometrySensor(LeafSystem):
    """Input ``state`` (held car state, 5); output ``odometry`` (5). Set a
    run's start and its errors with :meth:`set_start` after the context's
    reset (the default context starts at the origin, without errors)."""

    def __init__(self, config: OdometryConfig, period: float = 0.1):
        super().__init__()
        self.config = config.check()
        self.period = float(period)
        self.state_port = self.DeclareVectorInputPort("state", 5)
        self.memory = self.DeclareDiscreteState(9)
        self.odometry_port = self.DeclareVectorOutputPort(
            "odometry", 5, self._out,
            prerequisites_of_calc={self.input_port_ticket(self.state_port.get_index()),
                                   self.xd_ticket()})
        self.DeclarePeriodicDiscreteUpdateEvent(self.period, 0.0, self._commit)

    def set_start(self, context, start, seed: int) -> None:
        """Start the odometry at the true pose ``start`` with the errors of ``seed``."""
        start = np.asarray(start, np.float64)[:3]
        errors = odometry_errors(self.config, [int(seed)])[0]
        context.get_mutable_discrete_state(self.memory).SetFromVector(
            np.concatenate([start, start, errors]))

    def _pose(self, context) -> np.ndarray:
        m = context.get_discrete_state(self.memory).get_value()
        held = np.asarray(self.state_port.Eval(context))[None, :3]
        return odometry_step(m[None, _ODO], m[None, _TRUE], held, m[None, _ERR])[0]

    def _out(self, context, output: BasicVector) -> None:
        held = np.asarray(self.state_port.Eval(context))
        output.SetFromVector(np.concatenate([self._pose(context), held[3:5]]))

    def _commit(self, context, discrete_state):
        if context.get_time() < 0.5 * self.period:
            return EventStatus.DidNothing()      # the hold has sampled nothing yet
        m = np.array(context.get_discrete_state(self.memory).get_value())
        m[_ODO] = self._pose(context)
        m[_TRUE] = np.asarray(self.state_port.Eval(context))[:3]
        discrete_state.get_mutable_vector(self.memory).SetFromVector(m)
        return EventStatus.Succeeded()


class OdometryFrame(LeafSystem):
    """Inputs ``waypoint`` (2, odometry frame; NaN: stop), ``odometry`` (5)
    and ``state`` (held true car state, 5); output ``waypoint`` (2, world)."""

    def __init__(self):
        super().__init__()
        self.waypoint_in_port = self.DeclareVectorInputPort("waypoint", 2)
        self.odometry_port = self.DeclareVectorInputPort("odometry", 5)
        self.state_port = self.DeclareVectorInputPort("state", 5)
        self.waypoint_port = self.DeclareVectorOutputPort("waypoint", 2, self._out)

    def _out(self, context, output: BasicVector) -> None:
        wp = np.asarray(self.waypoint_in_port.Eval(context))[None, None]
        odo = np.asarray(self.odometry_port.Eval(context))[None]
        car = np.asarray(self.state_port.Eval(context))[None]
        output.SetFromVector(odometry_to_world(wp, odo, car)[0, 0])
