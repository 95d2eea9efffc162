"""The route tracker: where each car is along its taught route, by odometry
between anchors, with C_WP's answers and scan registrations as fixes.

Teach and repeat (VT&R) applied to the follower: each car keeps its pose
``rel`` (x, y, heading) in the frame of one anchor of its route (``ref``)
with its 3 x 3 covariance. Anchors are placed relative to each other by the
route's legs (:func:`route_frames`); anchors joined by an unknown leg lie in
different segments, and across them the car is localized again. Each period:

* :func:`propagate`: odometry moves ``rel`` and grows the covariance with
  the distance driven;
* :func:`fix`: a C_WP answer toward an anchor within ``fix_range_m`` is an
  extended Kalman measurement (its waypoint the anchor's position in the
  car frame, its heading head the heading difference), gated at
  ``gate_sigma``; an outvoted answer counts toward ``reset_after``, which
  restarts the prior;
* :func:`fix_pose`: a scan registered onto an anchor's taught scan measures
  ``rel`` directly;
* :func:`reanchor`: ``ref`` follows the car's last visited anchor.

:func:`anchor_in_car` and :func:`tracked_anchor` are what the follower
reads. Reasons and measured effects: docs/follower.md.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from topodrake.errors import TopodrakeError
from topodrake.se2 import compose, relative, wrap


@dataclass
class TrackerConfig:
    """The route tracker: the follower's rules that read it, the legs it
    tracks along, and its filter's noises and gates. Lengths in m, angles
    in rad (``_deg``: degrees); sigmas are standard deviations."""

    # what the follower does with the tracker (read by topodrake.navigation.follower)
    odometry_check: bool = True       # track cars along routes with legs (off: no tracker)
    check_deg: float = 35.0           # a Follow waypoint of C_WP's more than this off the
                                      # tracked pursuit point is replaced by that point
    scan_fix: bool = True             # fixes from the car's lidar scan registered onto the
                                      # active and last visited anchors' taught scans
    tracked_sure_m: float = 0.1       # position sigma under which the tracker is sure (0: never)
    tracked_reach_m: float = 2.5      # a sure tracker refuses Dead reckoning anchors it puts
                                      # farther than this (0: off) ...
    tracked_goal_m: float = 0.5       # ... and C_WP's "at the goal" where it puts the goal
                                      # farther than this (0: off) ...
    sure_follow_m: float | None = None  # ... and keeps a car in Follow where RE doubts an
                                      # active anchor it puts within this (0: off; None: the
                                      # C_WP's own ``sure_follow_m``, off where it has none)
    # the route's legs (read by topodrake.navigation.evaluate.encode_routes)
    legs_m: float = 2.0               # a hop without a taught leg takes C_WP's answer from the
                                      # anchor's own view toward the next as its leg, where that
                                      # waypoint is shorter than this (0: off)
    # the filter (read by this module)
    fix_range_m: float = 2.5          # answers toward anchors predicted farther are not fixes
    drift_m_per_m: float = 0.06       # position sigma grown per metre driven
    drift_rad_per_m: float = 0.04     # heading sigma grown per metre driven
    answer_m: float = 0.1             # an answer's position sigma at the target ...
    answer_m_per_m: float = 0.15      # ... plus this per metre of target distance
    answer_rad: float = 0.15          # the heading head's sigma
    gate_sigma: float = 3.0           # answers beyond this many sigma are outvoted
    reset_after: int = 4              # outvoted answers in a row that restart the prior
    initial_m: float = 0.3            # position sigma of a start from one answer
    initial_rad: float = 0.3          # heading sigma of a start from one answer
    repeats: float = 10.0             # an answer's variance counts this many times (a run of
                                      # answers toward one anchor weighs like one)
    floor_m: float = 0.15             # fixes never take the position sigma below this ...
    floor_rad: float = 0.07           # ... nor the heading sigma below this
    scan_m: float = 0.05              # a scan fix's position sigma ...
    scan_rad: float = 0.03            # ... and heading sigma
    scan_range_m: float = 2.5         # anchors predicted farther are not registered against

    def check(self) -> "TrackerConfig":
        """Refuses a bad setting in one line (TopodrakeError naming it)."""
        if not 0.0 < self.check_deg <= 180.0:
            raise TopodrakeError(f"follower check_deg must be in (0, 180], got {self.check_deg}")
        if not (np.isfinite(self.tracked_goal_m) and self.tracked_goal_m >= 0.0):
            raise TopodrakeError(f"follower tracked_goal_m must be >= 0 (0: off), got "
                                 f"{self.tracked_goal_m}")
        if self.sure_follow_m is not None and not (np.isfinite(self.sure_follow_m)
                                                   and self.sure_follow_m >= 0.0):
            raise TopodrakeError(f"follower sure_follow_m must be >= 0 (0: off) or None (the "
                                 f"C_WP's choice), got {self.sure_follow_m}")
        if not (self.tracked_reach_m >= 0.0 and self.tracked_sure_m >= 0.0):
            raise TopodrakeError(f"follower tracked_reach_m and tracked_sure_m must be >= 0 "
                                 f"(0: off), got {self.tracked_reach_m} and "
                                 f"{self.tracked_sure_m}")
        if not (np.isfinite(self.legs_m) and self.legs_m >= 0.0):
            raise TopodrakeError(f"follower legs_m must be >= 0 (0: off), got {self.legs_m}")
        return self


def pad_points(paths: np.ndarray, k: int) -> np.ndarray:
    """(R, K', 3) paths padded to K points with their last."""
    return paths if paths.shape[1] >= k else \
        np.concatenate([paths, np.repeat(paths[:, -1:], k - paths.shape[1], 1)], 1)


def route_frames(legs: list[np.ndarray], leg_paths: list[np.ndarray] | None = None
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For routes with ``legs`` (A_i - 1, 3) (and ``leg_paths`` (A_i - 1, K_i,
    3)), stacked in order: each anchor's pose (R, 3) in its segment's frame,
    its segment id (R,), and the taught poses of the hop into it (R, K, 3)
    in that frame (K the largest K_i, shorter paths padded with their end;
    NaN where a segment starts). A NaN leg starts a new segment; an anchor
    alone in its segment gets -1 (the tracker leaves it alone)."""
    if leg_paths is None:
        leg_paths = [np.asarray(lg, np.float64).reshape(-1, 1, 3) for lg in legs]
    k = max([p.shape[1] for p in leg_paths] + [1])
    frames, segments, approach, seg = [], [], [], 0
    for lg, paths in zip(legs, leg_paths):
        lg = np.asarray(lg, np.float64).reshape(-1, 3)
        paths = np.asarray(paths, np.float64)
        paths = pad_points(paths, k)
        pose = np.zeros((1, 3))
        frames.append(pose[0])
        segments.append(seg)
        approach.append(np.full((k, 3), np.nan))
        for leg, path in zip(lg, paths):
            if np.all(np.isfinite(leg)) and np.all(np.isfinite(path)):
                approach.append(compose(np.repeat(pose, k, 0), path))
                pose = compose(pose, leg)
            else:
                seg += 1
                pose = np.zeros((1, 3))
                approach.append(np.full((k, 3), np.nan))
            frames.append(pose[0])
            segments.append(seg)
        seg += 1
    if not frames:
        return np.zeros((0, 3)), np.zeros(0, np.int64), np.zeros((0, k, 3))
    segments = np.array(segments, np.int64)
    alone = np.bincount(segments)[segments] == 1
    segments[alone] = -1            # an anchor without known legs: nothing to track along
    return np.array(frames), segments, np.array(approach)


def diagonal_cov(pos_var, head_var) -> np.ndarray:
    """Covariances (N, 9) (3 x 3 over x, y, heading, flattened) with these
    position and heading variances and no correlation."""
    pos_var, head_var = np.broadcast_arrays(np.asarray(pos_var, np.float64),
                                            np.asarray(head_var, np.float64))
    cov = np.zeros((pos_var.size, 3, 3))
    cov[:, 0, 0] = cov[:, 1, 1] = pos_var.ravel()
    cov[:, 2, 2] = head_var.ravel()
    return cov.reshape(-1, 9)


def _cov(var: np.ndarray) -> np.ndarray:
    return np.asarray(var, np.float64).reshape(-1, 3, 3).copy()


def _flat(cov: np.ndarray) -> np.ndarray:
    return (0.5 * (cov + cov.transpose(0, 2, 1))).reshape(-1, 9)


def propagate(rel: np.ndarray, var: np.ndarray, odo_before: np.ndarray, odo_now: np.ndarray,
              cfg: TrackerConfig) -> tuple[np.ndarray, np.ndarray]:
    """``rel`` (N, 3) and its covariance ``var`` (N, 9) moved by the odometry
    increment (a heading error swings the position by the distance driven)."""
    step = relative(odo_before, odo_now)
    new = compose(rel, step)
    dist = np.hypot(step[:, 0], step[:, 1]) + 0.3 * np.abs(step[:, 2])
    jac = np.repeat(np.eye(3)[None], len(rel), axis=0)
    jac[:, 0, 2] = -(new[:, 1] - rel[:, 1])
    jac[:, 1, 2] = new[:, 0] - rel[:, 0]
    cov = jac @ _cov(var) @ jac.transpose(0, 2, 1)
    cov += _cov(diagonal_cov((cfg.drift_m_per_m * dist) ** 2, (cfg.drift_rad_per_m * dist) ** 2))
    return new, _flat(cov)


def anchor_in_car(rel: np.ndarray, anchor: np.ndarray) -> np.ndarray:
    """The anchor poses (N, 3), given in the ``ref`` frame, seen from cars at ``rel``."""
    return relative(rel, anchor)


def fix(rel: np.ndarray, var: np.ndarray, anchor: np.ndarray, waypoint: np.ndarray,
        heading: np.ndarray, cfg: TrackerConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One answer per car: C_WP's ``waypoint`` (N, 2) and ``heading`` (N,)
    toward an anchor at ``anchor`` (N, 3) in the ``ref`` frame, as an
    extended Kalman update of ``rel`` and its covariance ``var`` (N, 9)
    (the waypoint also corrects the heading: the anchor's bearing depends on
    it). Returns the corrected ``rel``, ``var`` and whether each answer was
    accepted (N,); rows with a non-finite answer are left alone."""
    rel = rel.copy()
    cov = _cov(var)
    seen = anchor_in_car(rel, anchor)
    dist = np.hypot(seen[:, 0], seen[:, 1])
    r_pos = (cfg.answer_m + cfg.answer_m_per_m * dist) ** 2
    err = waypoint - seen[:, :2]
    c, s = np.cos(rel[:, 2]), np.sin(rel[:, 2])
    jac = np.zeros((len(rel), 2, 3))                 # d(seen position) / d(x, y, heading)
    jac[:, 0, 0], jac[:, 0, 1], jac[:, 0, 2] = -c, -s, seen[:, 1]
    jac[:, 1, 0], jac[:, 1, 1], jac[:, 1, 2] = s, -c, -seen[:, 0]
    ok = np.isfinite(err).all(axis=1) & (dist < cfg.fix_range_m)
    if ok.any():
        spread = jac[ok] @ cov[ok] @ jac[ok].transpose(0, 2, 1)
        gate = spread + r_pos[ok, None, None] * np.eye(2)
        e = err[ok]
        m2 = np.einsum("ni,nij,nj->n", e, np.linalg.inv(gate), e)
        ok[np.flatnonzero(ok)] = m2 < cfg.gate_sigma ** 2
    if not ok.any():
        return rel, _flat(cov), ok
    j, p = jac[ok], cov[ok]
    innov = j @ p @ j.transpose(0, 2, 1) + cfg.repeats * r_pos[ok, None, None] * np.eye(2)
    gain = p @ j.transpose(0, 2, 1) @ np.linalg.inv(innov)             # (M, 3, 2)
    rel[ok] += np.einsum("nij,nj->ni", gain, err[ok])
    rel[ok, 2] = wrap(rel[ok, 2])
    cov[ok] = (np.eye(3) - gain @ j) @ p
    # the heading head measures the heading directly
    idx = np.flatnonzero(ok)
    dh = wrap(anchor[idx, 2] - np.asarray(heading, np.float64)[idx] - rel[idx, 2])
    p_hh = cov[idx, 2, 2]
    use = np.isfinite(dh) & (dh ** 2 < cfg.gate_sigma ** 2 * (p_hh + cfg.answer_rad ** 2))
    idx, dh = idx[use], dh[use]
    if idx.size:
        k = cov[idx, :, 2] / (cov[idx, 2, 2] + cfg.repeats * cfg.answer_rad ** 2)[:, None]
        rel[idx] += k * dh[:, None]
        rel[idx, 2] = wrap(rel[idx, 2])
        cov[idx] -= k[:, :, None] * cov[idx, 2, None, :]
    floor = np.array([cfg.floor_m ** 2, cfg.floor_m ** 2, cfg.floor_rad ** 2])
    d = np.diagonal(cov, axis1=1, axis2=2)
    cov[ok] += np.eye(3) * np.maximum(floor - d[ok], 0.0)[:, None, :]
    return rel, _flat(cov), ok


def fix_pose(rel: np.ndarray, var: np.ndarray, measured: np.ndarray, cfg: TrackerConfig
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Direct measurements ``measured`` (N, 3) of ``rel`` (a scan fix), as a
    Kalman update with sigmas ``scan_m`` / ``scan_rad``, gated at
    ``gate_sigma``. Returns the corrected ``rel``, ``var`` and which were
    accepted (N,)."""
    rel = rel.copy()
    cov = _cov(var)
    err = measured - rel
    err[:, 2] = wrap(err[:, 2])
    noise = np.diag([cfg.scan_m ** 2, cfg.scan_m ** 2, cfg.scan_rad ** 2])
    ok = np.isfinite(err).all(axis=1)
    if ok.any():
        innov = cov[ok] + noise
        m2 = np.einsum("ni,nij,nj->n", err[ok], np.linalg.inv(innov), err[ok])
        ok[np.flatnonzero(ok)] = m2 < cfg.gate_sigma ** 2
    if ok.any():
        gain = cov[ok] @ np.linalg.inv(cov[ok] + noise)
        rel[ok] += np.einsum("nij,nj->ni", gain, err[ok])
        rel[ok, 2] = wrap(rel[ok, 2])
        cov[ok] = (np.eye(3) - gain) @ cov[ok]
    return rel, _flat(cov), ok


def start_from_answer(waypoint: np.ndarray, heading: np.ndarray, cfg: TrackerConfig
                      ) -> tuple[np.ndarray, np.ndarray]:
    """The car's pose (N, 3) in the frame of the anchor C_WP answered about
    (as if the answer were exact), with the covariance (N, 9) of such a start."""
    h = np.where(np.isfinite(heading), heading, 0.0)
    anchor_seen = np.column_stack([waypoint, h])
    rel = relative(anchor_seen, np.zeros_like(anchor_seen))
    dist = np.hypot(*np.asarray(waypoint).T)
    return rel, diagonal_cov(cfg.initial_m ** 2 + (cfg.answer_m_per_m * dist) ** 2,
                             np.full(len(rel), cfg.initial_rad ** 2))


def reanchor(rel: np.ndarray, old_anchor: np.ndarray, new_anchor: np.ndarray) -> np.ndarray:
    """``rel`` re-expressed from one anchor's frame to another's (both
    given in a common frame, (N, 3))."""
    return compose(relative(new_anchor, old_anchor), rel)


def reanchor_cov(var: np.ndarray, old_anchor: np.ndarray, new_anchor: np.ndarray) -> np.ndarray:
    """Covariances (N, 9) re-expressed as :func:`reanchor` moves their poses."""
    turn = relative(new_anchor, old_anchor)[:, 2]
    c, s = np.cos(turn), np.sin(turn)
    rot = np.repeat(np.eye(3)[None], len(turn), axis=0)
    rot[:, 0, 0], rot[:, 0, 1], rot[:, 1, 0], rot[:, 1, 1] = c, -s, s, c
    return _flat(rot @ _cov(var) @ rot.transpose(0, 2, 1))


# -- the follower's use: functions over a FollowerState's tracking fields (ref, rel, var,
#    odo, misses), for the cars ``cars`` of the batch ------------------------------------------

def advance(state, odometry: np.ndarray, cfg: TrackerConfig) -> None:
    """Moves every tracked car by its odometry since the last period."""
    live = np.flatnonzero((state.ref >= 0) & np.isfinite(state.odo).all(axis=1))
    if live.size:
        state.rel[live], state.var[live] = propagate(state.rel[live], state.var[live],
                                                     state.odo[live], odometry[live], cfg)
    state.odo[:] = odometry


def apply_answers(state, cars: np.ndarray, anchors: np.ndarray, waypoint: np.ndarray,
                  heading: np.ndarray | None, frames, cfg: TrackerConfig) -> None:
    """C_WP's answers (rows ``cars`` ascending, their ``anchors``) as fixes;
    ``frames(cars, anchors)`` gives anchors' (poses (M, 3), segments (M,),
    approach paths (M, K, 3)).
    A car not tracked starts from its answer toward the first anchor asked."""
    m = len(cars)
    if m == 0:
        return
    heading = np.full(m, np.nan) if heading is None else np.asarray(heading, np.float64)
    first = np.r_[True, cars[1:] != cars[:-1]]
    order = np.arange(m) - np.maximum.accumulate(np.where(first, np.arange(m), 0))
    pose, seg, _ = frames(cars, anchors)
    # untracked cars: start from the first in-range answer
    start = first & (state.ref[cars] < 0) & np.isfinite(waypoint).all(axis=1) \
        & (np.hypot(*waypoint.T) < cfg.fix_range_m) & (seg >= 0)
    if start.any():
        c = cars[start]
        state.rel[c], state.var[c] = start_from_answer(waypoint[start], heading[start], cfg)
        state.ref[c] = anchors[start]
        state.misses[c] = 0
    for k in range(int(order.max()) + 1):
        idx = np.flatnonzero((order == k) & ~start)
        c = cars[idx]
        tracked = state.ref[c] >= 0
        idx, c = idx[tracked], c[tracked]
        if idx.size == 0:
            continue
        ref_pose, ref_seg, _ = frames(c, state.ref[c])
        same = (ref_seg == seg[idx]) & (ref_seg >= 0)
        idx, c, ref_pose = idx[same], c[same], ref_pose[same]
        if idx.size == 0:
            continue
        anchor = relative(ref_pose, pose[idx])
        rel, var, ok = fix(state.rel[c], state.var[c], anchor, waypoint[idx], heading[idx], cfg)
        state.rel[c], state.var[c] = rel, var
        seen = anchor_in_car(rel, anchor)
        asked = np.hypot(seen[:, 0], seen[:, 1]) < cfg.fix_range_m
        state.misses[c] = np.where(ok, 0, state.misses[c] + asked)
        lost = c[state.misses[c] >= cfg.reset_after]
        state.ref[lost] = -1


def apply_scans(state, cars: np.ndarray, frames, register, cfg: TrackerConfig) -> None:
    """Scan fixes (:func:`fix_pose`) for the tracked cars among ``cars``
    against their active and last visited anchors within ``scan_range_m``
    of the tracked pose. ``register(cars, anchors, guess)`` registers each
    car's scan onto the anchor's taught scan from ``guess`` (M, 3), the
    car's predicted pose in the anchor's frame, and returns the fitted poses
    (M, 3) and whether each fit pins the pose (M,). An accepted fix also
    clears the count of outvoted C_WP answers."""
    c = cars[state.ref[cars] >= 0]
    if c.size == 0:
        return
    for anchors in (state.active[c], state.visited[c]):
        q = c[anchors >= 0]
        a = anchors[anchors >= 0]
        if q.size == 0:
            continue
        ref_pose, ref_seg, _ = frames(q, state.ref[q])
        pose, seg, _ = frames(q, a)
        anchor = relative(ref_pose, pose)
        guess = relative(anchor, state.rel[q])
        near = (ref_seg == seg) & (seg >= 0) & (np.hypot(guess[:, 0], guess[:, 1])
                                                < cfg.scan_range_m)
        if not near.any():
            continue
        q, a, anchor = q[near], a[near], anchor[near]
        fitted, pinned = register(q, a, guess[near])
        measured = np.where(pinned[:, None], compose(anchor, fitted), np.nan)
        state.rel[q], state.var[q], ok = fix_pose(state.rel[q], state.var[q], measured, cfg)
        state.misses[q[ok]] = 0


def follow_visits(state, cars: np.ndarray, frames) -> None:
    """Tracked cars re-express their pose from their last visited anchor."""
    c = cars[(state.ref[cars] >= 0) & (state.visited[cars] >= 0)
             & (state.visited[cars] != state.ref[cars])]
    if c.size == 0:
        return
    old, old_seg, _ = frames(c, state.ref[c])
    new, new_seg, _ = frames(c, state.visited[c])
    same = (old_seg == new_seg) & (old_seg >= 0)
    state.rel[c[same]] = reanchor(state.rel[c[same]], old[same], new[same])
    state.var[c[same]] = reanchor_cov(state.var[c[same]], old[same], new[same])
    state.ref[c[same]] = state.visited[c[same]]
    state.ref[c[~same]] = -1


def pursuit_point(rel: np.ndarray, approach: np.ndarray, anchor: np.ndarray,
                  lookahead_m: float) -> np.ndarray:
    """Car-frame points (N, 2) to drive at: along the taught poses of the hop
    into the active anchor (``approach`` (N, K, 3), ``anchor`` (N, 3), both
    in the ``ref`` frame), the first after the one nearest the car that lies
    ``lookahead_m`` or farther from it; the anchor itself where none does
    (or the hop's poses are unknown)."""
    n, k = approach.shape[:2]
    pts = np.concatenate([approach, anchor[:, None]], axis=1)            # (N, K + 1, 3)
    seen = relative(np.repeat(rel, k + 1, 0), pts.reshape(-1, 3))[:, :2].reshape(n, k + 1, 2)
    d = np.hypot(seen[..., 0], seen[..., 1])
    d = np.where(np.isfinite(d), d, np.inf)
    d[:, -1] = np.where(np.isfinite(d[:, -1]), d[:, -1], 0.0)
    nearest = np.argmin(d, axis=1)
    after = np.arange(k + 1)[None] >= nearest[:, None]
    far = after & (d >= lookahead_m) & np.isfinite(d)
    pick = np.where(far.any(axis=1), np.argmax(far, axis=1), k)
    return seen[np.arange(n), pick]


def tracked_anchor(state, cars: np.ndarray, anchors: np.ndarray, frames
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Where anchors ``anchors`` of cars ``cars`` are in each car's frame
    (M, 3) by the tracker, whether it knows (M,), and the car-frame point
    (M, 2) to drive at toward each (:func:`pursuit_point`)."""
    out = np.full((len(cars), 3), np.nan)
    aim = np.full((len(cars), 2), np.nan)
    known = state.ref[cars] >= 0
    if known.any():
        c = cars[known]
        ref_pose, ref_seg, _ = frames(c, state.ref[c])
        pose, seg, approach = frames(c, anchors[known])
        same = (ref_seg == seg) & (seg >= 0)
        rows = np.flatnonzero(known)[same]
        into_ref = relative(ref_pose[same], pose[same])
        out[rows] = anchor_in_car(state.rel[c[same]], into_ref)
        k = approach.shape[1]
        path = relative(np.repeat(ref_pose[same], k, 0),
                        approach[same].reshape(-1, 3)).reshape(-1, k, 3)
        aim[rows] = pursuit_point(state.rel[c[same]], path, into_ref, PURSUIT_M)
        known[np.flatnonzero(known)[~same]] = False
    return out, known, aim


PURSUIT_M = 1.0     # the pursuit point's distance ahead of the car
