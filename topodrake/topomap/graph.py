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
``kind``: ``"trajectory"`` (consecutive anchors of one drive), ``"cross"``
(found between drives) or ``"junction"`` (a drive's arrival to another's
departure at the place where both end). An edge may carry a leg: v's pose
in u's frame (``leg``, (3,)) and ``LEG_POINTS`` poses along the hop
(``leg_path``), a relative transform, never an absolute pose: the drive's
odometry over a trajectory edge, the registration of the two vertices'
scans over a join or a reused vertex's hops (where the fit pins it). A
planned route hands the legs to the follower.

:class:`MapConfig` holds the settings, grouped by the step that reads
them; docs/map.md says what each does and why it has its value.
"""

from __future__ import annotations

import math
import typing
from dataclasses import dataclass, field, fields

import networkx as nx
import numpy as np

from topodrake.contract.route import LEG_POINTS
from topodrake.errors import TopodrakeError
from topodrake.topomap.bank import FrameBank
from topodrake.topomap.retrieval import VertexIndex
from topodrake.typed_yaml import first_line, load_typed_data

EDGE_KINDS = ("trajectory", "cross", "junction")

REUSE_RULES = ("paper", "resume")
TEACH_ODOMETRY = ("wheel", "perfect", "none")


@dataclass
class SparsifyConfig:
    """Where a drive's anchors fall (read as each drive is added)."""

    p: float = 0.99            # an anchor's hop ends at the last frame RE passes above this
    slack: float = 0.01        # where RE passes not even the next frame: the last frame within
                               # this of the next frame's RE (0: the paper's rule)
    window: int = 4            # frames in the first window of the greedy scan
    max_hop_m: float = 2.5     # lidar maps: no hop longer than this along the drive's
                               # odometry, metres (0: no cap)


@dataclass
class ReuseConfig:
    """When an existing vertex stands in for a new drive's anchor."""

    enabled: bool = True
    rule: str = "resume"       # "resume": v stands in for an anchor frame and the scan resumes
                               # from v; "paper": v replaces an anchor after sparsifying
    p: float = 0.99            # RE into v and out of v must both pass this
    legs: bool = True          # maps that place joins by scans: v's hops keep the drive's
                               # odometry, v placed by registering its scan
    pinned: bool = True        # lidar maps: only a v whose scan registration pins the translation
    loop_check_m: float = 1.5  # v must lie where the drive's odometry puts it, from the vertex
                               # reused last, within this, metres (0: off) ...
    loop_check_per_m: float = 0.1  # ... plus this share of the metres measured


@dataclass
class CrossConfig:
    """Cross edges between a new drive's vertices and the map's."""

    p: float = 0.99            # the single pair's RE and the sequence-matched minimum must
                               # pass this
    sequence_window: int = 2   # aligned anchors on each side that sequence matching checks
    sequence_retrieval: bool = True  # rank candidates by the aligned neighbours' embeddings too
    legs: bool = True          # maps that place joins by scans: the edge carries the pose its
                               # scans register to, where the fit pins it


@dataclass
class JunctionConfig:
    """Junction edges: a drive's last vertex -> another drive's first."""

    enabled: bool = True
    p: float = 0.7             # RE must pass this both ways
    scan_match: float = 0.7    # lidar maps: share of each scan's points the registration must
                               # pair (0: no scan check)


@dataclass
class CameraConfig:
    """Camera maps that keep the lidar scans their drives took."""

    scans: bool = True         # check reuse and the plan's links by the scans (``scan_match``)
    legs: bool = True          # place reused vertices and joins by registering the scans


@dataclass
class LinkConfig:
    """A plan's links from the start view and into the goal view."""

    p: float = 0.5             # RE a link must pass
    k: int = 32                # vertices ranked by the embedding that RE checks, per end
    consensus: bool = True     # plan between one group of links per end (one place each)
    hops: int = 3              # links within this many edges (either way) are one group
    direct_check: bool = True  # a direct start-goal link needs both ends' links within ``hops``
    goal_mutual: bool = True   # a goal link's p is min(RE(v, goal), RE(goal, v))
    goal_leg: bool = True      # maps that place joins by scans: the hop into the goal carries the
                               # pose the goal's scan registers to, where the fit pins it
    near_m: float = 2.0        # maps that check links by scans: plans start first from vertices
                               # the start's scan registers onto within this, metres (0: off) ...
    near_deg: float = 60.0     # ... facing the car's way within this, degrees ...
    near_behind_m: float = 0.3  # ... and at most this far behind the car, metres
    cover: float = 0.7         # maps that check links by scans: a link's view must register onto
                               # its vertex's scan pairing this share of both scans' points; an
                               # end with no such link is not covered (0: off; topomap/coverage.py)


@dataclass
class PlanConfig:
    """What Dijkstra counts for a hop beside its -log p."""

    legless_p: float = 0.98    # maps that place joins by scans: a map edge without a leg counts
                               # its p times this
    switch_p: float = 0.9      # a hop between drives (cross or junction edge) counts its p times
                               # this (1: off)


@dataclass
class MapConfig:
    """How a map is built and planned on, grouped by the step that reads it.

    The YAML form (:func:`load_map_config`) nests the groups (``reuse: {p:
    0.9}``); the flat form (:meth:`flat`, :data:`FLAT`) is how map files,
    caches and study records store a config."""

    retrieval_k: int = 64          # building: vertices ranked by the embedding that RE checks
                                   # (reuse and cross-edge candidates)
    scan_match: float = 0.8        # lidar maps (camera maps with ``camera.scans``): share of each
                                   # scan's points a registration must pair to confirm a reuse,
                                   # a junction or a plan's link (0: off)
    teach_odometry: str = "wheel"  # the odometry trajectory edges keep: "wheel" (drifts, seeded
                                   # by the drive's index), "perfect" or "none"
    sparsify: SparsifyConfig = field(default_factory=SparsifyConfig)
    reuse: ReuseConfig = field(default_factory=ReuseConfig)
    cross: CrossConfig = field(default_factory=CrossConfig)
    junction: JunctionConfig = field(default_factory=JunctionConfig)
    camera: CameraConfig = field(default_factory=CameraConfig)
    links: LinkConfig = field(default_factory=LinkConfig)
    plan: PlanConfig = field(default_factory=PlanConfig)

    @classmethod
    def from_dict(cls, settings: dict, where: str = "map config",
                  stored: bool = False) -> "MapConfig":
        """A config from ``settings``, nested (``{"reuse": {"p": 0.9}}``; a
        group may also be its dataclass), flat (``{"p_reuse": 0.9}``, the
        names of :data:`FLAT`) or both; the settings not given keep their
        defaults, and integers given for real numbers become floats. An
        unknown key or a setting given twice raises a TopodrakeError naming
        it, as does a deleted rule's setting other than its :data:`RETIRED`
        value unless ``stored`` (a config a map file holds: it is read as
        the map was built). Not validated (:meth:`validate`)."""
        return _assemble(_places(settings, where, stored))

    def updated(self, **settings) -> "MapConfig":
        """This config with ``settings`` (keys as :meth:`from_dict` takes) changed."""
        return _assemble({**_places(self.flat(), "map config", True),
                          **_places(settings, "map config", False)})

    def flat(self) -> dict:
        """The flat form, as map files, caches and study records store a
        config: every setting under its name in :data:`FLAT`, in that order,
        the deleted rules' at their :data:`RETIRED` values."""
        return {name: RETIRED[name] if place is None else _get(self, place)
                for name, place in FLAT.items()}

    def validate(self, where: str = "map config") -> "MapConfig":
        """This config, checked: each setting's type and range (a one-line
        TopodrakeError naming ``where`` and the setting)."""
        for group, cls in GROUPS.items():
            if not isinstance(getattr(self, group), cls):
                raise TopodrakeError(f"{where}: {group} must be a {cls.__name__}, got "
                                     f"{getattr(self, group)!r}")

        def check(places, ok, what: str) -> None:
            for place in places:
                v = _get(self, place)
                if not ok(v):
                    raise TopodrakeError(f"{where}: {_named(place)} must be {what}, got {v!r}")

        def number(v) -> bool:
            return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)

        check(("sparsify.p", "reuse.p", "cross.p", "links.p", "junction.p"),
              lambda v: number(v) and 0.0 < v < 1.0, "in (0, 1)")
        check(("sparsify.slack", "scan_match", "junction.scan_match", "links.cover"),
              lambda v: number(v) and 0.0 <= v < 1.0, "in [0, 1)")
        for place, choices in (("reuse.rule", REUSE_RULES), ("teach_odometry", TEACH_ODOMETRY)):
            check((place,), lambda v, c=choices: v in c, f"one of {', '.join(choices)}")
        check(("reuse.enabled", "reuse.legs", "reuse.pinned", "cross.sequence_retrieval",
               "cross.legs", "junction.enabled", "camera.scans", "camera.legs",
               "links.consensus", "links.direct_check", "links.goal_mutual", "links.goal_leg"),
              lambda v: isinstance(v, bool), "true or false")
        check(("plan.legless_p", "plan.switch_p"), lambda v: number(v) and 0.0 < v <= 1.0,
              "in (0, 1]")
        check(("sparsify.max_hop_m", "reuse.loop_check_m", "reuse.loop_check_per_m",
               "links.near_m", "links.near_deg", "links.near_behind_m"),
              lambda v: number(v) and v >= 0, "a number >= 0")
        for places, low in ((("cross.sequence_window", "links.hops"), 0),
                            (("retrieval_k", "sparsify.window", "links.k"), 1)):
            check(places, lambda v, low=low: isinstance(v, int) and not isinstance(v, bool)
                  and v >= low, f"an integer >= {low}")
        return self


#: the groups of :class:`MapConfig`
GROUPS = {"sparsify": SparsifyConfig, "reuse": ReuseConfig, "cross": CrossConfig,
          "junction": JunctionConfig, "camera": CameraConfig, "links": LinkConfig,
          "plan": PlanConfig}

#: every setting's flat name (the form map files, caches and study records
#: store, :meth:`MapConfig.flat`, in this order) -> its place in MapConfig
#: ("group.field", or a top-level field; None: a deleted rule's, :data:`RETIRED`)
FLAT = {
    "p_sparsify": "sparsify.p", "sparsify_slack": "sparsify.slack", "p_reuse": "reuse.p",
    "reuse_slack": None, "p_edge": "cross.p", "sequence_window": "cross.sequence_window",
    "join_ends": "junction.enabled", "p_join": "junction.p", "retrieval_k": "retrieval_k",
    "retrieval_first": None, "sequence_retrieval": "cross.sequence_retrieval",
    "p_link": "links.p", "link_k": "links.k", "link_consensus": "links.consensus",
    "link_hops": "links.hops", "link_order": None, "direct_check": "links.direct_check",
    "goal_mutual": "links.goal_mutual", "sparsify_window": "sparsify.window",
    "max_hop_m": "sparsify.max_hop_m", "reuse": "reuse.enabled", "reuse_rule": "reuse.rule",
    "teach_odometry": "teach_odometry", "reuse_ahead": None, "reuse_legs": "reuse.legs",
    "scan_match": "scan_match", "junction_scan_match": "junction.scan_match",
    "scan_match_cross": None, "camera_scans": "camera.scans", "camera_junction_scans": None,
    "camera_legs": "camera.legs", "loop_check_m": "reuse.loop_check_m",
    "loop_check_per_m": "reuse.loop_check_per_m", "reuse_pinned": "reuse.pinned",
    "cross_legs": "cross.legs", "goal_leg": "links.goal_leg", "legless_p": "plan.legless_p",
    "switch_p": "plan.switch_p", "start_near_m": "links.near_m",
    "start_near_deg": "links.near_deg", "start_near_behind_m": "links.near_behind_m",
    "link_cover": "links.cover"}

#: the settings of deleted rules (docs/history.md) at the value every map is
#: now built with; the flat form keeps them, so that stored configs and the
#: map caches' keys read as before
RETIRED = {"reuse_slack": 0.0, "retrieval_first": 0, "link_order": "probability",
           "reuse_ahead": 0, "scan_match_cross": False, "camera_junction_scans": False}

_FLAT_NAME = {place: name for name, place in FLAT.items() if place is not None}


def _get(config: MapConfig, place: str):
    group, _, name = place.rpartition(".")
    return getattr(getattr(config, group) if group else config, name)


def _named(place: str) -> str:
    """A setting's place, with its flat name where that differs."""
    name = _FLAT_NAME.get(place, place)
    return place if name == place else f"{place} ({name})"


def _places(settings, where: str, stored: bool) -> dict:
    """``settings`` (as :meth:`MapConfig.from_dict` takes them) as {place: value}."""
    if not isinstance(settings, dict):
        raise TopodrakeError(f"{where}: expected a mapping of map settings, got "
                             f"{type(settings).__name__}")
    out, by = {}, {}

    def put(place, value, key):
        if place in out:
            raise TopodrakeError(f"{where}: {_named(place)} is given twice ({by[place]}, {key})")
        out[place], by[place] = value, key

    for key, value in settings.items():
        if key in GROUPS and isinstance(value, (dict, GROUPS[key])):
            names = [f.name for f in fields(GROUPS[key])]
            items = value.items() if isinstance(value, dict) else \
                ((n, getattr(value, n)) for n in names)
            for name, v in items:
                if name not in names:
                    raise TopodrakeError(f"{where}: unknown key {name!r} in {key} (it holds "
                                         f"{', '.join(names)})")
                put(f"{key}.{name}", v, f"{key}.{name}")
        elif key in FLAT:
            if FLAT[key] is None:
                if not stored and value != RETIRED[key]:
                    raise TopodrakeError(f"{where}: {key} set a map rule that was deleted "
                                         f"(docs/history.md); only {RETIRED[key]!r} is left")
                continue
            put(FLAT[key], value, key)
        elif key in GROUPS:
            raise TopodrakeError(f"{where}: {key} must be a mapping of its settings, got "
                                 f"{value!r}")
        else:
            raise TopodrakeError(f"{where}: unknown key {key!r} in MapConfig")
    return out


def _assemble(places: dict) -> MapConfig:
    """A MapConfig with the settings at ``places`` ({place: value}), the rest defaults."""
    top, groups = {}, {g: {} for g in GROUPS}
    for place, value in places.items():
        group, _, name = place.rpartition(".")
        cls = GROUPS[group] if group else MapConfig
        if _HINTS[cls][name] is float and isinstance(value, int) and not isinstance(value, bool):
            value = float(value)
        (groups[group] if group else top)[name] = value
    return MapConfig(**top, **{g: GROUPS[g](**groups[g]) for g in GROUPS})


_HINTS = {cls: typing.get_type_hints(cls) for cls in (MapConfig, *GROUPS.values())}


#: settings added after maps were first written whose default builds a map as
#: before: a stored (flat) config without them reads as these values
LATER_DEFAULTS = {"reuse_ahead": 0, "scan_match": 0.0, "scan_match_cross": False,
                  "camera_scans": False, "camera_legs": False, "loop_check_m": 0.0,
                  "loop_check_per_m": 0.1, "reuse_pinned": False, "cross_legs": False,
                  "junction_scan_match": 0.8, "camera_junction_scans": True, "max_hop_m": 0.0}
#: flat settings only a lidar map reads (a map of another modality is built alike whatever they say)
LIDAR_ONLY = ("scan_match_cross", "reuse_pinned", "max_hop_m")
#: flat settings only a camera map reads
CAMERA_ONLY = ("camera_scans", "camera_legs", "camera_junction_scans")
#: flat settings only maps that place joins by lidar scans read (a pose oracle map keeps its
#: drives' scans for the route tracker only)
SCANS_ONLY = ("cross_legs",)
#: flat settings only planning reads, not building (a map is built alike whatever they say)
PLAN_ONLY = ("link_order", "direct_check", "goal_leg", "legless_p", "switch_p", "start_near_m",
             "start_near_deg", "start_near_behind_m", "link_cover")
# (the tuples keep the deleted rules' names: they shape the map caches' keys)


def same_config(stored, config: MapConfig, lidar: bool = True, scans: bool = True) -> bool:
    """Whether a map file's stored (flat) config is ``config`` as far as
    building a map of its kind reads them (:func:`map_settings`; the
    settings it predates read as :data:`LATER_DEFAULTS`)."""
    if not isinstance(stored, dict):
        return False
    return map_settings({**LATER_DEFAULTS, **stored}, lidar, scans) \
        == map_settings(config.flat(), lidar, scans)


def map_settings(config: dict, lidar: bool = True, scans: bool = True) -> dict:
    """The settings of a flat config (:meth:`MapConfig.flat`) that building
    a map of its kind reads: without :data:`PLAN_ONLY`, without
    :data:`LIDAR_ONLY` where it is not a lidar map nor :data:`CAMERA_ONLY`
    where it is one, and without :data:`SCANS_ONLY` where it keeps no scans
    (a pose oracle map)."""
    other = (CAMERA_ONLY if lidar else LIDAR_ONLY) + (() if scans else SCANS_ONLY)
    return {k: v for k, v in config.items() if k not in PLAN_ONLY and k not in other}


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
                "embedding": self.embedding.name, "config": self.config.flat()}


def load_map_config(path) -> MapConfig:
    """A MapConfig from a YAML file, checked, or the defaults for None. The
    file holds the groups nested (``reuse: {p: 0.9}``) or the settings'
    flat names (``p_reuse: 0.9``, :data:`FLAT`), every key optional; an
    unknown key raises a TopodrakeError naming the file and the key."""
    from pathlib import Path

    import yaml


    if not path:
        return MapConfig().validate()
    where = f"map config {path}"
    if not Path(path).is_file():
        raise TopodrakeError(f"map config file {path} does not exist")
    try:
        data = yaml.safe_load(Path(path).read_text())
    except (yaml.YAMLError, UnicodeDecodeError) as e:
        raise TopodrakeError(f"{where}: {first_line(e)}") from None
    places = _places({} if data is None else data, where, False)
    try:
        import pydrake.common.yaml  # noqa: F401  (the typed loader, where pydrake is installed)
    except ImportError:
        return _assemble(places).validate(where)
    nested: dict = {}
    for place, value in places.items():
        group, _, name = place.rpartition(".")
        (nested.setdefault(group, {}) if group else nested)[name] = value
    return load_typed_data(MapConfig, yaml.safe_dump(nested), where).validate(where)
