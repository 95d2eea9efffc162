"""The planning study's methods: what each builds its map with and follows its plans with.

A :class:`Method` names a map kind (the RE a map is built with, the
geometric oracle, or SPTM's graph), the networks its plans are followed
with (:func:`networks`), whether it is one of the fast oracle ablations
(run with ``--oracle-trials`` trials), and how its plans are driven: plainly
or replanning in dead reckoning (every method also drives in a changed
world when a scenario's ``changes`` say so). :data:`METHODS`
holds them in the order the study runs and reports them. Here too is each
method's shipped plan calibration (:func:`plan_calibration_of`) and the
calibration table of a study's records (:func:`calibration_table`).
"""

from __future__ import annotations

from dataclasses import dataclass

from topodrake.errors import TopodrakeError
from topodrake.topomap.plan_calibration import calibration
from topodrake.topomap.plan_calibration import FILENAME, PlanCalibration
from topodrake.topomap.sources import (
    ROOT,
    SHIPPED,
    load_networks,
    shipped_checkpoint,
    shipped_controller,
)

#: what a method's map is built with: the learned RE of a map kind of
#: :mod:`topodrake.topomap.sources`, the geometric ``"oracle"``, or SPTM's graph
MAP_KINDS = ("camera", "lidar", "lidar_reg", "oracle", "sptm")
#: follower's networks -> how the JSON config describes them ("camera", "lidar",
#: "lidar_reg": the shipped k=5 follower; "oracle": A* C_WP + geometric RE;
#: "oracle_cwp": A* C_WP + the learned camera RE)
FOLLOWERS = {"camera": "camera k5 C_WP + learned camera k5 RE",
             "lidar": "lidar k5 C_WP + learned lidar k5 RE",
             "lidar_scale": "lidar k5 C_WP trained at scale + learned lidar k5 RE",
             "camera_scale": "camera k5 C_WP trained at scale + learned camera k5 RE",
             "lidar_reg": "registration C_WP (lidar teach and repeat) + its learned RE",
             "oracle": "A* oracle C_WP + geometric oracle RE",
             "oracle_cwp": "A* oracle C_WP + learned camera k5 RE",
             "lidar_scale_oracle_re": "lidar k5 C_WP trained at scale + geometric oracle RE",
             "lidar_reg_oracle_re": "registration C_WP (lidar teach and repeat) + geometric "
                                    "oracle RE",
             "oracle_cwp_lidar": "A* oracle C_WP + learned lidar k5 RE"}
#: how a method's plans are driven: followed, or followed with replanning in
#: dead reckoning
DRIVES = ("plain", "replan")


@dataclass(frozen=True)
class Method:
    """One planning method: its map kind (:data:`MAP_KINDS`), its follower's
    networks (a key of :data:`FOLLOWERS`), whether it is an oracle ablation
    (run with ``--oracle-trials`` trials), how its plans are driven
    (:data:`DRIVES`), its follower as the JSON config describes it
    (default: :data:`FOLLOWERS`' line) and what it measures."""

    name: str
    map: str
    follower: str
    oracle: bool = False
    drive: str = "plain"
    followed_by: str = ""
    description: str = ""            # what the method is and what it measures (docs/studies.md)

    def __post_init__(self):
        if self.map not in MAP_KINDS:
            raise ValueError(f"method {self.name}: map kind {self.map!r} is not one of {MAP_KINDS}")
        if self.follower not in FOLLOWERS:
            raise ValueError(f"method {self.name}: follower {self.follower!r} is not one of "
                             f"{tuple(FOLLOWERS)}")
        if self.drive not in DRIVES:
            raise ValueError(f"method {self.name}: drive {self.drive!r} is not one of {DRIVES}")
        if not self.followed_by:
            object.__setattr__(self, "followed_by", FOLLOWERS[self.follower])

    @property
    def renders_routes(self) -> bool:
        """Whether its plans, made on a pose map, are rendered as camera
        images for a follower whose learned RE reads them."""
        return self.map == "oracle" and self.follower in ("camera", "oracle_cwp")


METHODS: dict[str, Method] = {m.name: m for m in (
    Method("ours", map="camera", follower="camera",
           description="the paper's system: the camera k=5 map built with the learned RE, "
                       "followed by the camera k=5 C_WP and RE"),
    Method("lidar", map="lidar", follower="lidar",
           description="the same with the lidar k=5 networks"),
    Method("lidar_reg", map="lidar_reg", follower="lidar_reg",
           description="lidar teach and repeat: the map built with the RE of the registration "
                       "C_WP (no network), followed by that controller and its RE"),
    Method("sptm", map="sptm", follower="camera",
           description="the SPTM baseline: every 20th frame, retrieval shortcuts, top-1 "
                       "localization, the path of fewest hops; followed by the camera k=5 "
                       "C_WP and RE"),
    Method("oracle", map="oracle", follower="camera",
           description="our map built with the geometric oracle RE (perception errors out of "
                       "the map), followed by the learned camera networks"),
    Method("ours_replan", map="camera", follower="camera", drive="replan",
           description="ours with replanning: a car in Dead reckoning plans again from where "
                       "it stands, without the edge it fails on (the scenario's replan)"),
    Method("oracle_full", map="oracle", follower="oracle", oracle=True,
           description="perfect perception, the design's ceiling: the oracle map followed by "
                       "the A* oracle C_WP and the geometric oracle RE"),
    Method("ours_oracle_follow", map="camera", follower="oracle", oracle=True,
           description="our camera map followed by the two oracles: the map's share of the "
                       "errors"),
    Method("oracle_cwp", map="oracle", follower="oracle_cwp", oracle=True,
           description="the oracle map followed by the A* oracle C_WP and the learned camera "
                       "RE: RE's share of the follower's errors"),
    Method("lidar_scale", map="lidar", follower="lidar_scale",
           description="the lidar map followed by the lidar C_WP trained at scale and the "
                       "lidar k=5 RE"),
    Method("ours_scale", map="camera", follower="camera_scale",
           description="our camera map followed by the camera C_WP trained at scale and the "
                       "camera k=5 RE"),
    Method("lidar_oracle_follow", map="lidar", follower="oracle", oracle=True,
           description="the lidar map followed by the two oracles: the lidar map's share"),
    Method("lidar_scale_oracle_re", map="lidar", follower="lidar_scale_oracle_re",
           description="the lidar map followed by lidar_scale's C_WP and the geometric oracle "
                       "RE: the follower's RE's share"),
    Method("lidar_oracle_cwp", map="lidar", follower="oracle_cwp_lidar",
           description="the lidar map followed by the A* oracle C_WP and the learned lidar RE: "
                       "the follower's C_WP's share"),
    Method("lidar_replan", map="lidar", follower="lidar", drive="replan",
           description="lidar with replanning"),
    Method("lidar_reg_replan", map="lidar_reg", follower="lidar_reg", drive="replan",
           description="lidar_reg with replanning"),
    Method("oracle_full_replan", map="oracle", follower="oracle", oracle=True, drive="replan",
           description="oracle_full with replanning"),
    Method("lidar_reg_oracle_follow", map="lidar_reg", follower="oracle", oracle=True,
           description="lidar_reg's map followed by the two oracles: the map's share"),
    Method("lidar_reg_oracle_re", map="lidar_reg", follower="lidar_reg_oracle_re",
           description="lidar_reg's map followed by the registration C_WP and the geometric "
                       "oracle RE: its RE's share"),
)}
#: the perfect-perception ablations (fast: they run ``--oracle-trials`` trials)
ORACLE_METHODS = tuple(name for name, m in METHODS.items() if m.oracle)
#: the planning study's default run: the paper's Table II (ours, lidar, SPTM), the
#: lidar system with its C_WP trained at scale, the registration controller, the
#: ceiling and replanning; the other ablations run when named
DEFAULT_METHODS = ("ours", "lidar", "lidar_scale", "lidar_reg", "sptm", "oracle_full",
                   "ours_replan", "lidar_replan")

_NETWORKS: dict = {}
#: followers with a C_WP trained at scale: (its checkpoint folder, the map
#: kind whose RE rates the hops it drives)
SCALE_FOLLOWERS = {"lidar_scale": ("lidar_k5_scale", "lidar"),
                   "camera_scale": ("camera_k5_scale", "camera")}


def networks(modality: str, world=None):
    """(C_WP, RE) of the shipped k=5 follower of ``modality`` (``lidar_reg``:
    the registration C_WP and its follower RE, :data:`FOLLOWER_REACH`; loaded
    once), or of the oracles in
    ``world`` (``"oracle"``: A* C_WP and geometric RE; ``"oracle_cwp"``: A*
    C_WP and the learned camera RE; ``"oracle_cwp_lidar"``: A* C_WP and the
    learned lidar RE; ``"lidar_scale_oracle_re"``: the C_WP at scale and the
    geometric RE; ``"lidar_reg_oracle_re"``: the registration C_WP and the
    geometric RE; a key of :data:`SCALE_FOLLOWERS`: that C_WP at scale and
    its map kind's learned RE)."""
    if modality in ("oracle", "oracle_cwp", "oracle_cwp_lidar"):
        from topodrake.learning.waypoint.policy import AStarOracle
        from topodrake.navigation.evaluate import GeometricReachability

        cwp = AStarOracle(world, k=5)
        learned_re = {"oracle_cwp": "camera", "oracle_cwp_lidar": "lidar"}
        return cwp, (networks(learned_re[modality])[1] if modality in learned_re
                     else GeometricReachability(world, k=5))
    if modality in ("lidar_scale_oracle_re", "lidar_reg_oracle_re"):
        from topodrake.navigation.evaluate import GeometricReachability

        return networks(modality[:-len("_oracle_re")])[0], GeometricReachability(world, k=5)
    if modality in SCALE_FOLLOWERS and modality not in _NETWORKS:
        # the C_WP at scale drives the map's hops, rated by the RE the map was built with
        from topodrake.learning.reachability.controllers import controller_policy
        from topodrake.learning.reachability.estimator import Reachability

        cwp, kind = SCALE_FOLLOWERS[modality]
        _NETWORKS[modality] = (controller_policy(shipped_checkpoint(cwp)),
                               Reachability.from_checkpoint(shipped_checkpoint(SHIPPED[kind][0]),
                                                            shipped_checkpoint(SHIPPED[kind][1])))
    if modality not in _NETWORKS:
        reach = FOLLOWER_REACH.get(modality, SHIPPED[modality][0])
        _NETWORKS[modality] = load_networks(shipped_controller(modality),
                                            shipped_checkpoint(reach))
    return _NETWORKS[modality]


#: map kinds whose follower asks another RE than the one their maps were built
#: with: the registration C_WP's follower asks the RE on labels that start it
#: tracking its target, as the follower's tracker does
FOLLOWER_REACH = {"lidar_reg": "reach_lidar_reg_tracked"}


#: methods whose follower is not their map kind's own: their plan calibration
#: ships beside the follower's C_WP (the map's RE is another follower's)
CALIBRATED_BESIDE_CWP = {"lidar_scale": SCALE_FOLLOWERS["lidar_scale"][0],
                         "ours_scale": SCALE_FOLLOWERS["camera_scale"][0]}


def plan_calibration_path(method: str):
    """Where a method's plan calibration ships: beside its map kind's RE where
    map and follower are one shipped system (``ours``, ``lidar``,
    ``lidar_reg`` and ``ours``' variants), beside the C_WP of
    :data:`CALIBRATED_BESIDE_CWP`'s methods; None for the others."""
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r} (known: {', '.join(METHODS)})")
    if method in CALIBRATED_BESIDE_CWP:
        return ROOT / "checkpoints" / CALIBRATED_BESIDE_CWP[method] / FILENAME
    kind, follower = METHODS[method].map, METHODS[method].follower
    if kind != follower or kind not in SHIPPED:
        return None
    return ROOT / "checkpoints" / SHIPPED[kind][0] / FILENAME


def plan_calibration_of(method: str):
    """The plan calibration shipped for a method (:func:`plan_calibration_path`), or None."""
    path = plan_calibration_path(method)
    return PlanCalibration.load(path) if path is not None and path.is_file() else None


def attach_success_probability(records: list[dict]) -> None:
    """Set each planned record's ``success_probability`` from its method's
    shipped plan calibration (None where the method has none or no plan)."""
    calibs = {m: plan_calibration_of(m) for m in {r["method"] for r in records} if m in METHODS}
    for r in records:
        c = calibs.get(r["method"])
        r["success_probability"] = (
            None if c is None or not r["planned"] or r["plan_probability"] is None else
            round(float(c.predict(r["plan_probability"], r["plan_anchors"])[0]), 5))


def calibration_table(methods: list[str], records: list[dict]) -> dict:
    """Per map method, over its planned trials: the plan probability against
    success (bins and ECE) and, where a calibration ships, its
    ``success_probability`` against success (``ece``; else the raw ECE)."""
    cal = {}
    for m in methods:
        if m in METHODS and METHODS[m].map == "sptm":       # its plans have no probability
            continue
        recs = [r for r in records if r["method"] == m and r["planned"]]
        rows, ece_raw = calibration([r["plan_probability"] for r in recs],
                                    [r["success"] for r in recs])
        row = {"bins_raw": rows, "ece_raw": ece_raw, "planned_trials": len(recs),
               "calibrated": False, "bins": rows, "ece": ece_raw}
        if recs and all(r.get("success_probability") is not None for r in recs):
            bins, ece = calibration([r["success_probability"] for r in recs],
                                    [r["success"] for r in recs])
            row.update(calibrated=True, bins=bins, ece=ece)
        cal[m] = row
    return cal


def calibration_houses(methods: list[str]) -> dict:
    """The houses each method's shipped plan calibration was fitted on."""
    out = {}
    for m in methods:
        c = plan_calibration_of(m) if m in METHODS else None
        if c is not None:
            out[m] = list(c.fitted_on.get("houses", []))
    return out


def check_map_methods(where: str, methods: list[str]) -> None:
    """Refuse, naming ``where``, a list of methods that is empty or holds
    one that is not a map method of the planning study (SPTM has no map)."""
    bad = [m for m in methods if m not in METHODS or METHODS[m].map == "sptm"]
    if bad or not methods:
        raise TopodrakeError(f"{where}: methods must be map methods of the planning study "
                             f"(not sptm), got {','.join(methods)!r}")
