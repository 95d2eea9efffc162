"""Sparsify a trajectory into anchors (the paper's "Sparsifying a Trajectory").

From anchor i the next anchor is the farthest frame j such that every frame
i+1 .. j passed ``reach(i, j) > p``: the controller is trusted to get from
anchor i to each of them. The scan stops at the first frame that fails, the
next anchor is the frame before it (at least i + 1, so the walk always
advances) and the trajectory's last frame is always kept.

Where RE does not trust even the next frame above ``p`` (it rarely reaches
0.99 from some views, at turns and doorways), the paper's rule keeps every
frame: runs of anchors 5 cm apart, each hop no more probable than a longer
one and each a target too close for C_WP to aim at. With ``slack`` > 0
(ours) the scan then goes on with the threshold ``reach(i, i+1) - slack``
instead: the next anchor is the farthest frame RE rates nearly as reachable
as the next one. ``slack = 0`` is the paper's rule.

With a ``snap`` hook (``sparsify_chain``) an existing map vertex can stand
in for an anchor, and the scan resumes from that vertex (map building's
``reuse_rule = "resume"``).

``reach(i, js)`` returns the probabilities for anchor ``i`` and a batch of
later frames ``js`` (N,), so a learned RE evaluates a window of candidates
in one batched call (with the anchor's and the candidates' cached features).
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from topodrake.errors import TopodrakeError


def sparsify(n_frames: int, reach: Callable[[int, np.ndarray], np.ndarray], p: float = 0.99,
             window: int = 4, max_window: int = 64, slack: float = 0.0,
             cap: np.ndarray | None = None) -> np.ndarray:
    """Anchor frame indices (increasing, first 0, last ``n_frames - 1``).

    Candidates are scored in windows that start at ``window`` frames and
    double up to ``max_window`` while every frame passes, so a short reach
    costs few queries and a long one few calls. ``cap`` (n_frames,): the
    farthest frame each frame's next anchor may be (:func:`hop_caps`)."""
    frames, _ = sparsify_chain(n_frames, reach, p, window, max_window, slack, cap=cap)
    return frames


def hop_caps(positions: np.ndarray, max_hop_m: float) -> np.ndarray | None:
    """(n,) for each frame of a drive at ``positions`` (n, 2) the farthest
    later frame within ``max_hop_m`` along the drive (at least the next
    one); None where ``max_hop_m`` is 0 (no cap)."""
    if not max_hop_m > 0:
        return None
    xy = np.asarray(positions, np.float64)[:, :2]
    along = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(xy, axis=0).T))])
    last = np.searchsorted(along, along + max_hop_m, side="right") - 1
    return np.maximum(last, np.minimum(np.arange(len(xy)) + 1, len(xy) - 1))


def sparsify_chain(n_frames: int, reach: Callable[[object, np.ndarray], np.ndarray],
                   p: float = 0.99, window: int = 4, max_window: int = 64, slack: float = 0.0,
                   snap: Callable[[int, object], object] | None = None,
                   cap: np.ndarray | None = None) -> tuple[np.ndarray, list]:
    """The greedy scan with an optional ``snap(frame, source)`` hook.

    Returns the anchor frames and, for each, the source the scan went on
    from: the frame index itself, or whatever ``snap`` returned for it (an
    existing map vertex that stands in for the frame). ``reach(source, js)``
    scores frames ``js`` from a source of either kind, so after a snap the
    next anchor is the farthest frame reachable from the vertex, not from
    the frame it replaced. ``cap`` (n_frames,): the farthest frame the
    next anchor after each frame may be (a hop no longer than the route
    tracker's reach), or None."""
    if n_frames < 1:
        raise TopodrakeError("cannot sparsify an empty trajectory")
    if not 0.0 < p < 1.0:
        raise TopodrakeError(f"p_sparsify must be in (0, 1), got {p}")
    if window < 1 or max_window < 1:
        raise TopodrakeError("window and max_window must be >= 1")
    if not 0.0 <= slack < 1.0:
        raise TopodrakeError(f"sparsify slack must be in [0, 1), got {slack}")
    snap = snap or (lambda j, source: j)
    i = 0
    source = snap(0, 0)
    anchors, sources = [0], [source]
    last = n_frames - 1
    while i < last:
        threshold = p
        j_pass = i                       # last frame that passed from the source
        start = i + 1
        size = window
        end = last if cap is None else max(i + 1, min(last, int(cap[i])))
        while start <= end:
            js = np.arange(start, min(start + size, end + 1))
            size = min(2 * size, max(max_window, window))
            probs = np.asarray(reach(source, js), np.float64).reshape(-1)
            if probs.shape != js.shape:
                raise TopodrakeError(f"reach() returned {probs.size} values for {js.size} frames")
            if start == i + 1 and slack > 0 and not probs[0] > p:
                threshold = probs[0] - slack     # the next frame fails p: stay near its RE
            fail = np.flatnonzero(~(probs > threshold))
            if fail.size:
                j_pass = int(js[fail[0]]) - 1
                break
            j_pass = int(js[-1])
            start = j_pass + 1
        i = max(j_pass, i + 1)
        source = snap(i, source)
        anchors.append(i)
        sources.append(source)
    return np.asarray(anchors, np.int64), sources
