"""The frames a map keeps: raw observations, poses (metadata) and RE features.

Every map vertex is an anchor frame with its (2k+1)-frame context; the
frames of all those contexts live in one :class:`FrameBank`, and vertices
refer to them by row. The bank keeps the raw observations (what a map file
stores) and computes the scorer's per-frame features on demand, once per
row: building a map needs them for every row, planning only for the few
vertices that retrieval proposes.

While a trajectory is added, all its frames are appended (sparsification
and the matching against the map need them); :meth:`FrameBank.keep_tail`
then drops the ones no vertex refers to, which touches only the tail.
"""

from __future__ import annotations

import numpy as np

from topodrake.errors import TopodrakeError


class _Growable:
    """A numpy array or torch tensor along axis 0 with amortised appends."""

    def __init__(self):
        self.buf = None
        self.size = 0

    def _empty(self, like, capacity: int):
        if hasattr(like, "new_empty"):
            return like.new_empty((capacity, *like.shape[1:]))
        return np.empty((capacity, *like.shape[1:]), like.dtype)

    def reserve(self, like, size: int) -> None:
        if self.buf is None:
            self.buf = self._empty(like, max(size, 16))
        elif len(self.buf) < size:
            bigger = self._empty(self.buf, max(size, 2 * len(self.buf)))
            bigger[:self.size] = self.buf[:self.size]
            self.buf = bigger

    def set_rows(self, start: int, values) -> None:
        self.reserve(values, start + len(values))
        self.buf[start:start + len(values)] = values
        self.size = max(self.size, start + len(values))

    def view(self):
        return self.buf[:self.size]


class FrameBank:
    """Rows of kept frames for one :class:`~topodrake.topomap.scorer.MapScorer`."""

    def __init__(self, scorer, observations: np.ndarray | None = None,
                 poses: np.ndarray | None = None):
        self.scorer = scorer
        self._obs = _Growable()
        self._poses = _Growable()
        self._scans = _Growable()
        self._feats: dict[str, _Growable] = {}
        self._have = np.zeros(0, bool)
        if observations is not None and len(observations):
            self.append(observations, poses)

    def __len__(self) -> int:
        return self._obs.size

    @property
    def observations(self) -> np.ndarray:
        return self._obs.view()

    @property
    def poses(self) -> np.ndarray:
        return self._poses.view()

    @property
    def scans(self) -> np.ndarray | None:
        """(F, beams) the lidar scan taken with each frame, where a camera
        map keeps them (NaN rows: none; None: the bank keeps no scans)."""
        return self._scans.view() if self._scans.size else None

    def append(self, observations: np.ndarray, poses: np.ndarray | None = None,
               features: dict | None = None, scans: np.ndarray | None = None) -> np.ndarray:
        """Add frames; returns their rows. ``features`` (if already computed
        for exactly these frames) are kept instead of being recomputed;
        ``scans`` (N, beams): the lidar scans taken with them."""
        observations = np.asarray(observations)
        n = len(observations)
        if poses is None:
            poses = np.full((n, 3), np.nan)
        poses = np.asarray(poses, np.float64).reshape(-1, 3)
        if len(poses) != n:
            raise TopodrakeError(f"{n} observations but {len(poses)} poses")
        start = len(self)
        if scans is not None:
            scans = np.asarray(scans, np.float64)
            if scans.ndim != 2 or len(scans) != n:
                raise TopodrakeError(f"{n} observations but scans of shape {scans.shape}")
            if self._scans.size and scans.shape[1] != self._scans.buf.shape[1]:
                raise TopodrakeError(f"scans of {scans.shape[1]} beams for a map of "
                                     f"{self._scans.buf.shape[1]}")
            if start and not self._scans.size:          # frames before kept none
                self._scans.set_rows(0, np.full((start, scans.shape[1]), np.nan))
        elif self._scans.size:
            scans = np.full((n, self._scans.buf.shape[1]), np.nan)
        self._obs.set_rows(start, observations)
        self._poses.set_rows(start, poses)
        if scans is not None:
            self._scans.set_rows(start, scans)
        self._have = np.concatenate([self._have, np.zeros(n, bool)])
        if features is not None:
            self._store(np.arange(start, start + n), features)
        return np.arange(start, start + n)

    def _store(self, rows: np.ndarray, feats: dict) -> None:
        for name, value in feats.items():
            g = self._feats.setdefault(name, _Growable())
            g.reserve(value, len(self))
            g.buf[rows] = value
            g.size = len(self)
        self._have[rows] = True

    def ensure(self, rows: np.ndarray, batch: int = 512) -> None:
        """Compute the features of ``rows`` that are not there yet."""
        rows = np.unique(np.asarray(rows, np.int64))
        missing = rows[~self._have[rows]]
        for lo in range(0, len(missing), batch):
            part = missing[lo:lo + batch]
            self._store(part, self.scorer.features(self.observations[part]))

    def features(self) -> dict:
        return {name: g.buf[:len(self)] for name, g in self._feats.items()}

    def score(self, source: np.ndarray, context_rows: np.ndarray) -> np.ndarray:
        """RE(frame ``source[m]`` -> context ``context_rows[m]``) (M,)."""
        source = np.asarray(source, np.int64).reshape(-1)
        rows = np.asarray(context_rows, np.int64).reshape(len(source), -1)
        if len(source) == 0:
            return np.zeros(0)
        self.ensure(np.concatenate([source, rows.ravel()]))
        return np.asarray(self.scorer.score(self.features(), source, rows), np.float64)

    def keep_tail(self, start: int, keep: np.ndarray) -> np.ndarray:
        """Keep only rows ``keep`` (sorted, all >= ``start``) of the tail that
        begins at ``start``; returns the map old row -> new row (-1 dropped)
        for the old tail rows ``start ..``."""
        keep = np.asarray(keep, np.int64)
        if len(keep) and (keep.min() < start or np.any(np.diff(keep) <= 0)):
            raise ValueError("keep must be increasing rows of the tail")
        n_tail = len(self) - start
        new = np.arange(start, start + len(keep))
        for g in (self._obs, self._poses, self._scans, *self._feats.values()):
            if g.buf is not None and g.size > start:
                g.buf[new] = g.buf[keep]
                g.size = start + len(keep)
        have = self._have[keep]
        self._have = np.concatenate([self._have[:start], have])
        mapping = np.full(n_tail, -1, np.int64)
        mapping[keep - start] = new
        return mapping
