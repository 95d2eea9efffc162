"""The map file (``.tdmap``): one versioned file, written atomically.

A map file is a compressed NumPy archive (zip) without pickled objects:

==================  ==========================================================
``meta``            JSON (UTF-8 bytes): ``format`` "topodrake-map", ``version``,
                    ``world``, ``modality``, ``k``, ``frame_step``, ``config``
                    (:class:`~topodrake.topomap.graph.MapConfig` in its flat
                    form, :meth:`~topodrake.topomap.graph.MapConfig.flat`), ``identity``
                    (the RE and C_WP checkpoints and their SHA-1, or the
                    oracle), ``embedding`` (name and fingerprint),
                    ``raw_frames``, ``trajectories`` (name and frames each)
``observations``    (F, ...) kept frames: camera uint8 (H, W, 3), lidar ranges
                    float32 in metres as the lidar gave them (inf = no hit;
                    before version 4 millimetres uint16, 65535 = no hit),
                    oracle poses
``poses``           (F, 3) where each frame was taken (metadata)
``scans``           (F, beams) float32, optional: the lidar scan taken with
                    each frame of a camera map (inf = no hit, NaN = none),
                    for the route tracker's scan fixes
``vertex_*``        per vertex: ``id``, ``center`` row, ``context`` rows
                    (V, 2k+1), origin ``traj``, ``frame`` and chain ``pos``
``edge_*``          per edge: ``src``, ``dst``, ``p``, ``kind`` (0 trajectory,
                    1 cross, 2 junction: from version 3), ``leg`` (E, 3) and
                    ``leg_path`` (E, LEG_POINTS, 3): the drive's odometry over
                    a trajectory edge, or a junction's registered offset (NaN
                    where none; from version 2); optional, where cars drove
                    the map (:mod:`~topodrake.topomap.recalibrate`):
                    ``passed``, ``failed`` and ``p_re`` (RE's own rating; NaN
                    on edges never driven)
``chain_ids``       every trajectory's chain of vertices, concatenated;
``chain_offsets``   (trajectories + 1,) into it
``embeddings``      (V, D) the vertices' place embeddings
``checksum``        (from version 5) the SHA-256 of every other entry
                    (:func:`payload_sha256`: each entry's name, dtype, shape
                    and bytes, in name order)
==================  ==========================================================

Reading a map's arrays (:func:`load_map`, :func:`read_map_arrays`) refuses,
each with one line naming the file and the problem: a truncated or foreign
file, an unknown version, a damaged one (an entry that fails its CRC-32, a
payload that differs from its ``checksum``, or bytes that differ from the
SHA-256 a card beside it records, as ``checkpoints/demo_map/card.json``
does), an inconsistent one (:func:`check_arrays`: arrays of unequal
length, ids that refer to nothing, a probability outside [0, 1], a pose
that is not finite), and a map built for another RE or controller than the
one given. Files of versions 1 to 4 carry no checksum: they are checked
for consistency (and against their card) only. Version 1 files (without
legs) are read as maps without odometry on their edges, version 2 files as
maps without junction edges. A stored config is read by
:meth:`~topodrake.topomap.graph.MapConfig.from_dict` (``stored``): the
settings it predates as :data:`~topodrake.topomap.graph.LATER_DEFAULTS`, a
deleted rule's setting dropped.
"""

from __future__ import annotations

import hashlib
import io
import json
from pathlib import Path

import numpy as np

from topodrake.contract.route import LEG_POINTS
from topodrake.errors import TopodrakeError
from topodrake.fileio import atomic_write_bytes, check_card, damaged, forget_card_sha256, is_zip
from topodrake.topomap.graph import EDGE_KINDS, LATER_DEFAULTS, MapConfig, TopoMap, Trajectory
from topodrake.topomap.retrieval import default_embedding

FORMAT = "topodrake-map"
VERSION = 5
READS = (1, 2, 3, 4, 5)   # versions this topodrake reads
#: the first version whose files carry the checksum of their payload
CHECKSUM_SINCE = 5
CHECKSUM = "checksum"
_NO_HIT_MM = 65535


def _encode_observations(modality: str, obs: np.ndarray) -> np.ndarray:
    if modality == "camera":
        return np.asarray(obs, np.uint8)
    if modality == "lidar":
        return np.asarray(obs, np.float32)
    return np.asarray(obs, np.float64)


def _decode_observations(modality: str, stored: np.ndarray) -> np.ndarray:
    if modality == "lidar" and stored.dtype == np.uint16:     # millimetres, before version 4
        return np.where(stored == _NO_HIT_MM, np.inf, stored / 1000.0).astype(np.float32)
    return stored


def save_map(topomap: TopoMap, path) -> Path:
    """Write ``topomap`` to ``path`` atomically (the old file stays until the new one is whole)."""
    m = topomap
    verts = np.array(sorted(m.graph.nodes), np.int64)
    nodes = [m.graph.nodes[v] for v in verts]
    edges = list(m.graph.edges(data=True))
    chains = [t.chain for t in m.trajectories]
    emb = np.zeros((0, m.index.vectors.shape[1]), np.float32)
    if len(verts):
        order = {int(v): i for i, v in enumerate(m.index.ids)}
        emb = m.index.vectors[[order[int(v)] for v in verts]]
    meta = {"format": FORMAT, "version": VERSION, "world": m.world, "modality": m.modality,
            "k": m.k, "frame_step": m.frame_step, "config": m.config.flat(),
            "identity": m.identity,
            "embedding": {"name": m.embedding.name, "fingerprint": m.embedding.fingerprint()},
            "raw_frames": m.raw_frames,
            "trajectories": [{"name": t.name, "frames": t.frames} for t in m.trajectories]}
    nan_leg, nan_path = np.full(3, np.nan), np.full((LEG_POINTS, 3), np.nan)
    arrays = dict(
        meta=np.frombuffer(json.dumps(meta).encode(), np.uint8),
        observations=_encode_observations(m.modality, m.bank.observations),
        poses=m.bank.poses,
        **({} if m.bank.scans is None else {"scans": m.bank.scans.astype(np.float32)}),
        vertex_id=verts, vertex_center=np.array([n["center"] for n in nodes], np.int64),
        vertex_context=np.array([n["context"] for n in nodes], np.int64).reshape(len(verts), -1),
        vertex_traj=np.array([n["traj"] for n in nodes], np.int64),
        vertex_frame=np.array([n["frame"] for n in nodes], np.int64),
        vertex_pos=np.array([n["pos"] for n in nodes], np.int64),
        edge_src=np.array([u for u, _, _ in edges], np.int64),
        edge_dst=np.array([v for _, v, _ in edges], np.int64),
        edge_p=np.array([d["p"] for _, _, d in edges], np.float64),
        edge_kind=np.array([EDGE_KINDS.index(d["kind"]) for _, _, d in edges], np.uint8),
        edge_leg=np.array([d.get("leg", nan_leg) for _, _, d in edges],
                          np.float64).reshape(len(edges), 3),
        edge_leg_path=np.array([d.get("leg_path", nan_path) for _, _, d in edges],
                               np.float64).reshape(len(edges), LEG_POINTS, 3),
        **_experience_arrays(edges),
        chain_ids=np.array([v for c in chains for v in c], np.int64),
        chain_offsets=np.cumsum([0] + [len(c) for c in chains]).astype(np.int64),
        embeddings=emb)
    arrays[CHECKSUM] = np.array(payload_sha256(arrays))
    buf = io.BytesIO()
    np.savez_compressed(buf, **arrays)
    forget_card_sha256(path)
    return atomic_write_bytes(path, buf.getvalue())


def payload_sha256(arrays: dict) -> str:
    """SHA-256 of a map file's entries but its checksum: each entry's name,
    dtype, shape and bytes, in name order."""
    h = hashlib.sha256()
    for name in sorted(arrays):
        if name == CHECKSUM:
            continue
        a = np.ascontiguousarray(arrays[name])
        h.update(f"{name}\0{a.dtype.str}\0{a.shape}\0".encode())
        h.update(memoryview(a.reshape(-1)).cast("B"))
    return h.hexdigest()


def _experience_arrays(edges) -> dict:
    """The edges' driving experience as arrays (none where no edge was driven)."""
    if not any("p_re" in d for _, _, d in edges):
        return {}
    return {"edge_p_re": np.array([d.get("p_re", np.nan) for _, _, d in edges], np.float64),
            "edge_passed": np.array([d.get("passed", 0) for _, _, d in edges], np.int64),
            "edge_failed": np.array([d.get("failed", 0) for _, _, d in edges], np.int64)}


def _set_experience(m: TopoMap, z, path) -> None:
    n_e = len(z["edge_src"])
    if any(len(z.get(k, ())) != n_e for k in ("edge_p_re", "edge_passed", "edge_failed")):
        raise TopodrakeError(f"{path}: the edges' driving experience does not cover its "
                             f"{n_e} edges")
    for u, v, p_re, n_pass, n_fail in zip(z["edge_src"], z["edge_dst"], z["edge_p_re"],
                                          z["edge_passed"], z["edge_failed"]):
        if np.isfinite(p_re):
            m.graph.edges[int(u), int(v)].update(p_re=float(p_re), passed=int(n_pass),
                                                 failed=int(n_fail))


def read_map_meta(path) -> dict:
    """The ``meta`` of a map file, checked (format and version)."""
    meta, _ = _read(path, arrays=False)
    return meta


def read_map_arrays(path) -> tuple[dict, dict]:
    """``(meta, arrays)`` of a map file, checked, without building the map."""
    return _read(path)


def _read(path, arrays: bool = True) -> tuple[dict, dict]:
    """``(meta, arrays)``; with ``arrays`` the whole file is checked (its card,
    every entry's CRC-32, the checksum, the arrays' consistency), else only
    its meta is read."""
    path = Path(path)
    if path.is_dir():
        raise TopodrakeError(f"{path} is a folder, not a map file")
    if not path.is_file():
        raise TopodrakeError(f"map file {path} does not exist")
    if arrays:
        check_card(path, "map file")
    try:
        with np.load(path, allow_pickle=False) as z:
            meta = json.loads(bytes(z["meta"]).decode())
            if not isinstance(meta, dict) or meta.get("format") != FORMAT:
                raise TopodrakeError(f"{path} is not a topodrake map file")
            if meta.get("version") not in READS:
                raise TopodrakeError(f"{path} has map format version {meta.get('version')}; "
                                     f"this topodrake reads versions "
                                     f"{', '.join(map(str, READS))}")
            data = {name: z[name] for name in z.files} if arrays else {}
    except TopodrakeError:
        raise
    except Exception as e:      # zip, zlib, npy and JSON errors alike
        what = f"{type(e).__name__}: {str(e).splitlines()[0]}" if str(e).strip() \
            else type(e).__name__
        if is_zip(path):
            raise TopodrakeError(f"{path} is damaged or truncated ({what}); it was not "
                                 f"loaded") from None
        raise TopodrakeError(f"{path} is truncated or not a topodrake map file "
                             f"({type(e).__name__})") from None
    if arrays:
        check_arrays(path, meta, data)
        want = data.pop(CHECKSUM, None)
        if meta["version"] >= CHECKSUM_SINCE:
            if want is None:
                raise damaged("map file", path, f"a version {meta['version']} map without "
                                                f"its {CHECKSUM!r}")
            have = payload_sha256(data)
            if str(want) != have:
                raise damaged("map file", path, f"its payload's SHA-256 {have[:12]}... "
                                                f"differs from the {str(want)[:12]}... it "
                                                f"was saved with")
        data.pop("meta")
    return meta, data


#: the arrays every map file holds
REQUIRED = ("meta", "observations", "poses", "vertex_id", "vertex_center", "vertex_context",
            "vertex_traj", "vertex_frame", "vertex_pos", "edge_src", "edge_dst", "edge_p",
            "edge_kind", "chain_ids", "chain_offsets", "embeddings")


def check_arrays(path, meta: dict, z: dict) -> None:
    """A map file's metadata and arrays hold together: every entry there,
    per-vertex and per-edge arrays of one length each, unique vertex ids
    that every edge and chain refers to, frame rows inside the file,
    finite poses and legs, edge probabilities in [0, 1], known edge kinds,
    chains that cover the trajectories. Anything else raises one line
    naming the file and the first problem."""
    def bad(problem: str) -> TopodrakeError:
        return TopodrakeError(f"{path} is an inconsistent map file: {problem}")

    for key, kind in (("world", str), ("modality", str), ("k", int), ("raw_frames", int),
                      ("trajectories", list), ("identity", dict), ("config", dict),
                      ("embedding", dict)):
        if not isinstance(meta.get(key), kind) or isinstance(meta.get(key), bool):
            raise bad(f"its meta lacks {key!r} or it is no {kind.__name__}")
    if meta["k"] < 0 or meta["raw_frames"] < 0:
        raise bad("its meta has a negative k or raw_frames")
    for t in meta["trajectories"]:
        if not (isinstance(t, dict) and isinstance(t.get("name"), str)
                and isinstance(t.get("frames"), int) and t["frames"] >= 0):
            raise bad(f"its meta has a trajectory entry {str(t)[:60]!r} without a name and "
                      f"frame count")
    if not isinstance(meta["embedding"].get("name"), str):
        raise bad("its meta lacks the embedding's name")
    missing = [name for name in REQUIRED if name not in z]
    if missing:
        raise bad(f"it lacks the array {missing[0]!r}")

    def ints(name):
        a = z[name]
        if a.dtype.kind not in "iu":
            raise bad(f"{name} holds {a.dtype} values, not integers")
        return a

    def length(names, n, what):
        for name in names:
            if name in z and (z[name].ndim == 0 or len(z[name]) != n):
                have = "a scalar" if z[name].ndim == 0 else f"{len(z[name])} entries"
                raise bad(f"{name} has {have} for {n} {what}")

    obs, poses = z["observations"], z["poses"]
    if obs.ndim == 0:
        raise bad("observations is a scalar")
    n_frames = len(obs)
    if poses.shape != (n_frames, 3):
        raise bad(f"poses has shape {poses.shape}, not ({n_frames}, 3) for its {n_frames} frames")
    unknown = np.isnan(poses).all(axis=1) if poses.dtype.kind == "f" else None
    # a frame without a pose (a map built from observations alone) is all NaN
    if unknown is None or not np.all(np.isfinite(poses[~unknown])):
        raise bad("a frame's pose is not finite")
    if "scans" in z and (z["scans"].ndim != 2 or len(z["scans"]) != n_frames):
        raise bad(f"scans has shape {z['scans'].shape} for {n_frames} frames")

    ids = ints("vertex_id")
    if ids.ndim != 1:
        raise bad(f"vertex_id has shape {ids.shape}")
    n_v = len(ids)
    length(("vertex_center", "vertex_context", "vertex_traj", "vertex_frame", "vertex_pos"),
           n_v, "vertices")
    for name in ("vertex_center", "vertex_traj", "vertex_frame", "vertex_pos"):
        if ints(name).ndim != 1:
            raise bad(f"{name} has shape {z[name].shape}")
    ctx = ints("vertex_context")
    if ctx.ndim != 2:
        raise bad(f"vertex_context has shape {ctx.shape}, not (vertices, context)")
    if n_v and (ids.min() < 0 or ids.max() >= 2 ** 31):
        v = ids[(ids < 0) | (ids >= 2 ** 31)][0]
        raise bad(f"vertex id {v} is out of range")
    if len(np.unique(ids)) != n_v:
        uniq, counts = np.unique(ids, return_counts=True)
        raise bad(f"vertex id {uniq[counts > 1][0]} is given twice")
    centers = z["vertex_center"]
    outside = (centers < 0) | (centers >= n_frames)
    if n_v and ctx.size:
        outside |= np.any((ctx < 0) | (ctx >= n_frames), axis=1)
    if np.any(outside):
        raise bad(f"vertex {ids[np.argmax(outside)]} refers to frames outside the file")
    n_traj = len(meta["trajectories"])
    trajs = z["vertex_traj"]
    if n_v and (trajs.min() < 0 or trajs.max() >= n_traj):
        i = int(np.argmax((trajs < 0) | (trajs >= n_traj)))
        raise bad(f"vertex {ids[i]} comes from trajectory {trajs[i]}; the map has {n_traj}")

    src, dst = ints("edge_src"), ints("edge_dst")
    if src.ndim != 1:
        raise bad(f"edge_src has shape {src.shape}")
    n_e = len(src)
    length(("edge_dst", "edge_p", "edge_kind", "edge_leg", "edge_leg_path", "edge_p_re",
            "edge_passed", "edge_failed"), n_e, "edges")
    known = np.isin(src, ids) & np.isin(dst, ids)
    if not np.all(known):
        i = int(np.argmin(known))
        v = src[i] if src[i] not in ids else dst[i]
        raise bad(f"edge {i} ({src[i]} -> {dst[i]}) refers to vertex {v}, which the map "
                  f"does not hold")
    p = z["edge_p"]
    if p.ndim != 1 or p.dtype.kind != "f":
        raise bad(f"edge_p has shape {p.shape} and dtype {p.dtype}")
    wrong = ~((p >= 0.0) & (p <= 1.0))            # NaN included
    if np.any(wrong):
        i = int(np.argmax(wrong))
        raise bad(f"edge {i} ({src[i]} -> {dst[i]}) has probability {p[i]}, outside [0, 1]")
    kinds = ints("edge_kind")
    if n_e and int(kinds.max()) >= len(EDGE_KINDS):
        raise bad(f"edge kind {int(kinds.max())} is unknown (known: {', '.join(EDGE_KINDS)})")
    for name, shape in (("edge_leg", (n_e, 3)), ("edge_leg_path", (n_e, LEG_POINTS, 3))):
        if name in z:
            if z[name].shape != shape:
                raise bad(f"{name} has shape {z[name].shape}, not {shape}")
            if np.any(np.isinf(z[name])):
                raise bad(f"{name} holds an infinite value")
    if "edge_p_re" in z:
        p_re = z["edge_p_re"]
        if np.any(~np.isnan(p_re) & ~((p_re >= 0) & (p_re <= 1))):
            raise bad("edge_p_re holds a probability outside [0, 1]")
        for name in ("edge_passed", "edge_failed"):
            if name not in z or ints(name).min(initial=0) < 0:
                raise bad(f"{name} is missing or negative")

    chain, off = ints("chain_ids"), ints("chain_offsets")
    if off.shape != (n_traj + 1,):
        raise bad(f"chain_offsets has shape {off.shape} for {n_traj} trajectories")
    if off[0] != 0 or off[-1] != len(chain) or np.any(np.diff(off) < 0):
        raise bad(f"chain_offsets do not run from 0 to the {len(chain)} chain entries")
    held = np.isin(chain, ids)
    if not np.all(held):
        raise bad(f"a chain refers to vertex {chain[np.argmin(held)]}, which the map does "
                  f"not hold")
    if z["embeddings"].ndim != 2:
        raise bad(f"embeddings has shape {z['embeddings'].shape}")


def identity_essence(identity: dict) -> dict:
    """What must match: the checkpoints' content hashes, or a whole oracle's identity."""
    return {k: v for k, v in identity.items() if k.endswith("_sha1")} or identity


def _describe(identity: dict) -> str:
    if "reach_sha1" in identity:
        return (f"RE {identity.get('reach', '?')} (sha1 {identity['reach_sha1'][:10]}) with C_WP "
                f"{identity.get('controller', '?')} (sha1 {identity.get('controller_sha1', '?')[:10]})")
    return f"RE {identity.get('reach', '?')}"


def check_identity(path, meta: dict, identity: dict) -> None:
    """Refuse a map built for another RE or controller than ``identity``."""
    have = meta.get("identity", {})
    if identity_essence(have) != identity_essence(identity):
        raise TopodrakeError(f"{path} was built for the reachability estimator and controller "
                             f"{_describe(have)}, not {_describe(identity)}")


def load_map(path, scorer, embedding=None) -> TopoMap:
    """Read a map file for ``scorer`` (its identity must match the file's).
    ``embedding`` defaults to the shipped one of the map's modality; if its
    fingerprint differs from the file's, the vertices are embedded anew."""
    meta, z = _read(path)
    check_identity(path, meta, scorer.identity)
    try:
        modality, k = meta["modality"], int(meta["k"])
        if modality != scorer.observation or k != scorer.k:
            raise TopodrakeError(f"{path} is a {modality} map with k={k}; the reachability "
                                 f"given is {scorer.observation} with k={scorer.k}")
        # (maps written before the slacks existed were built by the paper's rules; the
        # settings a map predates read as LATER_DEFAULTS)
        config = MapConfig.from_dict(
            {**LATER_DEFAULTS, "sparsify_slack": 0.0, "reuse_slack": 0.0, "reuse_rule": "paper",
             **meta["config"]}, f"{path}: config", stored=True).validate(f"{path}: config")
        embedding = embedding or default_embedding(modality)
        m = TopoMap(scorer, embedding, config, meta.get("world", ""), meta["identity"])
        obs = _decode_observations(modality, z["observations"])
        scans = z.get("scans")
        if scans is not None and (scans.ndim != 2 or len(scans) != len(obs)):
            raise TopodrakeError(f"{path}: {len(scans)} scans for {len(obs)} frames")
        m.bank.append(obs, z["poses"], scans=scans)
        n_rows = len(obs)
        for v, c, ctx, t, f, p in zip(z["vertex_id"], z["vertex_center"], z["vertex_context"],
                                      z["vertex_traj"], z["vertex_frame"], z["vertex_pos"]):
            if not (0 <= c < n_rows and ctx.min(initial=0) >= 0 and ctx.max(initial=0) < n_rows):
                raise TopodrakeError(f"{path}: vertex {v} refers to frames outside the file")
            m.graph.add_node(int(v), traj=int(t), frame=int(f), pos=int(p), center=int(c),
                             context=np.asarray(ctx, np.int64))
        n_e = len(z["edge_src"])
        legs = z.get("edge_leg", np.full((n_e, 3), np.nan))
        paths = z.get("edge_leg_path", np.full((n_e, LEG_POINTS, 3), np.nan))
        if n_e and int(np.max(z["edge_kind"])) >= len(EDGE_KINDS):
            raise TopodrakeError(f"{path}: edge kind {int(np.max(z['edge_kind']))} is unknown "
                                 f"(known: {', '.join(EDGE_KINDS)})")
        for u, v, p, kind, leg, path_ in zip(z["edge_src"], z["edge_dst"], z["edge_p"],
                                             z["edge_kind"], legs, paths):
            m.add_edge(int(u), int(v), float(p), EDGE_KINDS[int(kind)], leg, path_)
        if "edge_p_re" in z:
            _set_experience(m, z, path)
        off, ids = z["chain_offsets"], z["chain_ids"]
        for i, t in enumerate(meta["trajectories"]):
            m.trajectories.append(Trajectory(t["name"], int(t["frames"]),
                                             [int(v) for v in ids[off[i]:off[i + 1]]]))
        m.raw_frames = int(meta["raw_frames"])
        verts = z["vertex_id"]
        if (meta.get("embedding", {}).get("fingerprint") == embedding.fingerprint()
                and len(z["embeddings"]) == len(verts)):
            vectors = z["embeddings"]
        else:
            vectors = embedding.embed(m.bank.observations[z["vertex_center"]]) if len(verts) \
                else np.zeros((0, embedding.dim), np.float32)
        m.index.add(verts, vectors)
    except TopodrakeError:
        raise
    except (KeyError, TypeError, ValueError, IndexError) as e:
        raise TopodrakeError(f"{path} is an inconsistent map file ({type(e).__name__}: {e})") from None
    return m
