"""ReachabilityEstimator: RE as a Drake system (10 Hz sample and hold).

A thin wrapper over :class:`topodrake.learning.reachability.estimator.Reachability`
with the same timing and target cache as ``WaypointNet`` (both derive from
:class:`~topodrake.systems.waypoint_net.TargetConditionedNet`): the held
observation and the target's cached first-layer half give one probability
per control period. Output ``probability`` (1): 0 without a target.
"""

from __future__ import annotations

import numpy as np

from topodrake.systems.waypoint_net import TargetConditionedNet


class ReachabilityEstimator(TargetConditionedNet):
    """Inputs ``observation`` (camera image or lidar ranges) and ``target``
    (:class:`~topodrake.learning.waypoint.policy.TargetContext`); output
    ``probability``: the estimated probability that the controller RE was
    trained for reaches the target from here."""

    def __init__(self, reachability, period: float = 0.1, camera=None, lidar=None):
        if reachability.observation == "pose":
            raise ValueError("ReachabilityEstimator needs a camera or lidar RE")
        self.reachability = reachability
        super().__init__(reachability, period, camera, lidar, state_input=False)
        self.probability_port = self.DeclareVectorOutputPort(
            "probability", 1, lambda c, o: o.SetFromVector(self.prediction(c)[:1]),
            prerequisites_of_calc=self.prediction_ticket)

    def empty(self) -> np.ndarray:
        return np.zeros(1)

    def compute(self, observation, features) -> np.ndarray:
        return self.reachability.probability(observation, features)
