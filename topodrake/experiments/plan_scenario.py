"""The planning study's settings as one typed scenario.

:class:`PlanningScenario` holds what a planning run is: its houses (or one
world), methods, trial counts, the maps' settings (``map``: changes to a
:class:`~topodrake.topomap.graph.MapConfig`), the cars' follower
(``follower``: changes to a :class:`~topodrake.navigation.follower.FollowerConfig`),
their odometry, the replanning schedule (a
:class:`~topodrake.navigation.replan.ReplanSchedule`), the time rule, the pruned maps, the
experience rounds, the changed world every method also drives in
(``changes``), the seed and where it runs. Named scenarios live in
``studies/scenarios/planning.yaml``; the dataclass's defaults are its
``table2`` (the default run). :meth:`PlanningScenario.resolved` fills in
what depends on the houses (the time rule, the pruned fractions);
:meth:`PlanningScenario.check_worlds` loads the worlds.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

from topodrake.errors import TopodrakeError
from topodrake.experiments.map_cache import house_key
from topodrake.experiments.plan_methods import DEFAULT_METHODS, METHODS
from topodrake.experiments.plan_trials import T_MAX_S
from topodrake.experiments.scenarios import option
from topodrake.navigation.follower import FollowerConfig
from topodrake.navigation.replan import ReplanSchedule
from topodrake.odometry import ODOMETRY_MODELS
from topodrake.topomap.graph import MapConfig
from topodrake.topomap.recalibrate import PRIOR_WEIGHT
from topodrake.typed_yaml import load_typed_data
from topodrake.validate import check_count, check_finite, check_positive, check_seed
from topodrake.world import load_world
from topodrake.world.changes import WorldChanges

#: the test houses of the default run
HOUSES = ["test-0", "test-1", "test-2", "test-3", "test-4"]
#: the pruned maps' fractions of a run of houses (one world runs none)
HOUSE_PRUNED_FRACTIONS = [0.3, 0.6, 1.0]
TIME_RULES = ("auto", "fixed", "route")
#: a value of a nested config's setting in a scenario's mapping of changes
Setting = bool | int | float | str | None


def follower_config(changes: dict) -> FollowerConfig:
    """The follower of a scenario's ``follower`` changes, checked."""
    return FollowerConfig.from_dict(changes)


def map_config(changes: dict) -> MapConfig:
    """The map settings of a scenario's ``map`` changes (MapConfig's flat
    names, as :meth:`MapConfig.from_dict` takes them), checked."""
    return MapConfig.from_dict(dict(changes), "map settings").validate("map settings")


@dataclass
class PlanningScenario:
    """A planning run (the paper's Table II and our ablations); every field
    has the default of the ``table2`` scenario."""

    houses: list[str] = option(HOUSES, "test houses (catalogue names or map YAMLs)")
    world: str | None = option(None, "one world (catalogue name or ROS map YAML) instead of "
                                     "the houses")
    methods: list[str] = option(list(DEFAULT_METHODS), "methods to run, of " + ", ".join(METHODS))
    trials: int = option(100, "trials per method and house (paper: 1000)")
    oracle_trials: int = option(100, "trials per house of the oracle ablations")
    trajectories: int | None = option(None, "drives per map, in order (default: all 90)")
    changes: WorldChanges = option(WorldChanges, "what changed in the world since it was "
                                                 "mapped, on each trial's planned route: boxes, "
                                                 "people, blocked (each method then runs with "
                                                 "and without them)", flag="")
    batch: int = option(32, "cars per navigation-engine batch")
    time_limit: float = option(T_MAX_S, "seconds a trial may drive before it times out")
    time_rule: str = option("auto", "'fixed': every trial gets time_limit; 'route': each trial "
                                    "the longer of time_limit and its A* length at 0.25 m/s; "
                                    "'auto': fixed for houses, route for a world",
                            choices=TIME_RULES)
    paper_plans: bool = option(False, "plan the most probable path as the paper does, not the "
                                      "path most likely to be driven within the time limit")
    pruned_fractions: list[float] | None = option(
        None, "fractions of the drives for the pruned maps, or 'none' (paper: 0.1,0.2,...,1; "
              "default: 0.3,0.6,1 for houses, none for a world)")
    pruned_house: str | None = option(None, "house of the pruned maps (default: the first)")
    pruned_method: str = option("ours", "map of the pruned study",
                                choices=("ours", "lidar", "oracle"))
    pruned_trials: int = option(20, "trials per pruned map (paper: 1000)")
    pruned_seed: int = option(0, "seed of the drive subsets")
    experience_rounds: int = option(1, "rounds of each plainly driven map method's trials, each "
                                       "planned with the drives of the rounds before folded in")
    experience_prior_weight: float = option(PRIOR_WEIGHT, "drives RE's rating of an edge counts "
                                                          "for when earlier drives are folded in")
    map: dict[str, Setting] = option({}, "map settings to change (MapConfig fields) for the "
                                         "maps built from the drives; maps of other settings "
                                         "are cached under names of their own", flag="")
    follower: dict[str, Setting] = option({}, "follower settings to change (FollowerConfig "
                                              "fields, as FollowerConfig.from_dict takes them)",
                                          flag="")
    odometry: str = option("wheel", "what the cars' odometry reads: wheel odometry that drifts "
                                    "(each trial's errors from its seed) or the true pose",
                           choices=ODOMETRY_MODELS)
    replan: ReplanSchedule = option(ReplanSchedule, "replanning schedule of the *_replan "
                                                    "methods", flag="")
    seed: int = option(0, "base seed of the trials")
    data: str = option("data", "cache of demonstrations and maps")
    workers: int = option(1, "local worker processes, one house each")
    ray: str | None = option(None, "run the houses on a Ray cluster at this address")

    def validate(self, where: str = "planning scenario") -> "PlanningScenario":
        """Check every field (no file is read); a bad one raises a one-line
        TopodrakeError naming it."""
        unknown = [m for m in self.methods if m not in METHODS]
        if unknown or not self.methods:
            raise TopodrakeError(f"unknown methods {unknown}; choose from {', '.join(METHODS)}")
        for name in ("trials", "oracle_trials", "batch", "pruned_trials", "experience_rounds",
                     "workers"):
            check_count(f"{where}: {name}", getattr(self, name))
        if self.trajectories is not None:
            check_count(f"{where}: trajectories", self.trajectories)
        self.changes.check(f"{where}: changes")
        check_positive(f"{where}: time_limit", self.time_limit)
        w = check_finite(f"{where}: experience_prior_weight", self.experience_prior_weight)
        if not w > 0:
            raise TopodrakeError(f"{where}: experience_prior_weight must be > 0, got {w:g}")
        for name, value, allowed in (("time_rule", self.time_rule, TIME_RULES),
                                     ("pruned_method", self.pruned_method,
                                      ("ours", "lidar", "oracle")),
                                     ("odometry", self.odometry, ODOMETRY_MODELS)):
            if value not in allowed:
                raise TopodrakeError(f"{where}: {name} must be one of {', '.join(allowed)}, "
                                     f"got {value!r}")
        if any(not 0.0 < f <= 1.0 for f in self.pruned_fractions or []):
            raise TopodrakeError(f"{where}: pruned_fractions must be numbers in (0, 1], got "
                                 f"{self.pruned_fractions}")
        for name in ("seed", "pruned_seed"):
            check_seed(f"{where}: {name}", getattr(self, name))
        if not self.specs:
            raise TopodrakeError(f"{where}: houses names no house")
        self.follower_config()
        self.map_config()
        self.replan.check()
        return self

    def follower_config(self) -> FollowerConfig:
        """The cars' follower: the defaults changed by ``follower``, checked."""
        return follower_config(self.follower)

    def map_config(self) -> MapConfig:
        """The maps' settings: the defaults changed by ``map``, checked."""
        return map_config(self.map)

    @property
    def specs(self) -> list[str]:
        """The worlds run: ``world`` where given (it replaces the houses), else the houses."""
        return [self.world] if self.world is not None else [h for h in self.houses if h]

    def resolved(self) -> "PlanningScenario":
        """Checked, with what defaults by the houses filled in: the houses
        (one world's alone), the time rule ('route' for one world, 'fixed'
        for houses), the pruned fractions (sorted; none for one world) and
        the pruned house (the first)."""
        self.validate()
        one_world = self.world is not None
        rule = self.time_rule if self.time_rule != "auto" else "route" if one_world else "fixed"
        fractions = self.pruned_fractions
        if fractions is None:
            fractions = [] if one_world else HOUSE_PRUNED_FRACTIONS
        return replace(self, houses=[] if one_world else list(self.specs), time_rule=rule,
                       pruned_fractions=sorted(set(map(float, fractions))),
                       pruned_house=self.pruned_house or (self.specs[0] if fractions else None))

    @property
    def route_time(self) -> bool:
        """Whether each trial gets at least its A* length's time (:meth:`resolved` rule)."""
        return self.time_rule == "route" or (self.time_rule == "auto" and self.world is not None)

    def check_worlds(self) -> list[str]:
        """The worlds' house keys, each world loaded (a bad name or file fails
        here, in one line) and holding at least two places."""
        for spec in self.specs:
            w = load_world(spec)
            if len(w.places) < 2:
                raise TopodrakeError(f"world {spec!r} has {len(w.places)} places; planning "
                                     f"trials need at least 2")
        keys = [house_key(s) for s in self.specs]
        if len(set(keys)) != len(keys):
            raise TopodrakeError("houses names a house twice")
        if self.pruned_fractions and self.pruned_house:
            load_world(self.pruned_house)
        return keys

    @classmethod
    def from_record(cls, doc: dict) -> "PlanningScenario":
        """The scenario a planning.json was run with: its ``scenario``, or,
        for a file written before scenarios, its ``config`` (whose settings
        had other names; settings it lacks read as they ran then: the true
        pose for odometry, the paper's most probable paths; its follower and
        replanning schedule, recorded as changes under older fields, read as
        the defaults)."""
        import yaml


        if "scenario" in doc:
            recorded = dict(doc["scenario"])
            if "trials" in (recorded.get("changes") or {}):     # the boxes of ours_obstacles
                recorded["changes"] = {}
            return load_typed_data(cls, yaml.safe_dump(recorded), "recorded scenario")
        c = doc.get("config", {})
        names = {f for f in cls.__dataclass_fields__}
        kept = {k: v for k, v in c.items()
                if k in names and k not in ("map", "follower", "replan", "houses", "odometry")}
        sc = cls(**kept, odometry=c.get("odometry", "perfect"),
                 paper_plans=not c.get("plan_within_time", False),
                 time_limit=float(c.get("t_max_s") or T_MAX_S),
                 time_rule="route" if c.get("route_time", False) else "fixed")
        sc.houses = list(c.get("houses", HOUSES))
        defaults = MapConfig().flat()
        recorded = MapConfig.from_dict(c.get("map_config", {}), "recorded map config",
                                       stored=True).flat()
        sc.map = {k: v for k, v in recorded.items() if defaults[k] != v}
        return sc
