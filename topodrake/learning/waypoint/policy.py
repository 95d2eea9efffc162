"""Waypoint policies: the learned C_WP and the A* oracle.

Both implement :class:`topodrake.contract.waypoint.WaypointPolicy`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from topodrake.contract.frames import centre_pose, context_frames
from topodrake.contract.waypoint import (
    TargetContext,
    WaypointPolicy,
    WaypointPrediction,
    target_input,
)
from topodrake.learning.inference import ObservationNetwork
from topodrake.learning.networks import CONTROL_SCALE
from topodrake.learning.samples import expert_waypoint_labels, wrap_angle
from topodrake.sensing.config import CameraConfig, LidarConfig
from topodrake.sensing.overlap import mutual_overlap

__all__ = ["AStarOracle", "LearnedWaypointPolicy", "TargetContext", "WaypointPolicy",
           "WaypointPrediction", "make_target_context", "target_input"]


# ---------------------------------------------------------------- learned

class LearnedWaypointPolicy(ObservationNetwork):
    """C_WP from a trained :class:`WaypointNetwork` (batched; cached target features).

    ``encode_target`` returns the target half of the first layer, a tensor
    (N, 2k+1, C0, ...) (``.numpy()`` it to keep it in a Drake abstract
    state); ``predict`` adds the current observation's half, computed once.
    ``predict_naive`` runs the full network on the stacked pairs (for tests
    and benchmarks).
    """

    @classmethod
    def from_checkpoint(cls, path, *, modality: str | None = None, k: int | None = None,
                        output: str | None = None, camera: CameraConfig | None = None,
                        lidar: LidarConfig | None = None) -> "LearnedWaypointPolicy":
        """Load a checkpoint, refusing one trained for another sensor, k or output."""
        from topodrake.learning.checkpoint import load_checkpoint

        ck = load_checkpoint(path, modality=modality, k=k, output=output, camera=camera, lidar=lidar)
        return cls(ck.model, ck.sensor, name=Path(path).parent.name)

    @property
    def is_direct_control(self) -> bool:
        return self.cfg.output == "control"

    @torch.inference_mode()
    def predict(self, observation: np.ndarray, target) -> WaypointPrediction:
        cur = self.to_input(np.asarray(observation))
        tgt = torch.as_tensor(target)
        return self._prediction(self.plan.cached(cur, tgt))

    @torch.inference_mode()
    def predict_naive(self, observation: np.ndarray, context: np.ndarray) -> WaypointPrediction:
        cur = self.to_input(np.asarray(observation))
        ctx = self.to_input(np.asarray(context))
        if cur.shape[0] == 1 and ctx.shape[0] > 1:
            cur = cur.expand(ctx.shape[0], *cur.shape[1:])
        return self._prediction(self.plan.naive(cur, ctx))

    @staticmethod
    def _prediction(out: dict) -> WaypointPrediction:
        h = out["heading"]
        controls = out.get("control")
        return WaypointPrediction(
            out["waypoint"].numpy().astype(np.float64),
            torch.atan2(h[:, 1], h[:, 0]).numpy().astype(np.float64),
            torch.sigmoid(out["overlap_logits"]).numpy().astype(np.float64),
            None if controls is None else controls.numpy().astype(np.float64) * CONTROL_SCALE)


# ---------------------------------------------------------------- oracle

class AStarOracle:
    """The privileged A* oracle: the same labels the network is trained on,
    computed from poses (waypoint: A* from the car to the target's centre
    frame, expert lookahead, shortened to the target distance; heading
    difference; geometric mutual overlap)."""

    observation = "pose"

    def __init__(self, world, k: int = 0, frame_step: int = 3, camera: CameraConfig | None = None,
                 lookahead_m: float = 5.0, overlap_rays: int = 100, start_snap_m: float = 0.3):
        self.world = world
        self.k = k
        self.frame_step = frame_step
        self.camera = camera or CameraConfig()
        self.lookahead_m = lookahead_m
        self.overlap_rays = overlap_rays
        self.start_snap_m = start_snap_m   # a car in a wall's margin drives out along A*

    def encode_target(self, context: np.ndarray) -> np.ndarray:
        return centre_pose(context, self.k)

    def predict(self, observation: np.ndarray, target) -> WaypointPrediction:
        poses = np.asarray(observation, np.float64).reshape(-1, 3)
        tgt = np.asarray(target, np.float64).reshape(-1, 3)
        if len(tgt) == 1 and len(poses) > 1:
            tgt = np.repeat(tgt, len(poses), axis=0)
        if len(poses) == 1 and len(tgt) > 1:
            poses = np.repeat(poses, len(tgt), axis=0)
        wp, valid = expert_waypoint_labels(self.world, poses, tgt[:, :2], self.lookahead_m,
                                           start_snap_m=self.start_snap_m)
        if not valid.all():
            # no A* path (deeper in a wall's margin than start_snap_m): aim straight at the target
            d = tgt[~valid, :2] - poses[~valid, :2]
            c, s = np.cos(poses[~valid, 2]), np.sin(poses[~valid, 2])
            wp[~valid] = np.column_stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]])
        ov = mutual_overlap(self.world, poses, tgt, self.camera, self.overlap_rays)
        return WaypointPrediction(wp, wrap_angle(tgt[:, 2] - poses[:, 2]), ov)


def make_target_context(world, trajectory_poses: np.ndarray, j: int, k: int, *,
                        frame_step: int = 3, modality: str = "camera",
                        camera: CameraConfig | None = None, lidar: LidarConfig | None = None,
                        key: int = 0) -> TargetContext:
    """The :class:`TargetContext` of frame ``j`` of a trajectory: its 2k + 1
    context poses and their rendered observations (camera images or lidar
    ranges; ``modality="pose"`` renders nothing)."""
    poses = np.asarray(trajectory_poses, np.float64)[context_frames(len(trajectory_poses), j, k,
                                                                    frame_step)]
    obs = None
    if modality != "pose":
        from topodrake.sensing.observe import observe
        obs = observe(world, modality, poses, camera if modality == "camera" else lidar)
    return TargetContext(key=key, observations=obs, poses=poses)
