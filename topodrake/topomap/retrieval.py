"""Candidate retrieval: rank every map vertex cheaply, run RE on the top K.

Building and planning rank all vertices by a cheap place embedding of
their anchor observation and ask RE only about the ``K`` best.
:class:`VertexIndex` is that ranking: brute force in numpy, squared
Euclidean distance between embeddings (for unit vectors the same order as
cosine similarity).

Embeddings (anything with ``observation``, ``dim``, ``name``,
``embed(observations) -> (N, dim)`` and ``fingerprint()``):

* the learned place embedding (:mod:`topodrake.topomap.embedding`) for
  camera images and lidar scans;
* :class:`PoseEmbedding` for the pose oracle (position, and heading scaled
  so that a turn of one radian weighs like ``heading_m`` metres);
* :class:`~topodrake.topomap.embedding.ThumbnailEmbedding`, a
  training-free baseline (where no trained embedding is shipped).
"""

from __future__ import annotations

import numpy as np



class PoseEmbedding:
    """(x, y, h cos(theta), h sin(theta)) of poses: nearest = close and alike in heading."""

    observation = "pose"
    dim = 4

    def __init__(self, heading_m: float = 1.0):
        self.heading_m = float(heading_m)
        self.name = f"pose-h{self.heading_m:g}"

    def embed(self, observations: np.ndarray) -> np.ndarray:
        p = np.asarray(observations, np.float64).reshape(-1, 3)
        h = self.heading_m
        return np.column_stack([p[:, 0], p[:, 1], h * np.cos(p[:, 2]),
                                h * np.sin(p[:, 2])]).astype(np.float32)

    def fingerprint(self) -> str:
        return self.name


def default_embedding(observation: str):
    """The shipped embedding for a modality (the pose embedding for the
    oracle; the thumbnail baseline where no trained one is shipped)."""
    if observation == "pose":
        return PoseEmbedding()
    from pathlib import Path

    from topodrake.topomap.embedding import PlaceEmbedding, ThumbnailEmbedding

    path = Path(__file__).resolve().parents[2] / "checkpoints" / f"place_{observation}" / "checkpoint.pt"
    if path.is_file():
        return PlaceEmbedding.from_checkpoint(path)
    return ThumbnailEmbedding(observation)


class VertexIndex:
    """Embeddings of the map's vertices, searched brute force."""

    def __init__(self, embedding, dim: int | None = None):
        self.embedding = embedding
        self._vec = np.zeros((0, dim or embedding.dim), np.float32)
        self._sq = np.zeros(0, np.float32)
        self._ids = np.zeros(0, np.int64)

    def __len__(self) -> int:
        return len(self._ids)

    @property
    def ids(self) -> np.ndarray:
        return self._ids

    @property
    def vectors(self) -> np.ndarray:
        return self._vec

    def add(self, ids: np.ndarray, vectors: np.ndarray) -> None:
        vectors = np.asarray(vectors, np.float32).reshape(len(ids), -1)
        self._vec = np.concatenate([self._vec, vectors])
        self._sq = np.concatenate([self._sq, (vectors ** 2).sum(1)])
        self._ids = np.concatenate([self._ids, np.asarray(ids, np.int64)])

    def distances(self, queries: np.ndarray) -> np.ndarray:
        """(M, N) squared distances from the query vectors to every vertex."""
        q = np.asarray(queries, np.float32).reshape(-1, self._vec.shape[1])
        return np.maximum((q ** 2).sum(1)[:, None] + self._sq[None, :] - 2.0 * (q @ self._vec.T), 0.0)

    def positions(self, ids) -> np.ndarray:
        """Row of each vertex id in the index (-1 when absent)."""
        row = {int(v): i for i, v in enumerate(self._ids)}
        return np.array([row.get(int(v), -1) for v in ids], np.int64)

    def nearest(self, d: np.ndarray, k: int, exclude: np.ndarray | None = None) -> list[np.ndarray]:
        """Ids of the ``k`` smallest entries of each row of ``d`` (M, N)."""
        d = np.array(d, np.float64, copy=True).reshape(-1, len(self))
        if len(self) == 0 or k < 1:
            return [np.zeros(0, np.int64) for _ in d]
        if exclude is not None and len(exclude):
            d[:, np.isin(self._ids, exclude)] = np.inf
        k = min(k, len(self))
        part = np.argpartition(d, k - 1, axis=1)[:, :k] if k < len(self) else \
            np.broadcast_to(np.arange(len(self)), (len(d), len(self)))
        out = []
        for row, cand in zip(d, part):
            cand = cand[np.isfinite(row[cand])]
            out.append(self._ids[cand[np.argsort(row[cand], kind="stable")]])
        return out

    def search(self, queries: np.ndarray, k: int, exclude: np.ndarray | None = None) -> list[np.ndarray]:
        """For each query vector (M, dim) the ids of its ``k`` nearest
        vertices, nearest first (fewer when the index is smaller)."""
        if len(self) == 0:
            return [np.zeros(0, np.int64) for _ in np.atleast_2d(queries)]
        return self.nearest(self.distances(queries), k, exclude)
