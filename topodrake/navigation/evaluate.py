"""The networks the follower asks, for a batch of (car, anchor) queries.

:func:`encode_route` computes each anchor's target features once per route
(C_WP's and RE's; a network with a shorter context than the route's takes
the middle frames). :class:`Evaluator` answers
:func:`topodrake.navigation.follower.follower_step`'s queries from the cars'
current observations and those cached features; both executors (the Drake
``FollowerFsm`` and the batched engine) build one per period.

A stateful C_WP (one with ``track_size`` > 0, e.g. the registration
controller of :mod:`topodrake.registration.policy`) keeps (N, S) floats per
car, ``FollowerState.track`` (:func:`initial_track` makes them). The
executor hands the Evaluator a copy of the batch's rows and the cars'
odometry poses (the integrated pose, :mod:`topodrake.odometry`), and
stores the rows back after the period (:attr:`Evaluator.track`). Each C_WP
query then goes to ``policy.predict_tracked(observations, target features,
track, cars, keys, odometry)``, which answers like ``predict`` and updates
``track[cars]`` in place; ``keys`` name the anchors (rows of the route
features). Such a policy reads only observations and the motion between
odometry poses, never the poses themselves.
:class:`GeometricReachability` is a privileged pose oracle for RE (tests
and oracle studies), the counterpart of the A* oracle for C_WP.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from topodrake.contract.frames import centre_pose
from topodrake.contract.route import LEG_POINTS
from topodrake.errors import TopodrakeError
from topodrake.navigation.follower import Answers
from topodrake.navigation.tracker import pad_points, route_frames
from topodrake.registration.icp import IcpConfig, register_points, scan_points
from topodrake.sensing.config import CameraConfig, LidarConfig
from topodrake.sensing.overlap import mutual_overlap

# the tracker's scan fixes: a fit from the tracked pose (close to the truth: a looser
# overlap than a search), and the weakest translation constraint that pins it
SCAN_ICP = IcpConfig(min_inlier=0.45, max_shift_m=0.5, max_turn_rad=0.35)
SCAN_PINNED = 0.05


def network_context(route_contexts: np.ndarray, route_k: int, route_step: int, network) -> np.ndarray:
    """The (A, 2k+1, ...) part of a route's contexts that ``network`` reads."""
    k = network.k
    if k == route_k and (k == 0 or network.frame_step == route_step):
        return route_contexts
    if k > route_k or (k > 0 and network.frame_step != route_step):
        raise TopodrakeError(f"the route's contexts (k={route_k}, frame step {route_step}) do not "
                             f"hold the k={k}, frame step {network.frame_step} context of "
                             f"{getattr(network, 'name', '') or network.observation} network")
    return route_contexts[:, route_k - k:route_k + k + 1]


@dataclass
class RouteFeatures:
    """Per-anchor target features of one route, or of many stacked (with
    ``offsets``: route i's anchors are rows offsets[i]:offsets[i+1]), and
    each anchor's pose in its segment of the routes' legs
    (:func:`topodrake.navigation.tracker.route_frames`; none: no legs)."""
    cwp: object
    re: object
    offsets: np.ndarray
    frames: np.ndarray | None = None
    segments: np.ndarray | None = None
    approach: np.ndarray | None = None
    scans: np.ndarray | None = None       # (A, beams) each anchor's taught lidar scan
                                          # (lidar routes), for the tracker's scan fixes

    @property
    def n_anchors(self) -> np.ndarray:
        return np.diff(self.offsets)


def _concat(parts: list):
    """Features (torch tensors or numpy arrays) stacked along rows."""
    if hasattr(parts[0], "index_select"):
        import torch
        return _pixels_last(torch.cat(parts))
    return np.concatenate(parts)


def _pixels_last(feats):
    """Camera features (A, 2k+1, C0, H, W) stored channels-last: each pixel's
    C0 channels side by side in memory (the shape stays). The networks add
    the current image's half into a channels-last buffer, which from NCHW
    rows is a slow strided copy (about 1 ms per period at batch one)."""
    if feats.dim() != 5 or _is_pixels_last(feats):
        return feats
    return feats.permute(0, 1, 3, 4, 2).contiguous().permute(0, 1, 4, 2, 3)


def _is_pixels_last(feats) -> bool:
    return feats.dim() == 5 and feats.permute(0, 1, 3, 4, 2).is_contiguous()


def _encode(network, contexts: np.ndarray, batch: int = 64):
    return _concat([network.encode_target(contexts[lo:lo + batch])
                    for lo in range(0, len(contexts), batch)])


def encode_routes(routes, policy, reach, route_k: int | None = None,
                  route_step: int | None = None, legs_m: float = 0.0) -> RouteFeatures:
    """Target features of every anchor of ``routes`` for C_WP ``policy`` and
    RE ``reach``. The routes' contexts were rendered with ``route_k`` and
    ``route_step`` (default: the larger k of the two networks, and its frame step).
    A pose oracle (observation ``"pose"``) on a route of images reads the
    anchors' poses (a privileged ablation: the route's own perception is
    left out, its anchors kept). With ``legs_m`` > 0 the hops without a
    taught leg take C_WP's (:func:`cwp_legs`)."""
    offsets = np.concatenate([[0], np.cumsum([len(r) for r in routes])]).astype(np.int64)
    sensed = [n for n in (policy, reach) if not _reads_poses(n, routes)]
    if route_k is None and sensed:
        wide = max(sensed, key=lambda n: n.k)
        route_k, route_step = wide.k, wide.frame_step
    ctx = None
    if sensed:
        for r in routes:
            if r.contexts.shape[1] != 2 * route_k + 1:
                raise TopodrakeError(f"a route has {r.contexts.shape[1]} context frames per "
                                     f"anchor; the follower's networks need {2 * route_k + 1}")
        ctx = np.concatenate([r.contexts for r in routes])

    def features(network):
        if _reads_poses(network, routes):
            poses = np.concatenate([r.poses for r in routes])
            return _encode(network, np.repeat(poses[:, None], 2 * network.k + 1, axis=1))
        return _encode(network, network_context(ctx, route_k, route_step, network))


    cwp = features(policy)
    legs = [(r.legs, r.leg_paths) for r in routes]
    if legs_m > 0 and track_size(policy) == 0:
        legs = cwp_legs(routes, policy, cwp, offsets, route_k, legs_m)
    frames, segments, approach = route_frames([lg for lg, _ in legs], [p for _, p in legs])
    scans = None
    if ctx is not None and routes and all(r.modality == "lidar" for r in routes):
        scans = np.asarray(ctx[:, route_k], np.float64)
    elif routes and all(r.scans is not None for r in routes) \
            and len({r.scans.shape[1] for r in routes}) == 1:
        scans = np.concatenate([r.scans for r in routes])
    return RouteFeatures(cwp, features(reach), offsets, frames, segments, approach, scans)


def cwp_legs(routes, policy, features, offsets: np.ndarray, route_k: int | None,
             max_m: float) -> list[tuple[np.ndarray, np.ndarray]]:
    """Each route's (legs, leg paths), its hops without a leg (a join, a
    reuse or the goal link the scans did not place, or any of them on a
    map without scans: NaN) filled with C_WP's
    answer from the anchor's own view toward the next anchor: the waypoint
    as the next anchor's position and the heading head as its heading,
    where that waypoint is shorter than ``max_m`` (farther, C_WP's waypoint
    is a direction along the way, not the target's place); the leg's path
    a straight line. ``features``: ``policy``'s target features of every
    anchor (rows ``offsets``)."""
    out = []
    for i, r in enumerate(routes):
        legs, paths = np.array(r.legs, np.float64), np.array(r.leg_paths, np.float64)
        hops = np.flatnonzero(~np.all(np.isfinite(legs), axis=1))
        if _reads_poses(policy, routes):             # a pose oracle: both anchors' poses known
            hops = hops[np.all(np.isfinite(r.poses[hops]), axis=1) &
                        np.all(np.isfinite(r.poses[hops + 1]), axis=1)]
            views = r.poses[hops]
        else:
            views = r.contexts[hops, route_k if route_k is not None else r.contexts.shape[1] // 2]
        if len(hops):
            pred = policy.predict(views, take_rows(features, offsets[i] + hops + 1))
            wp = np.asarray(pred.waypoint, np.float64)
            hd = np.asarray(pred.heading_diff, np.float64)
            near = np.hypot(wp[:, 0], wp[:, 1]) < max_m
            est = np.column_stack([wp, hd])[near]
            legs[hops[near]] = est
            paths = pad_points(paths, LEG_POINTS)
            frac = (np.arange(1, paths.shape[1] + 1) / paths.shape[1])[None, :, None]
            paths[hops[near]] = frac * est[:, None, :]
        out.append((legs, paths))
    return out


def _reads_poses(network, routes) -> bool:
    """A pose oracle on routes whose contexts are observations, not poses."""
    return network.observation == "pose" and any(r.modality != "pose" for r in routes)


def stack_features(a: RouteFeatures, b: RouteFeatures) -> RouteFeatures:
    """The features of ``a``'s routes followed by ``b``'s."""
    frames = segments = approach = scans = None
    if a.scans is not None and b.scans is not None:
        scans = np.concatenate([a.scans, b.scans])
    if a.frames is not None and b.frames is not None:
        frames = np.concatenate([a.frames, b.frames])
        shift = a.segments.max(initial=-1) + 1
        segments = np.concatenate([a.segments, np.where(b.segments >= 0, b.segments + shift, -1)])
        k = max(a.approach.shape[1], b.approach.shape[1])
        approach = np.concatenate([pad_points(a.approach, k), pad_points(b.approach, k)])
    return RouteFeatures(_concat([a.cwp, b.cwp]), _concat([a.re, b.re]),
                         np.concatenate([a.offsets, a.offsets[-1] + b.offsets[1:]]),
                         frames, segments, approach, scans)



def take_rows(feats, rows: np.ndarray):
    """Rows ``rows`` of route features (torch or numpy), keeping their layout."""
    rows = np.asarray(rows, np.int64)
    if len(rows) and np.all(np.diff(rows) == 1):
        return feats[rows[0]:rows[-1] + 1]      # consecutive anchors: a view, no copy
    if hasattr(feats, "index_select"):
        import torch
        index = torch.as_tensor(rows, dtype=torch.long)
        if _is_pixels_last(feats):          # gather in memory order, keep the layout
            return feats.permute(0, 1, 3, 4, 2).index_select(0, index).permute(0, 1, 4, 2, 3)
        return feats.index_select(0, index)
    return feats[rows]


def track_size(policy) -> int:
    """The per-car state size of a stateful C_WP (0: stateless)."""
    return int(getattr(policy, "track_size", 0) or 0)


def initial_track(policy, n: int) -> np.ndarray:
    """(n, track_size) initial per-car state of ``policy`` ((n, 0) when stateless)."""
    if track_size(policy) == 0:
        return np.zeros((n, 0))
    return np.asarray(policy.initial_track(n), np.float64).reshape(n, track_size(policy))


class Evaluator:
    """Answers for cars of one batch: ``observations`` (B, ...) (poses for
    pose oracles), ``route_of`` (B,) the route of each car in ``features``;
    for a stateful C_WP, ``track`` (B, S), the cars' state, updated in place
    (read it back from :attr:`track`), and ``odometry`` (B, 3), the cars'
    odometry poses (default: ``poses``). With the cars' lidar scans
    (``ranges`` (B, beams) of ``lidar``; lidar observations serve) on routes
    that keep their anchors' scans, :attr:`scan_fixes` registers them for
    the route tracker (:meth:`register_anchors`)."""
    def __init__(self, policy, reach, features: RouteFeatures, route_of: np.ndarray,
                 observations: np.ndarray, poses: np.ndarray | None = None,
                 track: np.ndarray | None = None, odometry: np.ndarray | None = None,
                 lidar: LidarConfig | None = None, ranges: np.ndarray | None = None):
        self.policy = policy
        self.reach = reach
        self.features = features
        self.start = features.offsets[np.asarray(route_of, np.int64)]
        self.observations = observations
        self.poses = poses
        self.stateful = track_size(policy) > 0
        self.track = None if track is None else np.array(track, np.float64)
        self.odometry = poses if odometry is None else np.asarray(odometry, np.float64)
        if self.stateful and (self.track is None or self.odometry is None):
            raise TopodrakeError("a stateful C_WP needs the cars' track state and odometry")
        # the tracker's scan fixes: lidar routes followed on lidar observations
        self.lidar = lidar or LidarConfig()
        beams = self.lidar.beams
        if ranges is None and observations is not None and np.ndim(observations) == 2 \
                and np.shape(observations)[1] == beams:
            ranges = observations
        self.ranges = ranges
        self._scans_register = features.scans is not None and ranges is not None \
            and np.shape(ranges)[1] == beams and features.scans.shape[1] == beams

    # Answers are methods of the class, never bound methods kept on the
    # instance: such a cycle would keep every period's Evaluator, and with it
    # the route features it holds (a GB for a camera batch), alive until a
    # full garbage collection; a replanning run would hold each version.
    @property
    def scan_fixes(self):
        """:meth:`register_anchors` where the cars' scans can be registered
        onto the routes' taught scans, else None."""
        return self.register_anchors if self._scans_register else None

    def leg_frames(self, cars: np.ndarray, anchors: np.ndarray
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Anchors' poses (M, 3) in their segments' frames, their segments
        (M,; -1: no known legs) and the taught poses of the hops into them
        (M, K, 3)."""
        rows = self.start[np.asarray(cars, np.int64)] + np.asarray(anchors, np.int64)
        f = self.features
        if f.frames is None:
            return np.zeros((len(rows), 3)), np.full(len(rows), -1), np.full((len(rows), 1, 3),
                                                                          np.nan)
        return f.frames[rows], f.segments[rows], f.approach[rows]

    @property
    def sure_follow_m(self) -> float:
        """The C_WP's own ``sure_follow_m`` for the follower (0: none)."""
        return float(getattr(self.policy, "sure_follow_m", 0.0) or 0.0)

    # the route tracker's frames (a stateful C_WP, the registration one, keeps its
    # own estimates too: its answers are fixes like any C_WP's)
    anchor_frames = leg_frames

    def register_anchors(self, cars: np.ndarray, anchors: np.ndarray, guess: np.ndarray
                         ) -> tuple[np.ndarray, np.ndarray]:
        """Each car's scan registered onto its anchor's taught scan from
        ``guess`` (M, 3), the car's predicted pose in the anchor's frame: the
        fitted poses (M, 3) and whether each fit passed and pins the
        translation (M,; a corridor leaves it free to slide)."""
        rows = self.start[np.asarray(cars, np.int64)] + np.asarray(anchors, np.int64)
        sp, sv = scan_points(np.asarray(self.ranges, np.float64)[cars], self.lidar)
        tp, tv = scan_points(self.features.scans[rows], self.lidar)
        fit = register_points(sp, sv, tp, tv, np.asarray(guess, np.float64), len(rows), SCAN_ICP)
        return fit.pose, fit.accepted & (fit.constraint >= SCAN_PINNED)

    def _obs(self, network, cars: np.ndarray) -> np.ndarray:
        if network.observation == "pose":
            return self.poses[cars]
        obs = self.observations[cars[0]][None] if np.all(cars == cars[0]) else self.observations[cars]
        return obs

    def __call__(self, cars: np.ndarray, anchors: np.ndarray, cwp: bool, re: bool) -> Answers:
        cars = np.asarray(cars, np.int64)
        rows = self.start[cars] + np.asarray(anchors, np.int64)
        m = len(rows)
        out = Answers(np.full((m, 2), np.nan), np.full((m, 2), np.nan), np.full(m, np.nan))
        if m == 0:
            return out
        if cwp and self.stateful:
            pred = self.policy.predict_tracked(self.observations[cars],
                                               take_rows(self.features.cwp, rows), self.track,
                                               cars, rows, self.odometry[cars],
                                               legs=self.leg_frames(cars, anchors)[:2])
        elif cwp:
            pred = self.policy.predict(self._obs(self.policy, cars),
                                       take_rows(self.features.cwp, rows))
        if cwp:
            out.waypoint = np.asarray(pred.waypoint, np.float64).reshape(m, 2)
            out.overlap = np.asarray(pred.overlap, np.float64).reshape(m, 2)
            out.heading = np.asarray(pred.heading_diff, np.float64).reshape(m)
        if re:
            p = np.asarray(self.reach.probability(self._obs(self.reach, cars),
                                                  take_rows(self.features.re, rows)), np.float64)
            out.probability = route_calibrated(self.reach, p.reshape(m))
        return out


def route_calibrated(reach, p: np.ndarray) -> np.ndarray:
    """RE's probability toward a route's anchors under the follower's own
    calibration (``reach.follower_platt``, fitted on rollouts from the
    states the follower visits) where the RE has one, else under the
    calibration of the hops that placed the anchors (``reach.anchor_platt``,
    fitted on pairs of frames of one drive), converted from the general one
    (temperature ``T``) that ``reach.probability`` applies. Oracles without
    these calibrations answer unchanged."""
    platt = getattr(reach, "follower_platt", None) or getattr(reach, "anchor_platt", None)
    temperature = getattr(reach, "temperature", None)
    if platt is None or temperature is None:
        return p
    with np.errstate(divide="ignore"):
        z = temperature * (np.log(p) - np.log1p(-p))          # the raw logit (+-inf when saturated)
    return 1.0 / (1.0 + np.exp(-(platt[0] * z + platt[1])))


class GeometricReachability:
    """A privileged RE from poses for the follower: ``p_max`` while the
    target is within ``reach_m`` of the car and in view of it (either camera
    overlap above ``min_overlap``), falling off with the extra distance over
    ``falloff_m``; ``p_hidden`` when out of view. Observation ``"pose"``.

    ``reach_m`` is the distance the A* oracle C_WP reaches: in its labelled
    rollouts (``studies/oracle_reach.py``) success does not fall with the
    distance up to 6 m where the target is in sight, only with the overlap,
    the line of sight and the bearing. The map's oracle is
    :class:`topodrake.topomap.scorer.OracleScorer`."""
    observation = "pose"

    def __init__(self, world, k: int = 0, frame_step: int = 3, reach_m: float = 6.0,
                 falloff_m: float = 0.5, p_max: float = 0.99, p_hidden: float = 0.3,
                 min_overlap: float = 0.05, camera=None):
        self.world = world
        self.k = k
        self.frame_step = frame_step
        self.reach_m = reach_m
        self.falloff_m = falloff_m
        self.p_max = p_max
        self.p_hidden = p_hidden
        self.min_overlap = min_overlap
        self.camera = camera or CameraConfig()

    def encode_target(self, context: np.ndarray) -> np.ndarray:
        return centre_pose(context, self.k)

    def probability(self, observation: np.ndarray, target) -> np.ndarray:
        poses = np.asarray(observation, np.float64).reshape(-1, 3)
        tgt = np.asarray(target, np.float64).reshape(-1, 3)
        poses, tgt = np.broadcast_arrays(poses, tgt)
        d = np.hypot(*(tgt[:, :2] - poses[:, :2]).T)
        seen = mutual_overlap(self.world, poses, tgt, self.camera).max(axis=1) > self.min_overlap
        p = self.p_max * np.exp(-np.maximum(d - self.reach_m, 0.0) / self.falloff_m)
        return np.where(seen, p, self.p_hidden)
