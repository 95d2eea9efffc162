"""How well a place embedding retrieves, and how fast a brute-force search is.

Recall split of one (test) house's demonstrations: queries are every
``query_step``-th frame of the first ``query_drives`` drives, the database
every ``db_step``-th frame of the other drives. A database frame is relevant
to a query when their symmetric camera overlap ``min(R_q->v, R_v->q)``
exceeds ``threshold`` (and, with an RE, when RE(query -> vertex) passes too).

recall@K of a query = |relevant in top K| / min(K, |relevant|), averaged over
the queries that have any relevant frame (1.0: the top K is as full of
relevant frames as it can be).

Search timing: one query against ``n`` random unit vectors of ``dim``
dimensions, top ``k`` by dot product: numpy (matrix-vector product +
argpartition + sort of the K) and, if installed, faiss ``IndexFlatIP`` on
one thread (``faiss_agrees``: the share of numpy's top K that faiss returns).
"""

from __future__ import annotations

import time

import numpy as np

from topodrake.contract.frames import context_frames
from topodrake.demonstrations import demo_poses
from topodrake.sensing.config import CameraConfig
from topodrake.sensing.observe import observe
from topodrake.sensing.overlap import mutual_overlap
from topodrake.world import load_world

KS = (8, 16, 32, 64)


def recall_at(scores: np.ndarray, relevant: np.ndarray, ks=KS) -> dict:
    """{K: mean recall@K} over queries (rows) with any relevant column."""
    rows = relevant.any(axis=1)
    scores, relevant = scores[rows], relevant[rows]
    order = np.argsort(-scores, axis=1, kind="stable")
    hits = np.take_along_axis(relevant, order, axis=1).cumsum(axis=1)
    n_rel = relevant.sum(axis=1)
    out = {}
    for k in ks:
        k_ = min(k, scores.shape[1])
        out[str(k)] = round(float(np.mean(hits[:, k_ - 1] / np.minimum(k_, n_rel))), 4)
    return out


def recall_split(world_name: str, data_dir, *, query_drives: int = 30, query_step: int = 20,
                 db_step: int = 20, seed: int = 0, protocol: str = "pairs") -> dict:
    """Query and database poses of a house's demonstrations (drive index of each)."""
    drives = demo_poses(world_name, data_dir, protocol, seed)
    pick = lambda ds, step: (np.concatenate([drives[i][::step] for i in ds]),      # noqa: E731
                             np.concatenate([np.full(len(drives[i][::step]), i) for i in ds]))
    q, qd = pick(range(query_drives), query_step)
    v, vd = pick(range(query_drives, len(drives)), db_step)
    vf = np.concatenate([np.arange(0, len(drives[i]), db_step)
                         for i in range(query_drives, len(drives))])
    return {"query_poses": q, "query_drive": qd, "db_poses": v, "db_drive": vd, "db_frame": vf,
            "drives": drives}


def overlap_relevance(world, split: dict, camera: CameraConfig | None = None,
                      threshold: float = 0.5) -> np.ndarray:
    """(Q, D) bool: symmetric camera overlap above ``threshold``."""
    q, v = split["query_poses"], split["db_poses"]
    a = np.repeat(q, len(v), axis=0)
    b = np.tile(v, (len(q), 1))
    return (mutual_overlap(world, a, b, camera).min(axis=1) > threshold).reshape(len(q), len(v))


def re_relevance(world, split: dict, reach, queries: np.ndarray, threshold: float = 0.5,
                 ) -> np.ndarray:
    """(len(queries), D) bool: RE(query -> vertex) > ``threshold``, the vertex
    seen with its context in its own drive; the RE's general calibration
    (temperature), as query and vertex come from different drives."""
    drives = split["drives"]
    ctx = [drives[d][context_frames(len(drives[d]), f, reach.k, reach.cfg.frame_step)]
           for d, f in zip(split["db_drive"], split["db_frame"])]
    ctx_poses = np.concatenate(ctx)                                   # (D * (2k+1), 3)
    q_poses = split["query_poses"][queries]
    obs = observe(world, reach.cfg.modality, np.concatenate([q_poses, ctx_poses]), reach.sensor)
    feats = reach.frame_features(obs)
    n_ctx = reach.cfg.frames
    rows = len(q_poses) + np.arange(len(ctx_poses)).reshape(-1, n_ctx)     # (D, 2k+1)
    source = np.repeat(np.arange(len(q_poses)), len(rows))
    p = reach.pairwise(feats, source, np.tile(rows, (len(q_poses), 1)),
                       platt=(1.0 / reach.temperature, 0.0))
    return (p > threshold).reshape(len(q_poses), len(rows))


def recall_study(world_name: str, data_dir, embeddings: list, *, camera: CameraConfig | None = None,
                 seed: int = 0, threshold: float = 0.5, relevance: np.ndarray | None = None,
                 split: dict | None = None) -> dict:
    """recall@K of each embedding on one house (geometric relevance unless given)."""
    world = load_world(world_name)
    split = split or recall_split(world_name, data_dir, seed=seed)
    rel = overlap_relevance(world, split, camera, threshold) if relevance is None else relevance
    out = {"queries": int(rel.any(axis=1).sum()), "database": int(rel.shape[1]),
           "mean_relevant": round(float(rel.sum(axis=1)[rel.any(axis=1)].mean()), 1)}
    for emb in embeddings:
        sensor = getattr(emb, "sensor", None)
        eq = emb.embed(observe(world, emb.observation, split["query_poses"], sensor))
        ev = emb.embed(observe(world, emb.observation, split["db_poses"], sensor))
        key = "recall_at" if emb.name != "thumbnail" else "baseline_recall_at"
        out[key] = recall_at(eq @ ev.T, rel)
    return out


def search_timing(n: int = 100000, dim: int = 64, k: int = 64, queries: int = 200,
                  seed: int = 0) -> dict:
    """Per-query milliseconds of a top-``k`` dot-product search over ``n`` vectors."""
    rng = np.random.default_rng(seed)
    db = rng.standard_normal((n, dim)).astype(np.float32)
    db /= np.linalg.norm(db, axis=1, keepdims=True)
    qs = db[rng.integers(0, n, queries)] + 0.1 * rng.standard_normal((queries, dim)).astype(np.float32)

    def numpy_top(q):
        s = db @ q
        idx = np.argpartition(s, n - k)[n - k:]
        return idx[np.argsort(-s[idx])]

    numpy_top(qs[0])
    t = time.perf_counter()
    top_np = [numpy_top(q) for q in qs]
    out = {"numpy_ms": round(1e3 * (time.perf_counter() - t) / queries, 3)}
    try:
        import faiss
    except ImportError:
        return out
    faiss.omp_set_num_threads(1)
    index = faiss.IndexFlatIP(dim)
    index.add(db)
    index.search(qs[:1], k)
    t = time.perf_counter()
    top_f = [index.search(q[None], k)[1][0] for q in qs]
    out["faiss_ms"] = round(1e3 * (time.perf_counter() - t) / queries, 3)
    out["faiss_agrees"] = float(np.mean([len(set(a) & set(b)) / k for a, b in zip(top_np, top_f)]))
    return out


def bench_place(checkpoint: str, world: str = "test-0", data_dir="data", seed: int = 0,
                threads: int = 1, reach: tuple[str, str] | None = None,
                re_queries: int = 60) -> dict:
    """recall@K of a place-embedding checkpoint and of the thumbnail baseline
    on ``world``, and the per-query search time at 100,000 vertices. With
    ``reach`` (RE checkpoint, its C_WP checkpoint), also recall@K against
    RE-passing vertices for ``re_queries`` evenly spread queries."""
    import torch

    from topodrake.topomap.embedding import PlaceEmbedding, ThumbnailEmbedding

    torch.set_num_threads(threads)
    emb = PlaceEmbedding.from_checkpoint(checkpoint)
    both = [emb, ThumbnailEmbedding(emb.observation, emb.sensor)]
    split = recall_split(world, data_dir)
    study = recall_study(world, data_dir, both, seed=seed, split=split)
    out = {"embedding": emb.name, "fingerprint": emb.fingerprint(), "world": world,
           "recall_at": study["recall_at"], "baseline_recall_at": study["baseline_recall_at"],
           "queries": study["queries"], "database": study["database"],
           "mean_relevant": study["mean_relevant"]}
    if reach is not None:
        from topodrake.learning.reachability.estimator import Reachability

        re = Reachability.from_checkpoint(*reach)
        idx = np.unique(np.linspace(0, len(split["query_poses"]) - 1, re_queries).astype(int))
        rel = re_relevance(load_world(world), split, re, idx)
        sub = {**split, "query_poses": split["query_poses"][idx]}
        re_study = recall_study(world, data_dir, both, seed=seed, split=sub, relevance=rel)
        out.update({"re_recall_at": re_study["recall_at"],
                    "re_baseline_recall_at": re_study["baseline_recall_at"],
                    "re_queries": re_study["queries"], "re_mean_relevant": re_study["mean_relevant"]})
    timing = search_timing(dim=emb.dim, seed=seed)
    out["query_ms_100k"] = timing.pop("numpy_ms")
    if "faiss_ms" in timing:
        out["query_ms_100k_faiss"] = timing["faiss_ms"]
        out["faiss_agrees"] = timing["faiss_agrees"]
    return out
