"""CarPlant (continuous bicycle dynamics) and ActuationNoise."""

from __future__ import annotations

import numpy as np
from pydrake.systems.framework import BasicVector, LeafSystem

from topodrake.vehicle import VehicleConfig, clamp_state, vehicle_derivatives


class CarPlant(LeafSystem):
    """Continuous state ``x, y, theta, v, steer``; input ``controls`` (a, sigma).

    Integrate with a fixed-step RK2 at ``h = config.dt``; a periodic
    unrestricted update clamps speed and steering each period, which makes
    the Drake run step-for-step equal to :func:`topodrake.vehicle.vehicle_step`.
    """

    def __init__(self, config: VehicleConfig | None = None, initial_state=None):
        super().__init__()
        self.config = config or VehicleConfig()
        x0 = np.zeros(5) if initial_state is None else np.asarray(initial_state, float)
        self.state_index = self.DeclareContinuousState(BasicVector(x0), 3, 2, 0)
        self.controls_port = self.DeclareVectorInputPort("controls", 2)
        self.state_port = self.DeclareStateOutputPort("state", self.state_index)
        self.pose_port = self.DeclareVectorOutputPort(
            "pose", 3, self._calc_pose, prerequisites_of_calc={self.xc_ticket()})
        self.DeclarePeriodicUnrestrictedUpdateEvent(self.config.dt, 0.0, self._clamp)

    def DoCalcTimeDerivatives(self, context, derivatives):
        x = context.get_continuous_state_vector().CopyToVector()
        u = self.controls_port.Eval(context)
        derivatives.get_mutable_vector().SetFromVector(
            vehicle_derivatives(x[None], u[None], self.config)[0])

    def _calc_pose(self, context, output):
        output.SetFromVector(context.get_continuous_state_vector().CopyToVector()[:3])

    def _clamp(self, context, state):
        x = context.get_continuous_state_vector().CopyToVector()
        state.get_mutable_continuous_state().get_mutable_vector().SetFromVector(
            clamp_state(x[None], self.config)[0])


class ActuationNoise(LeafSystem):
    """``noisy = controls * (1 + std * w)``; ``w`` is standard-normal noise from a
    Drake ``RandomSource`` (sample-and-hold, one sample per control period),
    seeded through the context with ``diagram.SetRandomContext``."""

    def __init__(self, std: float = 0.33):
        super().__init__()
        self.std = float(std)
        self.controls_port = self.DeclareVectorInputPort("controls", 2)
        self.noise_port = self.DeclareVectorInputPort("standard_normal", 2)
        self.output_port = self.DeclareVectorOutputPort(
            "noisy_controls", 2, self._calc, prerequisites_of_calc={
                self.input_port_ticket(p.get_index())
                for p in (self.controls_port, self.noise_port)})

    def _calc(self, context, output):
        u = self.controls_port.Eval(context)
        w = self.noise_port.Eval(context)
        output.SetFromVector(u * (1.0 + self.std * w))
