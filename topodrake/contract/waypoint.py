"""The C_WP contract: what a waypoint policy offers the follower.

A :class:`WaypointPolicy` answers "where should the car drive next to reach
this target?" in two steps, so the target side can be cached while the car
follows one anchor:

* ``encode_target(context)`` takes the target's context, (N, 2k+1, ...)
  observations of the kind named by ``policy.observation`` (``"camera"``:
  uint8 images (H, W, 3); ``"lidar"``: ranges (beams,); ``"pose"``: car poses
  (3,), the oracle's privileged input), and returns opaque target features;
* ``predict(observation, target)`` takes the current observations (N, ...)
  (or one, shared by N targets) and returns a :class:`WaypointPrediction`:
  the waypoint in the car frame, the heading difference and both overlaps
  (and controls for the direct-control baseline).

The follower hands targets around as :class:`TargetContext` (a key that
changes whenever the target changes, plus the context's observations and,
when known, poses); :func:`target_input` picks what a policy consumes.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

import numpy as np

from topodrake.errors import TopodrakeError

__all__ = ["TargetContext", "WaypointPolicy", "WaypointPrediction", "target_input"]


@dataclass
class WaypointPrediction:
    waypoint: np.ndarray              # (N, 2) car frame (m)
    heading_diff: np.ndarray          # (N,) target minus current heading (rad)
    overlap: np.ndarray               # (N, 2) R_cur->tgt, R_tgt->cur in [0, 1]
    controls: np.ndarray | None = None  # (N, 2) accel, steering rate (direct-control baseline)


@dataclass
class TargetContext:
    """A target as the follower sees it: 2k + 1 context frames, past to future.

    A sender that already ran a policy (``by``) may pass on what it has:
    ``features``, its ``encode_target`` of this context (1, ...), and
    ``prediction``, its answer for the observation ``observed`` (the image
    or scan, or the pose for a pose policy). A receiver uses them only if it
    runs that same policy, and the prediction only for that very
    observation."""

    key: int = -1                            # changes whenever the target changes; -1 = none
    observations: np.ndarray | None = None   # (2k+1, H, W, 3) uint8 or (2k+1, beams)
    poses: np.ndarray | None = None          # (2k+1, 3) when known (oracle)
    by: Any = None
    features: Any = None
    prediction: WaypointPrediction | None = None
    observed: np.ndarray | None = None


@runtime_checkable
class WaypointPolicy(Protocol):
    """What a C_WP offers the follower. Optional attributes: ``track_size``
    (per-car tracking state, a stateful C_WP) and ``sure_follow_m`` (the
    follower's ``TrackerConfig.sure_follow_m`` where that is None)."""

    observation: str      # "camera" | "lidar" | "pose"
    k: int
    frame_step: int

    def encode_target(self, context: np.ndarray) -> Any: ...

    def predict(self, observation: np.ndarray, target: Any) -> WaypointPrediction: ...


def target_input(policy: WaypointPolicy, target: TargetContext) -> np.ndarray:
    """The (1, 2k+1, ...) array of ``target`` that ``policy.encode_target`` takes."""
    arr = target.poses if policy.observation == "pose" else target.observations
    if arr is None:
        what = "poses" if policy.observation == "pose" else f"{policy.observation} observations"
        raise TopodrakeError(f"target {target.key} has no {what} for this policy")
    arr = np.asarray(arr)
    if len(arr) != 2 * policy.k + 1:
        raise TopodrakeError(f"target {target.key} has {len(arr)} context frames; the policy "
                             f"needs 2k + 1 = {2 * policy.k + 1}")
    return arr[None]
