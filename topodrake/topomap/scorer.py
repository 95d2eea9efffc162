"""Reachability as the map asks it: any pair of kept frames, by row.

A map keeps the raw observations of its anchors' context frames in one
:class:`~topodrake.topomap.bank.FrameBank`. Building and planning ask
"does the controller get from the frame at row ``s`` to the target whose
context is rows ``c`` (2k+1)?" for batches of such pairs. A
:class:`MapScorer` answers from per-frame features computed once per frame:

* :class:`LearnedScorer` wraps the learned RE
  (:class:`~topodrake.learning.reachability.estimator.Reachability`): the features
  are the first layer's two halves of each image (and of its mirror image),
  the pairs use the RE's anchor-hop calibration (map edges are short hops);
* :class:`OracleScorer` is a privileged reachability from geometry (the
  observation is the pose): straight-line distance, heading change, line of
  sight and image overlap. It lets map tests run in seconds and separates
  perception errors from planning errors in studies.

Both carry an ``identity`` (content hashes of the RE and C_WP checkpoints,
or the oracle's name and parameters) that a map file records and checks.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Protocol

import numpy as np

from topodrake.errors import TopodrakeError
from topodrake.expert.sight import segment_clear
from topodrake.fileio import file_sha1
from topodrake.learning.reachability.controllers import controller_identity
from topodrake.sensing.overlap import mutual_overlap


class MapScorer(Protocol):
    observation: str        # "camera" | "lidar" | "pose"
    k: int
    frame_step: int
    identity: dict

    def features(self, observations: np.ndarray) -> dict: ...

    def score(self, feats: dict, source: np.ndarray, context_rows: np.ndarray) -> np.ndarray: ...


class LearnedScorer:
    """The learned RE over bank rows (``features``: first-layer halves)."""

    def __init__(self, reach, identity: dict | None = None):
        self.reach = reach
        self.observation = reach.observation
        self.k = reach.k
        self.frame_step = reach.frame_step
        self.sensor = reach.sensor
        self.identity = identity or {"reach": reach.name}

    @classmethod
    def from_checkpoints(cls, reach_path, controller_path) -> "LearnedScorer":
        from topodrake.learning.reachability.estimator import Reachability

        reach = Reachability.from_checkpoint(reach_path, controller_path)
        return cls(reach, {"reach": str(reach_path), "reach_sha1": file_sha1(reach_path),
                           "controller": str(controller_path),
                           "controller_sha1": controller_identity(controller_path)["sha1"]})

    def features(self, observations: np.ndarray) -> dict:
        ff = self.reach.frame_features(observations)
        out = {"current": ff.current, "target": ff.target}
        if ff.mirrored is not None:
            out["m_current"], out["m_target"] = ff.mirrored.current, ff.mirrored.target
        return out

    def score(self, feats: dict, source: np.ndarray, context_rows: np.ndarray) -> np.ndarray:
        from topodrake.learning.reachability.estimator import FrameFeatures

        mirrored = (FrameFeatures(feats["m_current"], feats["m_target"])
                    if "m_current" in feats else None)
        ff = FrameFeatures(feats["current"], feats["target"], mirrored)
        return self.reach.pairwise(ff, np.asarray(source), np.asarray(context_rows))


@dataclass
class OracleConfig:
    """The geometric oracle: ``p = p_max * s(reach_m - d) * s(bearing_rad -
    |bearing|) * s(turn_rad - |dtheta|) * s(overlap - min_overlap)``, each s a
    logistic of its softness, times ``hidden`` where no straight line keeps
    ``sight_clearance_m`` from walls (``d``: distance, ``bearing``: where the
    target lies seen from the source's heading, ``dtheta``: heading change,
    ``overlap``: the smaller mutual image overlap). Targets nearer than
    ``reverse_m`` are rated whatever their bearing: the follower reverses
    onto them (its manoeuvres), as the expert's turns on the spot and
    three-point turns do, where the fitted controller alone did not.

    The defaults are the map's oracle: the shape of :data:`CALIBRATED_ORACLE`
    with every softness sharp and the ceiling ``p_max`` above the map's 0.99
    thresholds (docs/results.md and docs/limits.md, "The geometric oracle RE").
    """

    p_max: float = 0.9995
    reach_m: float = 10.0
    reach_soft_m: float = 0.1
    bearing_rad: float = 3.2
    bearing_soft_rad: float = 0.2
    reverse_m: float = 1.0
    turn_rad: float = 2.0
    turn_soft_rad: float = 0.2
    min_overlap: float = 0.0
    overlap_soft: float = 0.1
    hidden: float = 0.2
    sight_clearance_m: float = 0.12


#: The oracle fitted (maximum likelihood) to labelled rollouts of the A*
#: oracle C_WP in the five test houses (``python studies/oracle_reach.py``).
CALIBRATED_ORACLE = OracleConfig(p_max=0.9995, reach_m=10.0, reach_soft_m=0.2, bearing_rad=3.2,
                                 bearing_soft_rad=0.8, turn_rad=2.0, turn_soft_rad=0.4,
                                 min_overlap=0.02, overlap_soft=0.01, hidden=0.5,
                                 reverse_m=0.0)


#: The same fit with every softness held sharp (at most 0.2): more than 0.99
#: where the controller is at its best (over-confident by design); the trust
#: of the follower's oracle RE (docs/limits.md, "The geometric oracle RE").
TRUSTING_ORACLE = OracleConfig(p_max=0.9995, reach_m=10.0, reach_soft_m=0.1, bearing_rad=3.2,
                               bearing_soft_rad=0.2, turn_rad=2.0, turn_soft_rad=0.2,
                               min_overlap=0.0, overlap_soft=0.1, hidden=0.2, reverse_m=0.0)


def _logistic(x: np.ndarray) -> np.ndarray:
    return 0.5 * (1.0 + np.tanh(0.5 * x))


def pair_geometry(world, a: np.ndarray, b: np.ndarray, sight_clearance_m: float = 0.12,
                  rows: np.ndarray | None = None) -> dict:
    """What the geometric oracle reads of poses ``a`` -> ``b`` (N, 3):
    ``distance``, ``turn`` (absolute heading change), ``bearing`` (absolute
    angle of the target off the source's heading), and for ``rows`` (default
    all; NaN / False elsewhere) ``overlap`` (the smaller mutual image
    overlap) and ``sight`` (a straight line keeping ``sight_clearance_m``)."""
    a = np.asarray(a, np.float64).reshape(-1, 3)
    b = np.asarray(b, np.float64).reshape(-1, 3)
    a, b = np.broadcast_arrays(a, b)
    delta = b[:, :2] - a[:, :2]
    d = np.hypot(*delta.T)
    ahead = delta[:, 0] * np.cos(a[:, 2]) + delta[:, 1] * np.sin(a[:, 2])
    side = -delta[:, 0] * np.sin(a[:, 2]) + delta[:, 1] * np.cos(a[:, 2])
    out = {"distance": d,
           "turn": np.abs((b[:, 2] - a[:, 2] + np.pi) % (2 * np.pi) - np.pi),
           "bearing": np.where(d > 1e-9, np.abs(np.arctan2(side, ahead)), 0.0),
           "overlap": np.full(len(a), np.nan), "sight": np.zeros(len(a), bool)}
    rows = np.arange(len(a)) if rows is None else np.asarray(rows, np.int64)
    if len(rows):
        g = world.grid
        clear, (ox, oy), res = g.clearance, g.origin, g.resolution
        out["sight"][rows] = [bool(segment_clear(clear, ox, oy, res, sight_clearance_m,
                                                 *a[i, :2], *b[i, :2])) for i in rows]
        out["overlap"][rows] = mutual_overlap(world, a[rows], b[rows]).min(axis=1)
    return out


def _shape(g: dict, c: OracleConfig) -> np.ndarray:
    """The oracle's factors that need neither overlap nor sight."""
    p = (c.p_max * _logistic((c.reach_m - g["distance"]) / c.reach_soft_m)
         * _logistic((c.turn_rad - g["turn"]) / c.turn_soft_rad))
    if math.isfinite(c.bearing_rad):
        behind = 1.0 - _logistic((c.bearing_rad - g["bearing"]) / c.bearing_soft_rad)
        if c.reverse_m > 0.0:
            behind = behind * _logistic((g["distance"] - c.reverse_m) / c.reach_soft_m)
        p = p * (1.0 - behind)
    return p


def reach_from_geometry(g: dict, config: OracleConfig) -> np.ndarray:
    """The oracle's probability from :func:`pair_geometry` (every row's
    overlap and sight known)."""
    c = config
    p = _shape(g, c) * np.where(g["sight"], 1.0, c.hidden)
    p = p * _logistic((g["overlap"] - c.min_overlap) / c.overlap_soft)
    p[(g["distance"] < 1e-9) & (g["turn"] < 1e-6)] = c.p_max
    return p


def geometric_reach(world, a: np.ndarray, b: np.ndarray, config: OracleConfig) -> np.ndarray:
    """p(the oracle controller at poses ``a`` (N, 3) reaches poses ``b`` (N, 3))
    under ``config`` (:class:`OracleConfig`); overlap and sight are computed
    only where the other factors leave more than 1e-4."""
    a, b = np.broadcast_arrays(np.asarray(a, np.float64).reshape(-1, 3),
                               np.asarray(b, np.float64).reshape(-1, 3))
    g = pair_geometry(world, a, b, config.sight_clearance_m, rows=np.zeros(0, np.int64))
    near = np.flatnonzero(_shape(g, config) > 1e-4)
    if len(near):
        sub = pair_geometry(world, a[near], b[near], config.sight_clearance_m)
        g["overlap"][near], g["sight"][near] = sub["overlap"], sub["sight"]
    g["overlap"] = np.nan_to_num(g["overlap"], nan=-1.0)     # (far: the shape is ~0 anyway)
    return reach_from_geometry(g, config)


class OracleScorer:
    """Privileged reachability from the poses (``observation = "pose"``):
    reads the source pose and the context's centre pose only."""
    observation = "pose"

    def __init__(self, world, k: int = 5, frame_step: int = 3, config: OracleConfig | None = None):
        self.world = world
        self.k = k
        self.frame_step = frame_step
        self.sensor = None
        self.config = config or OracleConfig()
        self.identity = {"reach": "oracle-geometry", "config": asdict(self.config)}

    def features(self, observations: np.ndarray) -> dict:
        poses = np.asarray(observations, np.float64)
        if poses.ndim != 2 or poses.shape[1] != 3:
            raise TopodrakeError(f"the oracle's observations are poses (N, 3), got {poses.shape}")
        return {"pose": poses}

    def probability(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """p(car at poses ``a`` (N, 3) reaches poses ``b`` (N, 3))."""
        return geometric_reach(self.world, a, b, self.config)

    def score(self, feats: dict, source: np.ndarray, context_rows: np.ndarray) -> np.ndarray:
        poses = feats["pose"]
        rows = np.asarray(context_rows, np.int64).reshape(len(source), -1)
        return self.probability(poses[np.asarray(source, np.int64)], poses[rows[:, rows.shape[1] // 2]])
