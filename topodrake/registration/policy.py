"""RegistrationPolicy: a lidar C_WP that repeats taught scans by registering against them.

Teach and repeat, with no training. An anchor's context (2k + 1 lidar scans
``frame_step`` periods apart along the drive that taught it) is the taught
path near the anchor. ``encode_target`` registers each context frame to its
neighbour (:func:`topodrake.registration.icp.register`) and chains the
results outward from the centre frame: the taught frames' poses in the
anchor's frame (the centre frame's car frame), from the scans alone. A link
whose walls leave the fit free to slide (a corridor) starts again from the
motion of the nearest well-pinned link, and frames past a link that fails
the result check are left out.

Per car the policy keeps a small tracking state (``track_size`` floats,
carried in ``FollowerState.track`` by both executors; see
:mod:`topodrake.navigation.evaluate`): up to ``slots`` anchors, each with
the car's estimated pose in that anchor's frame, the odometry pose the
estimate belongs to, the last overlaps and a count of failed registrations.
A query toward an anchor (``predict_tracked``):

1. moves the anchor's estimate by the odometry since it was made (the
   relative motion between the two odometry poses, optionally with
   ``odometry_error``: a scale error of translation and rotation);
2. registers the current scan against the taught frames nearest that
   prediction, warm-started from it; a fresh anchor (or one lost for
   ``relocalise_after`` periods) is also tried from every taught frame and
   from ``behind_m`` behind the first one, each at the headings
   ``search_turns`` (every ``search_every`` periods while it stays lost);
3. keeps the best accepted fit (inlier share, residual, agreement with
   the prediction: :class:`~topodrake.registration.icp.IcpConfig`), or holds
   the odometry prediction when none passes; an estimate counts as confirmed
   after ``confirm`` periods in a row of fits that agreed with the odometry
   prediction and pinned the translation (a fit in a corridor slides along
   it: it keeps a confirmed estimate, but confirms none, and a search fit
   must be pinned, except, along a route's legs, the fit from the identity
   onto the anchor's own scan for a car that has no estimate yet: at the
   route's start the start link put the car at that view, and the walls
   pin what they can, ``start_slides``);
4. answers by pure pursuit along the taught path: the point ``lookahead_m``
   along the frames from the car's projection onto them, no farther than
   the anchor (centre frame), in the car frame; the heading difference to
   the anchor; as overlaps, the inlier shares of the scan against the
   anchor's own scan from the estimate (both ways), zero unless the fit is
   confirmed (a single fit may be wrong, and the follower marks anchors
   visited from the overlaps).

An anchor without an estimate, or one lost for ``relocalise_after``
periods, takes its prediction from the car's best-tracked anchor of the
same segment of the route's legs (VT&R's edge transforms: the teach
drive's odometry between the two anchors, ``legs`` of
``predict_tracked``; a route without legs has none): that anchor's estimate
moved by odometry and carried through the stored transform, with its
confirmation, so the handover needs no registration between taught frames
and holds along a corridor that pins no fit. Without legs, an anchor the
car asks about beside the anchor before it (the follower asks about the
next two) is linked to that one instead: the earlier anchor's last taught
frames and this one's first, frames of the same drive where the contexts
overlap, are registered to each other, and the car's prediction in the
earlier anchor's frame carries over. An anchor
without any estimate is approached along the exit of the taught path of the
nearest earlier anchor the car tracks (``exit_m`` on past its last frame;
the follower may have skipped the one just before), else straight ahead.
The policy reads the scans and the motion between odometry
poses, never the map or the car's true pose. ``predict`` (the stateless
:class:`~topodrake.learning.waypoint.policy.WaypointPolicy` call) answers each query
from a fresh state.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from topodrake.errors import TopodrakeError
from topodrake.contract.waypoint import WaypointPrediction
from topodrake.registration.icp import IcpConfig, Registration, register_points, scan_points
from topodrake.se2 import compose, invert, relative
from topodrake.sensing.config import LidarConfig

__all__ = ["RegistrationConfig", "RegistrationPolicy"]

# one tracking slot: anchor key, estimate (x, y, th), odometry pose (x, y, th),
# overlaps (current -> anchor, anchor -> current), failed registrations since the last fit,
# the pose of the anchor's last usable taught frame (where its taught path leaves it),
# consecutive fits that agreed with the odometry prediction, the anchor's segment of the
# route's legs and its pose in that segment's frame (the teach drive's odometry)
_KEY, _EST, _ODO, _OVL, _MISS, _EXIT, _HITS, _SEG, _FRAME = (
    0, slice(1, 4), slice(4, 7), slice(7, 9), 9, slice(10, 13), 13, 14, slice(15, 18))
SLOT = 18


@dataclass(frozen=True)
class RegistrationConfig:
    """The controller's settings."""

    k: int = 5                       # context frames either side of an anchor (2k + 1)
    frame_step: int = 3              # periods between context frames
    lookahead_m: float = 3.0        # pure-pursuit lookahead along the taught path
    exit_m: float = 3.0              # the approach goes on this far past the exit
    slots: int = 4                   # anchors tracked per car
    nearest: int = 2                 # taught frames registered against per query
    relocalise_after: int = 10       # failed periods before every frame is tried again
    behind_m: tuple[float, ...] = (0.5, 1.0)   # searched too: the car this far behind the
                                               # first taught frame (approaching the anchor)
    link_frames: int = 3             # frames at each end tried when linking two anchors
    search_turns: tuple[float, ...] = (0.0, -0.5, 0.5, -1.0, 1.0)   # headings tried (rad)
    search_back: float = 0.5         # a search fit also covers this share of the frame's points
    search_every: int = 3            # a lost anchor is searched every this many periods
    confirm: int = 3                 # fits agreeing with odometry before overlaps are reported
    agree_m: float = 0.15            # a fit agrees with the odometry prediction this closely
    agree_rad: float = 0.1
    odometry_error: tuple[float, float] = (0.0, 0.0)   # scale errors (translation, rotation)
    # tracking from the odometry prediction: close agreement, a looser overlap
    icp: IcpConfig = field(default_factory=lambda: IcpConfig(min_inlier=0.45, max_shift_m=0.3,
                                                             max_turn_rad=0.2))
    # searching without a prediction: a stricter overlap
    search_icp: IcpConfig = field(default_factory=IcpConfig)
    # two anchors' taught frames where their contexts overlap (a wrong link misleads
    # the tracking of the later anchor until it fails: demand a clear overlap)
    link_icp: IcpConfig = field(default_factory=lambda: IcpConfig(min_inlier=0.6, max_shift_m=0.75,
                                                                  max_turn_rad=0.5))
    # consecutive taught frames (a short move; a turn on the spot changes much of the view)
    teach_icp: IcpConfig = field(default_factory=lambda: IcpConfig(min_inlier=0.4, max_shift_m=1.0,
                                                                   max_turn_rad=0.6))
    slide_constraint: float = 0.05   # fits pinned less than this slide (corridors)
    handover: bool = True            # with the route's legs: a fresh or lost anchor's prediction
                                     # comes from the anchor tracked best, moved by the legs
    handover_m: float = 2.0          # ... when that anchor's estimate is this recent (m driven)
    search_check_m: float = 1.0      # with the route's legs: a search fit must also fit the scan
                                     # to a neighbouring anchor of the segment whose taught frames
                                     # it puts within this of the car (a corridor that repeats
                                     # fits one anchor metres off; 0: off)
    start_slides: bool = True        # with the route's legs: a car that has no estimate yet (the
                                     # route's start) takes the fit from the identity onto the
                                     # anchor's own scan even where it slides (the start link put
                                     # it at that view; the walls pin what they can)

    def check(self) -> "RegistrationConfig":
        if self.k < 0 or self.frame_step < 1:
            raise TopodrakeError(f"registration k must be >= 0 and frame_step >= 1, got "
                                 f"{self.k} and {self.frame_step}")
        if not (self.lookahead_m > 0 and self.exit_m > 0):
            raise TopodrakeError(f"registration lookahead_m and exit_m must be > 0, got "
                                 f"{self.lookahead_m} and {self.exit_m}")
        if self.slots < 2 or self.nearest < 1 or self.relocalise_after < 1 or self.confirm < 1:
            raise TopodrakeError("registration slots must be >= 2, nearest, relocalise_after and "
                                 "confirm >= 1")
        if not (self.agree_m > 0 and self.agree_rad > 0) or any(b <= 0 for b in self.behind_m):
            raise TopodrakeError("registration agree_m, agree_rad and behind_m must be > 0")
        if not (np.isfinite(self.search_check_m) and self.search_check_m >= 0):
            raise TopodrakeError(f"registration search_check_m must be >= 0 (0: off), got "
                                 f"{self.search_check_m}")
        if len(self.odometry_error) != 2 or not all(np.isfinite(self.odometry_error)):
            raise TopodrakeError(f"registration odometry_error must be two finite numbers, got "
                                 f"{self.odometry_error}")
        self.icp.check()
        self.search_icp.check()
        self.link_icp.check()
        self.teach_icp.check()
        return self


class RegistrationPolicy:
    """The registration C_WP for lidar (see the module docstring).

    ``encode_target(context)`` takes (N, 2k+1, beams) scans and returns
    (N, 2k+1, 4 + beams) features: each frame's pose in the anchor frame,
    whether it is usable, and its ranges."""

    observation = "lidar"
    # the follower keeps a car in Follow where RE doubts an active anchor that
    # a sure tracker puts within this (m; where TrackerConfig.sure_follow_m is None)
    sure_follow_m = 2.5

    def __init__(self, config: RegistrationConfig | None = None, lidar: LidarConfig | None = None):
        self.config = (config or RegistrationConfig()).check()
        self.sensor = lidar or LidarConfig()
        self.k = self.config.k
        self.frame_step = self.config.frame_step
        self.name = "registration"
        self.track_size = SLOT * self.config.slots

    # -- teach --------------------------------------------------------------------
    def encode_target(self, context: np.ndarray) -> np.ndarray:
        ctx = np.asarray(context, np.float64)
        n_f = 2 * self.k + 1
        if ctx.ndim != 3 or ctx.shape[1:] != (n_f, self.sensor.beams):
            raise TopodrakeError(f"registration target context must be (N, {n_f}, "
                                 f"{self.sensor.beams}) lidar ranges, got {ctx.shape}")
        n = len(ctx)
        poses = np.zeros((n, n_f, 3))
        ok = np.zeros((n, n_f), bool)
        ok[:, self.k] = True
        if self.k > 0 and n:
            links = self._links(ctx)          # (N, 2k, 3): frame j+1 in frame j, and accepted
            step, good = links
            for j in range(self.k, n_f - 1):              # forward from the centre
                poses[:, j + 1] = compose(poses[:, j], step[:, j])
                ok[:, j + 1] = ok[:, j] & good[:, j]
            for j in range(self.k, 0, -1):                # backward
                poses[:, j - 1] = compose(poses[:, j], invert(step[:, j - 1]))
                ok[:, j - 1] = ok[:, j] & good[:, j - 1]
        return np.concatenate([poses, ok[..., None].astype(np.float64), ctx], axis=2)

    def _links(self, ctx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pose of each context frame j+1 in frame j (N, 2k, 3), and whether
        the fit passed (N, 2k). Links that slide (a corridor) start again from
        the nearest pinned link's motion."""
        n, n_f, beams = ctx.shape
        cfg = self.config
        src = ctx[:, 1:].reshape(-1, beams)
        tgt = ctx[:, :-1].reshape(-1, beams)
        sp, sv = scan_points(src, self.sensor)
        tp, tv = scan_points(tgt, self.sensor)
        res = register_points(sp, sv, tp, tv, np.zeros((1, 3)), len(src), cfg.teach_icp)
        step = res.pose.reshape(n, n_f - 1, 3)
        good = res.accepted.reshape(n, n_f - 1)
        pinned = (res.constraint >= cfg.slide_constraint).reshape(n, n_f - 1) & good
        same = np.all(ctx[:, 1:] == ctx[:, :-1], axis=2) | ~np.isfinite(ctx[:, 1:]).any(axis=2) & \
            ~np.isfinite(ctx[:, :-1]).any(axis=2)
        step[same] = 0.0                                   # clamped context: repeated frames
        good[same] = True
        pinned[same] = False
        redo = good & ~pinned & ~same
        if redo.any():
            guess = np.zeros((n, n_f - 1, 3))
            for i, j in zip(*np.nonzero(redo)):
                cand = np.flatnonzero(pinned[i])
                if cand.size:
                    guess[i, j] = step[i, cand[np.argmin(np.abs(cand - j))]]
            idx = np.flatnonzero(redo.ravel())
            again = register_points(sp[idx], sv[idx], tp[idx], tv[idx], guess.reshape(-1, 3)[idx],
                                    len(idx), cfg.teach_icp)
            flat = step.reshape(-1, 3)
            flat[idx] = np.where(again.accepted[:, None], again.pose, guess.reshape(-1, 3)[idx])
        return step, good

    # -- repeat -------------------------------------------------------------------
    def initial_track(self, n: int) -> np.ndarray:
        t = np.full((n, self.track_size), np.nan)
        t[:, _KEY::SLOT] = -1.0
        return t

    def tracked_start(self, starts: np.ndarray, targets: np.ndarray,
                      error: np.ndarray | None = None) -> np.ndarray:
        """Tracking state of cars at ``starts`` (N, 3) that already track
        the anchor at ``targets`` (N, 3; key 0), as a following car's
        tracker holds the anchor it drives toward: the car's pose in the
        anchor's frame (plus ``error`` (N, 3), where given), confirmed, made
        at the odometry pose ``starts``. For labels of the tracked
        controller (the poses are the truth)."""
        starts = np.asarray(starts, np.float64).reshape(-1, 3)
        est = relative(np.asarray(targets, np.float64).reshape(-1, 3), starts)
        if error is not None:
            est = est + np.asarray(error, np.float64).reshape(-1, 3)
        t = self.initial_track(len(starts))
        slot = t[:, :SLOT]
        slot[:, _KEY] = 0.0
        slot[:, _EST] = est
        slot[:, _ODO] = starts
        slot[:, _OVL] = 0.0
        slot[:, _MISS] = 0.0
        slot[:, _HITS] = float(self.config.confirm)
        slot[:, _SEG] = -1.0
        return t

    def predict(self, observation: np.ndarray, target) -> WaypointPrediction:
        feats = np.asarray(target, np.float64)
        obs = np.asarray(observation, np.float64).reshape(-1, self.sensor.beams)
        m = max(len(obs), len(feats))
        obs = np.broadcast_to(obs, (m, obs.shape[1])) if len(obs) == 1 else obs
        feats = np.broadcast_to(feats, (m, *feats.shape[1:])) if len(feats) == 1 else feats
        track = self.initial_track(m)
        return self.predict_tracked(obs, feats, track, np.arange(m), np.arange(m), np.zeros((m, 3)))

    def predict_tracked(self, observation, target, track: np.ndarray, cars, keys,
                        odometry, legs=None) -> WaypointPrediction:
        """Answers for M queries (car ``cars[m]`` toward the anchor ``keys[m]``
        with features ``target[m]``), updating ``track[cars]`` in place.
        ``legs``: the anchors' poses (M, 3) in their segments of the route's
        legs and the segments (M,; -1: no known legs), when the route has them
        (:func:`topodrake.navigation.tracker.route_frames`)."""
        cfg = self.config
        obs = np.asarray(observation, np.float64).reshape(-1, self.sensor.beams)
        feats = np.asarray(target, np.float64)
        cars = np.asarray(cars, np.int64)
        keys = np.asarray(keys, np.int64)
        odo = np.asarray(odometry, np.float64).reshape(-1, 3)
        m = len(keys)
        n_f = 2 * self.k + 1
        if feats.shape != (m, n_f, 4 + self.sensor.beams) or len(obs) != m or len(cars) != m \
                or len(odo) != m:
            raise TopodrakeError(f"registration queries: {m} keys, {len(obs)} scans, "
                                 f"{len(cars)} cars, {len(odo)} odometry poses and target "
                                 f"features {feats.shape} (need (M, {n_f}, "
                                 f"{4 + self.sensor.beams}))")
        frames, usable = feats[:, :, :3], feats[:, :, 3] > 0.5
        if legs is not None:
            frame_of = np.asarray(legs[0], np.float64).reshape(m, 3)
            seg_of = np.asarray(legs[1], np.float64).reshape(m)
            seg_of = np.where(np.all(np.isfinite(frame_of), axis=1), seg_of, -1.0)
        # 1. slots and predictions
        slot = np.zeros(m, np.int64)
        prior = np.full((m, 3), np.nan)
        search = np.zeros(m, bool)
        for q in range(m):
            row = track[cars[q]].reshape(cfg.slots, SLOT)
            slot[q], fresh = _slot_of(row, keys[q])
            if fresh:
                row[slot[q]] = np.nan
                row[slot[q], _KEY] = keys[q]
                row[slot[q], _MISS] = cfg.relocalise_after
                row[slot[q], _OVL] = 0.0
            s = row[slot[q]]
            if legs is not None:
                s[_SEG], s[_FRAME] = seg_of[q], frame_of[q]
            if np.all(np.isfinite(s[_EST])) and np.all(np.isfinite(s[_ODO])):
                prior[q] = compose(s[_EST], self._motion(s[_ODO], odo[q]))[0]
        if legs is not None and cfg.handover:
            self._handover(prior, track, cars, slot, odo)
        # an anchor without a prediction, asked beside the one before it: the two
        # anchors' taught paths overlap (frames of one drive), which links their frames
        self._link(prior, feats, cars, keys)
        for q in range(m):
            s = track[cars[q]].reshape(cfg.slots, SLOT)[slot[q]]
            late = s[_MISS] - cfg.relocalise_after
            search[q] = (not np.all(np.isfinite(prior[q])) or late >= 0) \
                and (late <= 0 or late % cfg.search_every == 0)
        # 2. registrations: the frames nearest the prediction, and every frame when searching
        jq, jf, jg, js = [], [], [], []
        for q in range(m):
            good = np.flatnonzero(usable[q])
            if np.all(np.isfinite(prior[q])):
                d = np.hypot(*(frames[q, good, :2] - prior[q, :2]).T)
                for f in good[np.argsort(d)[:cfg.nearest]]:
                    jq.append(q)
                    jf.append(f)
                    jg.append(compose(invert(frames[q, f]), prior[q])[0])
                    js.append(False)
            if search[q]:
                for turn in cfg.search_turns:
                    for f in good:
                        jq.append(q)
                        jf.append(f)
                        jg.append(np.array([0.0, 0.0, turn]))
                        js.append(True)
                    for b in cfg.behind_m:
                        jq.append(q)
                        jf.append(good[0])
                        jg.append(np.array([-b, 0.0, turn]))
                        js.append(True)
        jq, jf, js = np.array(jq, np.int64), np.array(jf, np.int64), np.array(js, bool)
        jg = np.array(jg).reshape(-1, 3)
        # the route's start: a car without any estimate may take the identity fit onto the
        # anchor's own scan even where it slides
        placed = np.isfinite(track[cars].reshape(m, cfg.slots, SLOT)[:, :, _EST]).any(axis=(1, 2))
        starting = search & ~placed & (cfg.start_slides and legs is not None)
        jstart = starting[jq] & js & (jf == self.k) & np.all(jg == 0.0, axis=1)
        best = np.full(m, -1, np.int64)
        if len(jq):
            res = self._register(obs[jq], feats[jq, jf, 4:], jg, js)
            # a search fit must be pinned: in a corridor it could sit anywhere along it
            usable_fit = res.accepted & (~js | (((res.constraint >= cfg.slide_constraint) | jstart)
                                                & (res.inlier_back >= cfg.search_back)))
            score = np.where(usable_fit, res.inlier - res.rms, -np.inf)
            for i in range(len(jq)):
                if score[i] > -np.inf and (best[jq[i]] < 0 or score[i] > score[best[jq[i]]]):
                    best[jq[i]] = i
        # 3. estimates: the best accepted fit, else the held prediction
        est = prior.copy()
        fitted = best >= 0
        pinned = np.zeros(m, bool)
        if fitted.any():
            b = best[fitted]
            est[fitted] = compose(frames[fitted, jf[b]], res.pose[b])
            pinned[fitted] = res.constraint[b] >= cfg.slide_constraint
        if legs is not None and cfg.search_check_m > 0 and fitted.any():
            found = np.flatnonzero(fitted)[js[best[fitted]]]
            wrong = self._neighbours_refuse(found, est, obs, feats, frames, usable, cars, keys,
                                            frame_of, seg_of)
            fitted[wrong], pinned[wrong], est[wrong] = False, False, prior[wrong]
        agree = fitted & (np.hypot(*(est[:, :2] - prior[:, :2]).T) < cfg.agree_m) \
            & (np.abs(_wrap(est[:, 2] - prior[:, 2])) < cfg.agree_rad)
        hits = np.zeros(m)
        for q in range(m):
            s = track[cars[q]].reshape(cfg.slots, SLOT)[slot[q]]
            old = s[_HITS] if np.isfinite(s[_HITS]) else 0.0
            # a fit that slides (a corridor) keeps a confirmed estimate confirmed but
            # confirms none: along the corridor it only repeats the prediction
            if agree[q] and (pinned[q] or old >= cfg.confirm):
                hits[q] = old + 1
            elif agree[q]:
                hits[q] = old
            else:
                hits[q] = 1.0 if fitted[q] and pinned[q] else 0.0
        # 4. overlaps against the anchor's own scan from a confirmed estimate
        overlap = np.zeros((m, 2))
        confirmed = fitted & (hits >= cfg.confirm)
        if confirmed.any():
            q = np.flatnonzero(confirmed)
            sp, sv = scan_points(obs[q], self.sensor)
            tp, tv = scan_points(feats[q, self.k, 4:], self.sensor)
            ov = register_points(sp, sv, tp, tv, est[q], len(q), cfg.icp)
            overlap[q] = np.column_stack([ov.inlier, ov.inlier_back])
        for q in range(m):
            row = track[cars[q]].reshape(cfg.slots, SLOT)
            s = row[slot[q]]
            s[_KEY] = keys[q]
            if np.all(np.isfinite(est[q])):
                s[_EST] = est[q]
                s[_ODO] = odo[q]
            s[_OVL] = overlap[q]
            s[_MISS] = 0 if fitted[q] else min(s[_MISS] + 1, 1e6)
            s[_EXIT] = frames[q, np.flatnonzero(usable[q])[-1]]
            s[_HITS] = hits[q]
        # 5. pure pursuit along the taught frames
        waypoint = np.zeros((m, 2))
        heading = np.zeros(m)
        for q in range(m):
            if np.all(np.isfinite(est[q])):
                path = frames[q, :self.k + 1][usable[q, :self.k + 1]]
                point = _pursuit(path[:, :2], est[q, :2], cfg.lookahead_m)
                waypoint[q] = _to_car(est[q], point)
                heading[q] = _wrap(-est[q, 2])
            else:
                waypoint[q], heading[q] = self._approach(track[cars[q]], keys[q], odo[q])
        return WaypointPrediction(waypoint, heading, overlap)

    def _neighbours_refuse(self, found, est, obs, feats, frames, usable, cars, keys,
                           frame_of, seg_of) -> np.ndarray:
        """The queries among ``found`` (fitted by search) whose estimate a
        neighbour refuses: another query of the car toward an anchor of the
        same segment of the legs, whose taught frames the estimate (carried
        through the legs) puts within ``search_check_m`` of the car, where
        the scan does not register onto the nearest of them from there."""
        cfg = self.config
        jobs = []                                     # (query, neighbour, frame, guess)
        for q in found:
            if seg_of[q] < 0:
                continue
            for o in np.flatnonzero((cars == cars[q]) & (keys != keys[q]) & (seg_of == seg_of[q])):
                guess = compose(relative(frame_of[o][None], frame_of[q][None]), est[q][None])[0]
                good = np.flatnonzero(usable[o])
                d = np.hypot(*(frames[o, good, :2] - guess[:2]).T)
                if good.size and d.min() < cfg.search_check_m:
                    f = good[np.argmin(d)]
                    jobs.append((q, o, f, compose(invert(frames[o, f]), guess[None])[0]))
        if not jobs:
            return np.zeros(0, np.int64)
        q, o, f = (np.array([j[i] for j in jobs], np.int64) for i in range(3))
        sp, sv = scan_points(obs[o], self.sensor)
        tp, tv = scan_points(feats[o, f, 4:], self.sensor)
        res = register_points(sp, sv, tp, tv, np.array([j[3] for j in jobs]), len(jobs), cfg.icp)
        return np.unique(q[~res.accepted])

    def _handover(self, prior: np.ndarray, track: np.ndarray, cars: np.ndarray,
                  slot: np.ndarray, odo: np.ndarray) -> None:
        """Predictions (in place) for queries whose anchor has none or is lost,
        from the car's best-tracked anchor of the same segment of the route's
        legs (fitted most recently, not lost): its estimate moved by odometry,
        carried into this anchor's frame by the teach drive's odometry between
        the two (VT&R's edge transforms). The confirmation carries over too:
        the stored transform is what a registration between the two anchors'
        taught frames would only approximate."""
        cfg = self.config
        for q in range(len(cars)):
            row = track[cars[q]].reshape(cfg.slots, SLOT)
            s = row[slot[q]]
            if s[_SEG] < 0 or not np.isfinite(s[_SEG]):
                continue
            own = s[_MISS] if np.all(np.isfinite(prior[q])) else np.inf
            if own == 0:
                continue
            cand = [i for i in range(cfg.slots) if i != slot[q] and row[i, _SEG] == s[_SEG]
                    and row[i, _MISS] < min(own, cfg.relocalise_after)
                    and np.all(np.isfinite(row[i, _EST])) and np.all(np.isfinite(row[i, _ODO]))
                    and np.hypot(*(odo[q, :2] - row[i, _ODO][:2])) < cfg.handover_m]
            if not cand:
                continue
            src = row[min(cand, key=lambda i: (row[i, _MISS], -row[i, _HITS]))]
            moved = compose(src[_EST], self._motion(src[_ODO], odo[q]))
            prior[q] = compose(relative(s[_FRAME][None], src[_FRAME][None]), moved)[0]
            s[_EST], s[_ODO] = prior[q], odo[q]
            s[_MISS], s[_HITS] = src[_MISS], src[_HITS]

    def _link(self, prior: np.ndarray, feats: np.ndarray, cars: np.ndarray, keys: np.ndarray
              ) -> None:
        """Predictions (in place) for queries without one whose car also asks
        about the anchor before (key - 1) with a prediction: that anchor's
        last taught frames registered against this one's first give the pose
        of one anchor frame in the other."""
        cfg = self.config
        pairs = []
        for q in np.flatnonzero(~np.all(np.isfinite(prior), axis=1)):
            before = np.flatnonzero((cars == cars[q]) & (keys == keys[q] - 1)
                                    & np.all(np.isfinite(prior), axis=1))
            if before.size:
                pairs.append((q, before[0]))
        if not pairs:
            return
        jobs = []                                     # (query, prev query, prev frame, frame)
        for q, p in pairs:
            late = np.flatnonzero(feats[p, :, 3] > 0.5)[-cfg.link_frames:]
            early = np.flatnonzero(feats[q, :, 3] > 0.5)[:cfg.link_frames]
            jobs += [(q, p, j, i) for j in late for i in early]
        jobs = np.array(jobs, np.int64)
        sp, sv = scan_points(feats[jobs[:, 0], jobs[:, 3], 4:], self.sensor)
        tp, tv = scan_points(feats[jobs[:, 1], jobs[:, 2], 4:], self.sensor)
        res = register_points(sp, sv, tp, tv, np.zeros((1, 3)), len(jobs), cfg.link_icp)
        score = np.where(res.accepted & (res.constraint >= cfg.slide_constraint),
                         res.inlier - res.rms, -np.inf)
        for q, p in pairs:
            mine = np.flatnonzero(jobs[:, 0] == q)
            b = mine[np.argmax(score[mine])]
            if score[b] == -np.inf:
                continue
            _, _, j, i = jobs[b]
            # this anchor's frame in the one before's: its frame j, the fit, back from frame i
            link = compose(compose(feats[p, j, :3], res.pose[b]), invert(feats[q, i, :3]))
            prior[q] = compose(invert(link), prior[p])[0]

    def _register(self, source, target, guess, searching):
        """Registrations of tracking jobs (``cfg.icp``) and searching ones
        (``cfg.search_icp``), in one result."""
        cfg = self.config
        sp, sv = scan_points(source, self.sensor)
        tp, tv = scan_points(target, self.sensor)
        out = None
        for mask, icp in ((~searching, cfg.icp), (searching, cfg.search_icp)):
            idx = np.flatnonzero(mask)
            if not idx.size:
                continue
            r = register_points(sp[idx], sv[idx], tp[idx], tv[idx], guess[idx], len(idx), icp)
            if out is None:
                out = Registration(*(np.empty((len(source), *np.shape(v)[1:]), np.asarray(v).dtype)
                                     for v in vars(r).values()))
            for name, v in vars(r).items():
                getattr(out, name)[idx] = v
        return out

    def _motion(self, odo_then: np.ndarray, odo_now: np.ndarray) -> np.ndarray:
        d = compose(invert(odo_then), odo_now)[0]
        et, er = self.config.odometry_error
        return np.array([d[0] * (1 + et), d[1] * (1 + et), d[2] * (1 + er)])

    def _approach(self, row_flat: np.ndarray, key: int, odo: np.ndarray
                  ) -> tuple[np.ndarray, float]:
        """Toward an anchor not yet registered: on from the nearest earlier
        anchor the car tracks along its taught path's exit (its centre, its
        last usable frame and on straight), with that anchor's estimate moved
        by odometry; else straight ahead."""
        cfg = self.config
        row = row_flat.reshape(cfg.slots, SLOT)
        prev = np.flatnonzero((row[:, _KEY] < key) & np.all(np.isfinite(row[:, _EST]), axis=1)
                              & np.all(np.isfinite(row[:, _EXIT]), axis=1))
        if prev.size:
            s = row[prev[np.argmax(row[prev, _KEY])]]
            est = compose(s[_EST], self._motion(s[_ODO], odo))[0]
            ahead = compose(s[_EXIT], np.array([cfg.exit_m, 0.0, 0.0]))[0]
            path = np.array([[0.0, 0.0], s[_EXIT][:2], ahead[:2]])
            return (_to_car(est, _pursuit(path, est[:2], cfg.lookahead_m)),
                    float(_wrap(s[_EXIT][2] - est[2])))
        return np.array([cfg.lookahead_m, 0.0]), 0.0


def _slot_of(row: np.ndarray, key: int) -> tuple[int, bool]:
    """The slot tracking ``key`` (fresh=False), else a free one or the one of
    the lowest key (fresh=True)."""
    hit = np.flatnonzero(row[:, _KEY] == key)
    if hit.size:
        return int(hit[0]), False
    free = np.flatnonzero(row[:, _KEY] < 0)
    if free.size:
        return int(free[0]), True
    return int(np.argmin(row[:, _KEY])), True


def _pursuit(path: np.ndarray, car: np.ndarray, lookahead: float) -> np.ndarray:
    """The point ``lookahead`` along polyline ``path`` (P, 2) from the car's
    projection onto it, no farther than its end."""
    if len(path) == 1:
        return path[0]
    seg = np.diff(path, axis=0)
    length = np.hypot(*seg.T)
    cum = np.concatenate([[0.0], np.cumsum(length)])
    if cum[-1] < 1e-9:
        return path[-1]
    t = np.clip(np.einsum("ij,ij->i", car - path[:-1], seg) / np.maximum(length ** 2, 1e-12), 0, 1)
    proj = path[:-1] + t[:, None] * seg
    i = int(np.argmin(np.hypot(*(proj - car).T)))
    s = min(cum[i] + t[i] * length[i] + lookahead, cum[-1])
    j = min(int(np.searchsorted(cum, s, side="right")) - 1, len(seg) - 1)
    u = (s - cum[j]) / length[j] if length[j] > 1e-12 else 0.0
    return path[j] + min(max(u, 0.0), 1.0) * seg[j]


def _to_car(pose: np.ndarray, point: np.ndarray) -> np.ndarray:
    d = point - pose[:2]
    c, s = np.cos(pose[2]), np.sin(pose[2])
    return np.array([c * d[0] + s * d[1], -s * d[0] + c * d[1]])


def _wrap(a):
    return (a + np.pi) % (2 * np.pi) - np.pi
