"""The topological map: anchors as vertices of a networkx DiGraph.

A vertex is an anchor frame of a driven trajectory. It knows the trajectory
and frame it came from, its position in that trajectory's chain, and the
rows of its observation context in the map's
:class:`~topodrake.topomap.bank.FrameBank` (``center``: the anchor frame
itself, ``context``: the 2k+1 frames a target needs). Building and
planning read observations (through RE) only; where a frame was taken
(``TopoMap.pose``) is privileged metadata for plots and evaluation.

An edge u -> v carries ``p``, the predicted probability that the controller
drives from u to v, ``weight`` = -log p (what Dijkstra adds up) and
``kind``: ``"trajectory"`` (consecutive anchors of one drive) or
``"cross"`` (found between drives) or ``"junction"`` (a drive's arrival to
another's departure at the place where both end). A trajectory edge also carries the
odometry of the drive that made it from u to v (``leg``: v's pose in u's
frame; ``leg_path``: ``LEG_POINTS`` poses along the hop), a relative
transform as a real robot measures it, never an absolute pose; at a vertex
another drive placed (reuse), a lidar map registers that vertex's scan onto
the drive's to place it, as does a camera map that keeps its drives' lidar
scans (``camera_legs``), and other maps leave the hop without. Such maps
give a cross edge (``cross_legs``) and a junction the pose that
registering the two vertices' scans finds, where the fit pins it. A planned
route hands the legs to the follower.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

import networkx as nx
import numpy as np

from topodrake.errors import TopodrakeError
from topodrake.contract.route import LEG_POINTS
from topodrake.topomap.bank import FrameBank
from topodrake.topomap.retrieval import VertexIndex

EDGE_KINDS = ("trajectory", "cross", "junction")


REUSE_RULES = ("paper", "resume")
TEACH_ODOMETRY = ("wheel", "perfect", "none")
#: settings added after maps were first written whose default builds a map as
#: before: a stored config without them reads as these values
LATER_DEFAULTS = {"reuse_ahead": 0, "scan_match": 0.0, "scan_match_cross": False,
                  "camera_scans": False, "camera_legs": False, "loop_check_m": 0.0,
                  "loop_check_per_m": 0.1, "reuse_pinned": False, "cross_legs": False,
                  "junction_scan_match": 0.8, "camera_junction_scans": True, "max_hop_m": 0.0}


#: settings only a lidar map reads (a map of another modality is built alike whatever they say)
LIDAR_ONLY = ("scan_match_cross", "reuse_pinned", "max_hop_m")
#: settings only a camera map reads
CAMERA_ONLY = ("camera_scans", "camera_legs", "camera_junction_scans")
#: settings only maps that place joins by lidar scans read (a pose oracle map keeps its
#: drives' scans for the route tracker only)
SCANS_ONLY = ("cross_legs",)
#: settings only planning reads, not building (a map is built alike whatever they say)
PLAN_ONLY = ("link_order", "direct_check", "goal_leg", "legless_p", "switch_p", "start_near_m",
             "start_near_deg", "start_near_behind_m")
LINK_ORDERS = ("probability", "support")


def same_config(stored, config: "MapConfig", lidar: bool = True, scans: bool = True) -> bool:
    """Whether a map file's stored config is ``config`` (the settings it
    predates read as :data:`LATER_DEFAULTS`), as far as building reads them
    (:func:`map_settings`: neither the :data:`PLAN_ONLY` settings count nor
    those of the other kind of map)."""
    if not isinstance(stored, dict):
        return False
    return map_settings({**LATER_DEFAULTS, **stored}, lidar, scans) \
        == map_settings(asdict(config), lidar, scans)


def map_settings(config: dict, lidar: bool = True, scans: bool = True) -> dict:
    """The settings of a map config (as a dict) that building a map of its
    kind reads: without the :data:`PLAN_ONLY` ones, nor the
    :data:`LIDAR_ONLY` ones where it is not a lidar map, nor the
    :data:`CAMERA_ONLY` ones where it is one, nor the :data:`SCANS_ONLY`
    ones where it keeps no scans (a pose oracle map). (A scan_match set for
    a pose oracle map counts too: harmless, it only names another cached
    map.)"""
    other = (CAMERA_ONLY if lidar else LIDAR_ONLY) + (() if scans else SCANS_ONLY)
    return {k: v for k, v in config.items() if k not in PLAN_ONLY and k not in other}


@dataclass
class MapConfig:
    """How a map is built and queried (the paper's settings by default)."""

    p_sparsify: float = 0.99     # anchors: the next one is the last frame RE passes above this
    sparsify_slack: float = 0.01  # ... and where RE passes not even the next frame, the last one
                                  # within this of the next frame's RE (0: the paper's rule)
    p_reuse: float = 0.99        # an existing vertex stands in for an anchor above this (both hops)
    reuse_slack: float = 0.0     # ... or, where the anchor's own hop is below p_reuse, above that
                                 # hop's RE less this (0: the paper's rule; reuse_rule "paper" only)
    p_edge: float = 0.99         # cross edges: sequence-matched RE above this
    sequence_window: int = 2     # aligned anchors on each side for sequence matching
    join_ends: bool = True       # junction edges: a drive's last vertex -> another's first ...
    p_join: float = 0.7          # ... where RE passes this both ways
    retrieval_k: int = 64        # building: vertices ranked by the embedding that RE checks
    retrieval_first: int = 0     # cross edges: RE checks this many first, the rest of the top
                                 # retrieval_k only for a vertex with edges in the second half
                                 # of them (0: all retrieval_k at once)
    sequence_retrieval: bool = True  # cross edges: rank by the aligned neighbours' embeddings too
    p_link: float = 0.5          # planning: start and goal links above this
    link_k: int = 32             # planning: vertices ranked by the embedding that RE checks
                                 # for the start and goal links
    link_consensus: bool = True  # planning: keep the start's (goal's) links of one place only:
    link_hops: int = 3           # ... links within this many edges of each other are one place
    link_order: str = "probability"  # ... the groups tried first: "probability" (the most
                                 # probable link's), "support" (the most links' probability in
                                 # all: a place seen from several anchors before a lone look-alike)
    direct_check: bool = True    # planning: a direct start-goal link only where the start's
                                 # and the goal's links are one place (within link_hops; a
                                 # look-alike room otherwise joins them in one step)
    goal_mutual: bool = True     # planning: a goal link's p is min(RE(v, goal), RE(goal, v))
    sparsify_window: int = 4     # first window of candidates in the greedy scan
    max_hop_m: float = 2.5       # ... which takes no frame farther along the drive than this
                                 # (by its odometry) as the next anchor of a lidar map: the
                                 # route tracker registers the car's scan onto anchors within
                                 # 2.5 m (TrackerConfig.scan_range_m), and in a corridor RE
                                 # trusts hops of 4-6 m (0: off)
    reuse: bool = True
    reuse_rule: str = "resume"   # "paper": a vertex replaces a sparsified anchor; "resume":
                                 # it stands in for an anchor frame and the scan resumes from it
    teach_odometry: str = "wheel"  # the drives' odometry stored on trajectory edges: wheel
                                   # odometry that drifts, the true motion, or none
    reuse_ahead: int = 0         # resume reuse: a stand-in's drive must lead on where this one
                                 # goes (its successor within RE of one of the next this many
                                 # context steps' frames; 0: off)
    reuse_legs: bool = True      # lidar maps: edges into and out of a reused vertex carry the
                                 # drive's odometry too, the vertex placed by registering its scan
    scan_match: float = 0.8      # lidar maps: a reused vertex, a junction and the plan's start
                                 # and goal links must match by registering the scans, each
                                 # scan's points paired at least this share (0: off)
    junction_scan_match: float = 0.7  # ... but a junction's two scans need pair only this
                                 # share: an arrival and a departure at one place face
                                 # different ways, which leaves far beams without a partner
                                 # (chosen on train-60..63; docs/figures.md, "Drives that join")
    scan_match_cross: bool = False  # ... and cross edges too (off: the long cross edges it
                                    # drops in open rooms are true hops, and success did not move)
    camera_scans: bool = True    # camera maps that keep their drives' lidar scans check a reused
                                 # vertex by scan_match too (textures repeat) ...
    camera_junction_scans: bool = False  # ... and a junction (off: RE both ways tells a camera
                                 # map's junctions apart, and the scans refused true ones)
    camera_legs: bool = True     # ... and place them by registering those scans, as lidar maps
                                 # do: hops into and out of them keep the drive's odometry
    loop_check_m: float = 1.5    # a reused vertex must lie where the drive's odometry puts it,
                                 # from the vertex it reused last along the map's legs, within
                                 # this (0: off) ...
    loop_check_per_m: float = 0.1  # ... plus this share of the metres measured
    reuse_pinned: bool = True    # lidar maps: reuse only a vertex whose scan registers onto the
                                 # drive's pinning the translation, so every hop into and out of
                                 # it keeps a leg (and the loop check can see it)
    cross_legs: bool = True      # maps that place joins by scans (lidar; camera with
                                 # camera_legs): a cross edge carries the pose its scans
                                 # register to, where the fit pins it (a hop between drives
                                 # the follower can then track across)
    goal_leg: bool = True        # planning, on such maps: the hop into the goal carries the
                                 # pose the goal view's scan registers to on the last vertex's,
                                 # where the fit pins it
    legless_p: float = 0.98      # planning, on such maps: a hop of the map without a leg (a
                                 # join its scans could not place) counts its p times this: the
                                 # follower cannot track across it and fails it more often
    switch_p: float = 0.9        # planning: a hop between drives (a cross or junction edge)
                                 # counts its p times this (1: off): each switch hands the
                                 # route tracker over to another drive's frames
    start_near_m: float = 2.0    # planning, where the links are checked by scans: plans start
                                 # first from the vertices the start's scan registers onto
                                 # within this (0: off), then from every link: at the anchor
                                 # the car stands by, not one RE trusts metres on ...
    start_near_deg: float = 60.0   # ... of such vertices only those facing the car's way
    start_near_behind_m: float = 0.3  # within this and at most this far behind it count

    def validate(self, where: str = "map config") -> "MapConfig":
        for name in ("p_sparsify", "p_reuse", "p_edge", "p_link", "p_join"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and 0.0 < v < 1.0):
                raise TopodrakeError(f"{where}: {name} must be in (0, 1), got {v}")
        for name in ("sparsify_slack", "reuse_slack"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and 0.0 <= v < 1.0):
                raise TopodrakeError(f"{where}: {name} must be in [0, 1), got {v}")
        for name, choices in (("reuse_rule", REUSE_RULES), ("link_order", LINK_ORDERS),
                              ("teach_odometry", TEACH_ODOMETRY)):
            if getattr(self, name) not in choices:
                raise TopodrakeError(f"{where}: {name} must be one of {', '.join(choices)}, "
                                     f"got {getattr(self, name)!r}")
        for name in ("link_consensus", "direct_check", "join_ends", "scan_match_cross",
                     "reuse_legs", "camera_scans", "camera_legs", "reuse_pinned", "cross_legs",
                     "goal_leg", "camera_junction_scans"):
            if not isinstance(getattr(self, name), bool):
                raise TopodrakeError(f"{where}: {name} must be true or false, got "
                                     f"{getattr(self, name)!r}")
        for name in ("legless_p", "switch_p"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and 0.0 < v <= 1.0):
                raise TopodrakeError(f"{where}: {name} must be in (0, 1], got {v!r}")
        for name in ("loop_check_m", "loop_check_per_m", "start_near_m", "start_near_deg",
                     "start_near_behind_m", "max_hop_m"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise TopodrakeError(f"{where}: {name} must be a number >= 0, got {v!r}")
        for name in ("scan_match", "junction_scan_match"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and 0.0 <= v < 1.0):
                raise TopodrakeError(f"{where}: {name} must be in [0, 1), got {v!r}")
        if self.reuse_slack > 0 and self.reuse_rule != "paper":
            raise TopodrakeError(f"{where}: reuse_slack applies to reuse_rule 'paper' only")
        for name, low in (("sequence_window", 0), ("retrieval_k", 1), ("sparsify_window", 1),
                          ("retrieval_first", 0), ("link_k", 1), ("link_hops", 0),
                          ("reuse_ahead", 0)):
            v = getattr(self, name)
            if not isinstance(v, int) or v < low:
                raise TopodrakeError(f"{where}: {name} must be an integer >= {low}, got {v}")
        return self


@dataclass
class Trajectory:
    """A drive added to the map: its name, length and chain of vertices."""

    name: str
    frames: int
    chain: list[int] = field(default_factory=list)


class TopoMap:
    """Vertices, edges, the kept frames and the retrieval index of one map."""

    def __init__(self, scorer, embedding, config: MapConfig | None = None, world: str = "",
                 identity: dict | None = None):
        self.scorer = scorer
        self.embedding = embedding
        self.config = (config or MapConfig()).validate()
        self.world = world
        self.identity = identity if identity is not None else dict(scorer.identity)
        self.graph = nx.DiGraph()
        self.bank = FrameBank(scorer)
        self.index = VertexIndex(embedding)
        self.trajectories: list[Trajectory] = []
        self.raw_frames = 0

    # -- shape ------------------------------------------------------------------
    @property
    def modality(self) -> str:
        return self.scorer.observation

    @property
    def k(self) -> int:
        return self.scorer.k

    @property
    def frame_step(self) -> int:
        return self.scorer.frame_step

    def __len__(self) -> int:
        return self.graph.number_of_nodes()

    @property
    def n_edges(self) -> int:
        return self.graph.number_of_edges()

    def edge_counts(self) -> dict:
        out = dict.fromkeys(EDGE_KINDS, 0)
        for _, _, kind in self.graph.edges(data="kind"):
            out[kind] += 1
        return out

    # -- vertices -----------------------------------------------------------------
    def add_vertex(self, traj: int, frame: int, pos: int, center: int, context: np.ndarray) -> int:
        v = self.graph.number_of_nodes()
        while v in self.graph:
            v += 1
        self.graph.add_node(v, traj=int(traj), frame=int(frame), pos=int(pos), center=int(center),
                            context=np.asarray(context, np.int64))
        return v

    def centers(self, vertices) -> np.ndarray:
        return np.array([self.graph.nodes[v]["center"] for v in vertices], np.int64)

    def contexts(self, vertices) -> np.ndarray:
        rows = [self.graph.nodes[v]["context"] for v in vertices]
        return np.array(rows, np.int64).reshape(len(rows), 2 * self.k + 1)

    def pose(self, vertices) -> np.ndarray:
        """Where the anchors were taken (metadata; NaN when unknown)."""
        return self.bank.poses[self.centers(vertices)]

    def origin_chain(self, v: int) -> tuple[list[int], int]:
        """The chain of the drive that created vertex ``v``, and its position there."""
        node = self.graph.nodes[v]
        return self.trajectories[node["traj"]].chain, node["pos"]

    # -- edges --------------------------------------------------------------------
    def add_edge(self, u: int, v: int, p: float, kind: str, leg: np.ndarray | None = None,
                 leg_path: np.ndarray | None = None) -> None:
        """Add u -> v; an existing edge keeps the larger probability and its
        leg, and a trajectory edge is never demoted to a cross edge.
        ``leg`` (3,) and ``leg_path`` (LEG_POINTS, 3): v's pose in u's frame
        and the path there (the drive's odometry over a trajectory edge; the
        scans' registration over a join)."""
        if kind not in EDGE_KINDS:
            raise ValueError(f"edge kind must be one of {EDGE_KINDS}")
        if u == v:
            return
        p = float(min(max(p, 1e-12), 1.0))
        old = self.graph.get_edge_data(u, v)
        extra = {}
        if leg is not None and np.all(np.isfinite(leg)):
            extra = {"leg": np.asarray(leg, np.float64).reshape(3),
                     "leg_path": np.asarray(leg_path, np.float64).reshape(LEG_POINTS, 3)}
        if old is not None:
            p = max(p, old["p"])
            if old["kind"] == "trajectory":
                kind = "trajectory"
            if "leg" in old:
                extra = {"leg": old["leg"], "leg_path": old["leg_path"]}
        self.graph.add_edge(u, v, p=p, weight=-math.log(p), kind=kind, **extra)

    def legs(self, vertices) -> tuple[np.ndarray, np.ndarray]:
        """The drives' odometry between consecutive ``vertices`` of a path:
        legs (n - 1, 3) and leg paths (n - 1, LEG_POINTS, 3), NaN where the
        edge carries none (a join or a reuse its scans could not place)."""
        n = max(len(vertices) - 1, 0)
        legs, paths = np.full((n, 3), np.nan), np.full((n, LEG_POINTS, 3), np.nan)
        for i, (u, v) in enumerate(zip(vertices[:-1], vertices[1:])):
            d = self.graph.get_edge_data(u, v) or {}
            if "leg" in d:
                legs[i], paths[i] = d["leg"], d["leg_path"]
        return legs, paths

    def set_edge_probability(self, u: int, v: int, p: float) -> None:
        p = float(min(max(p, 1e-12), 1.0))
        self.graph.edges[u, v].update(p=p, weight=-math.log(p))

    # -- summary ------------------------------------------------------------------
    def info(self) -> dict:
        n, e = len(self), self.n_edges
        return {"world": self.world, "modality": self.modality, "vertices": n, "edges": e,
                "edge_kinds": self.edge_counts(), "trajectories": len(self.trajectories),
                "raw_frames": self.raw_frames,
                "keep_ratio": round(n / self.raw_frames, 5) if self.raw_frames else 0.0,
                "kept_frames": len(self.bank),
                "checkpoints": {k: v for k, v in self.identity.items()},
                "embedding": self.embedding.name, "config": asdict(self.config)}


def load_map_config(path):
    """A MapConfig from YAML (every key optional), or the defaults for None."""
    from topodrake.typed_yaml import load_typed

    return (load_typed(MapConfig, path, "map config") if path else MapConfig()).validate(
        f"map config {path}" if path else "map config")
