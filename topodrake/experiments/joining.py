"""Do drives that share a place join? Maps of two drives, a -> b and b -> c.

A map built from only the drive a -> b and the drive b -> c must plan
a -> c: the first drive's arrival at b and the second's departure from it
have to become one route (a junction edge, a reused vertex or a cross
edge), and neither the start's nor the goal's links may jump to a place
that only looks alike. :func:`join_trial` builds such a map and plans on
it; :func:`joining_triples` draws the seeded (a, b, c) of a study;
:func:`house_results` runs a house's triples and :func:`joining_study`
every house and map kind of a study's options, with its result document.

A plan's steps are judged in truth (privileged poses, evaluation only).
Every step that is not one of the drives' own hops (a start, goal or
direct link, a cross or junction edge) is a link. A link whose two ends are
not within the controller's reach of each other in truth
(:func:`~topodrake.experiments.link_truth.within_reach`: a short way that
does not wind round walls) joins places that only look alike: a ``false
step``. So does a drive's own hop into or out of a vertex that the drive
reused in a look-alike place: the vertex is not within reach of where the
hop's leg (the drive's odometry) puts it, or, for a hop without a leg, of
the vertex before (kind ``reuse``).
``strict`` figures count every link longer than :data:`JOIN_STEP_M` (2 m)
instead; they also count a start link to an anchor one clear hop along
its drive (3-6 m on a lidar map, whose RE trusts long hops in the open),
which is the planner skipping an anchor, not a look-alike.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass

import numpy as np

from topodrake.errors import TopodrakeError
from topodrake.experiments.link_truth import within_reach
from topodrake.experiments.scenarios import option
from topodrake.montecarlo import trial_seeds
from topodrake.se2 import compose
from topodrake.sensing.observe import camera_scans
from topodrake.topomap.build import BuildStats, add_trajectory
from topodrake.topomap.graph import TopoMap, load_map_config
from topodrake.topomap.plan import plan_path
from topodrake.topomap.retrieval import default_embedding
from topodrake.topomap.sources import (
    demo_drives,
    drive_observations,
    make_scorer,
    place_of,
)
from topodrake.validate import check_count, check_seed
from topodrake.world import load_world

JOIN_STEP_M = 2.0     # a link or edge between drives longer than this in truth is false
#: the map kinds a joining study builds
MODALITIES = ("camera", "lidar", "lidar_reg")


@dataclass
class JoinResult:
    """One triple's map and plan."""

    places: tuple[int, int, int]
    vertices: int
    junctions: int              # junction edges in the map
    planned: bool
    probability: float
    longest_step_m: float       # over every step of the plan (nan: no plan)
    longest_link_m: float       # over the steps that are not a drive's own hop (nan: no plan)
    longest_link_kind: str = ""  # start, goal, direct, cross or junction
    false_link_m: float = 0.0    # the longest false link of the plan (0: none)
    false_link_kind: str = ""
    reason: str = ""

    @property
    def false_step(self) -> bool:
        return self.planned and self.false_link_m > 0.0

    @property
    def strict_false_step(self) -> bool:
        return self.planned and self.longest_link_m > JOIN_STEP_M

    @property
    def joined(self) -> bool:
        """Planned a -> c with no false step."""
        return self.planned and not self.false_step

    def record(self) -> dict:
        out = asdict(self)
        out["places"] = list(self.places)
        out.update(joined=self.joined, false_step=self.false_step,
                   strict_false_step=self.strict_false_step)
        for k in ("probability", "longest_step_m", "longest_link_m", "false_link_m"):
            out[k] = None if not np.isfinite(out[k]) else round(float(out[k]), 4)
        return out


def joining_triples(n_places: int, n: int, seed: int) -> np.ndarray:
    """(n, 3) ordered triples of distinct places (a, b, c); triple i comes
    from its own spawned seed, so a prefix of a longer study is the same
    triples."""
    if n_places < 3:
        raise TopodrakeError(f"joining needs at least 3 places, the world has {n_places}")
    return np.array([np.random.default_rng(s).choice(n_places, 3, replace=False)
                     for s in trial_seeds(seed, n)], np.int64).reshape(n, 3)


def plan_links(world, topomap, result, start_pose, goal_pose) -> dict:
    """The steps of a plan ``result`` from ``start_pose`` to ``goal_pose``
    in truth (in ``world``): ``longest_step_m`` (every step),
    ``longest_link_m`` and ``longest_link_kind`` (steps that are not
    trajectory edges), ``false_link_m`` and ``false_link_kind`` (the longest
    false link, by its straight length; 0 and "" for none)."""
    vs = list(result.vertices)
    poses = topomap.pose(vs).reshape(-1, 3)
    xy = np.vstack([np.asarray(start_pose, np.float64)[None, :2], poses[:, :2],
                    np.asarray(goal_pose, np.float64)[None, :2]])
    steps = np.hypot(*np.diff(xy, axis=0).T)
    edges = [topomap.graph.edges[u, v] for u, v in zip(vs[:-1], vs[1:])]
    kinds = (["start"] + [e["kind"] for e in edges] + ["goal"]) if vs else ["direct"]
    links = [(float(d), kind, i) for i, (d, kind) in enumerate(zip(steps, kinds))
             if kind != "trajectory"]
    false = [(d, kind) for d, kind, i in links if not within_reach(world, xy[i], xy[i + 1])]
    for i, e in enumerate(edges):      # a drive's own hop, through a vertex reused elsewhere
        if e["kind"] != "trajectory":
            continue
        end = compose(poses[i], e["leg"])[0, :2] if "leg" in e else poses[i, :2]
        if not within_reach(world, end, poses[i + 1, :2]):
            false.append((float(np.hypot(*(end - poses[i + 1, :2]))), "reuse"))
    link_m, link_kind, _ = max(links)
    false_m, false_kind = max(false, default=(0.0, ""))
    return {"longest_step_m": float(steps.max()), "longest_link_m": link_m,
            "longest_link_kind": link_kind, "false_link_m": false_m,
            "false_link_kind": false_kind}


def join_trial(world, make_map, drive_of, observe, triple, scan=None) -> JoinResult:
    """Build a map from the drives a -> b and b -> c of ``triple`` and plan
    a -> c from the views at the places.

    ``make_map()`` gives an empty map; ``drive_of(s, g)`` the expert drive
    from place s to place g (its ``poses``) or None; ``observe(poses)``
    what the map's scorer sees there; ``scan(poses)``, for a camera map, the
    lidar scans taken with those views, which the map keeps and checks its
    reuses and links by, as every camera map built by ``topodrake map
    build`` or the planning study does (None: none kept)."""
    a, b, c = (int(x) for x in triple)
    topomap = make_map()
    stats = BuildStats()
    for s, g in ((a, b), (b, c)):
        drive = drive_of(s, g)
        if drive is None:
            return JoinResult((a, b, c), len(topomap), stats.junctions, False, 0.0, np.nan,
                              np.nan, reason=f"no expert drive from place {s} to place {g}")
        add_trajectory(topomap, observe(drive.poses), drive.poses, f"{s}->{g}", stats,
                       scans=None if scan is None else scan(drive.poses))
    places = np.asarray(world.places, np.float64)
    views = observe(places[[a, c]])
    plan = plan_path(topomap, views[0], views[1], start_pose=places[a], goal_pose=places[c],
                     view_scans=None if scan is None else scan(places[[a, c]]))
    if not plan.reachable:
        return JoinResult((a, b, c), len(topomap), stats.junctions, False, 0.0, np.nan, np.nan,
                          reason=plan.reason)
    return JoinResult((a, b, c), len(topomap), stats.junctions, True, plan.probability,
                      **plan_links(world, topomap, plan, places[a], places[c]))


def summarize(results: list[JoinResult]) -> dict:
    """``joined_triples`` (share planned without a false step),
    ``false_steps`` (share of plans holding one), their ``strict_``
    versions, ``planned``, counts."""
    n = len(results)
    planned = [r for r in results if r.planned]

    def share(xs, of):
        return round(sum(xs) / len(of), 4) if of else None

    return {"triples": n,
            "joined_triples": share([r.joined for r in results], results),
            "false_steps": share([r.false_step for r in planned], planned),
            "strict_joined_triples": share([r.planned and not r.strict_false_step
                                            for r in results], results),
            "strict_false_steps": share([r.strict_false_step for r in planned], planned),
            "junction_maps": share([r.junctions > 0 for r in results], results),
            "planned": round(len(planned) / n, 4) if n else None,
            "mean_probability": (round(float(np.mean([r.probability for r in planned])), 4)
                                 if planned else None)}


def _by_poses(sense):
    """``sense(poses)`` remembered per poses: each drive's frames are
    rendered (or scanned) once, however many triples use the drive."""
    seen: dict[bytes, np.ndarray] = {}

    def remembered(poses):
        key = np.asarray(poses, np.float64).tobytes()
        if key not in seen:
            seen[key] = sense(poses)
        return seen[key]
    return remembered


def house_results(spec: str, modality: str, triples, config, progress: bool) -> list:
    """The :class:`JoinResult` of each triple in one house."""
    from tqdm import tqdm


    world = load_world(spec)
    _, drives = demo_drives(spec, None, progress=progress)
    by_places = {}
    for d in drives:
        by_places.setdefault((place_of(world, d.poses[0]), place_of(world, d.poses[-1])), d)
    scorer = make_scorer(modality, world)
    embedding = default_embedding(scorer.observation)
    observe = _by_poses(lambda poses: drive_observations(world, scorer, poses))
    scan = _by_poses(lambda poses: camera_scans(world, scorer.observation, poses))

    def make_map():
        return TopoMap(scorer, embedding, config, world=spec)

    out = []
    for triple in tqdm(triples, desc=f"{spec} {modality}", unit="triple", disable=not progress):
        out.append(join_trial(world, make_map, lambda s, g: by_places.get((s, g)),
                              observe, triple, scan if modality == "camera" else None))
    return out


@dataclass
class JoiningStudy:
    """The map-joining study's settings: its houses, the map kinds
    (:data:`MODALITIES`), ordered place triples per house, their seed, and
    the map settings (a MapConfig YAML; None: the library's defaults)."""
    houses: list[str] = option([f"test-{i}" for i in range(5)], "comma-separated houses (their "
                               "demonstrations are collected once)")
    modalities: list[str] = option(["camera", "lidar"], "comma-separated map kinds of "
                                   + ", ".join(MODALITIES))
    triples: int = option(40, "ordered place triples per house")
    seed: int = option(0, "seed of the triples")
    config: str | None = option(None, "map config YAML (default: the library's defaults)")

    def validate(self) -> "JoiningStudy":
        """Check the numbers (the houses and map kinds are checked as the
        study starts); a bad one raises a one-line TopodrakeError."""
        check_count("map-joining scenario: triples", self.triples)
        check_seed("map-joining scenario: seed", self.seed)
        return self


def joining_study(study: JoiningStudy, command: str, quiet: bool = False) -> dict:
    """The study's result document for ``study``; ``command`` is recorded;
    ``quiet``: no progress bars."""
    houses = [h for h in study.houses if h]
    modalities = [m for m in study.modalities if m]
    bad = [m for m in modalities if m not in MODALITIES]
    if bad or not modalities:
        raise TopodrakeError(f"--modalities takes {', '.join(MODALITIES)}, got "
                             f"{','.join(study.modalities)!r}")
    if not houses:
        raise TopodrakeError("--houses names no house")
    config = load_map_config(study.config)
    worlds = {h: load_world(h) for h in houses}             # unknown houses fail here, first
    t0 = time.perf_counter()
    per_house, records, summary = {}, [], {}
    for modality in modalities:
        every = []
        for h, seed in zip(houses, trial_seeds(study.seed, len(houses))):
            triples = joining_triples(len(worlds[h].places), study.triples, seed)
            results = house_results(h, modality, triples, config, not quiet)
            every += results
            per_house.setdefault(h, {})[modality] = summarize(results)
            records += [{"house": h, "modality": modality, **r.record()} for r in results]
        summary[modality] = summarize(every)
    return {"command": command,
            "seed": study.seed, "triples_per_house": study.triples, "houses": houses,
            "config": config.flat(), "wall_time_s": round(time.perf_counter() - t0, 1),
            "summary": summary, "per_house": per_house, "trials": records}
