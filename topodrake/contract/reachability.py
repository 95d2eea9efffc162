"""The RE contract: what a reachability estimator offers the follower and the map.

A :class:`ReachabilityModel` answers "how likely does the local controller
reach this target from here?" in the same two steps as a waypoint policy:
``encode_target(context)`` once per target, then
``probability(observation, target)`` (N,) in [0, 1] per observation. The
learned RE (:class:`topodrake.learning.reachability.estimator.Reachability`)
and the geometric oracle implement it.
"""

from __future__ import annotations

from typing import Any, Protocol, runtime_checkable

import numpy as np

__all__ = ["ReachabilityModel"]


@runtime_checkable
class ReachabilityModel(Protocol):
    """What an RE offers: its observation kind and context, and probabilities."""

    observation: str      # "camera" | "lidar" | "pose"
    k: int
    frame_step: int

    def encode_target(self, context: np.ndarray) -> Any: ...

    def probability(self, observation: np.ndarray, target: Any) -> np.ndarray: ...
