"""The trajectory-following study's settings as one typed scenario.

:class:`FollowingScenario` holds what a trajectory-following run is: the
test drives (how many, in which houses, their seed), the p values of the RE
chains and the headline p, the controllers with their C_WP and RE
replacements, which runs to make, the sensitivity sweep, the follower's
settings (``follower``, changes to a
:class:`~topodrake.navigation.follower.FollowerConfig`), the odometry, the
actuation noise and the engine's batch. Named scenarios live in
``studies/scenarios/trajectory_following.yaml``; the dataclass's defaults
are its ``default`` scenario.
"""

from __future__ import annotations

from dataclasses import dataclass

from topodrake.errors import TopodrakeError
from topodrake.experiments.follow_trials import CONTROLLERS
from topodrake.experiments.plan_scenario import HOUSES, Setting, follower_config
from topodrake.experiments.scenarios import option
from topodrake.odometry import odometry_model
from topodrake.validate import (
    check_count,
    check_fraction,
    check_nonnegative,
    check_seed,
)
from topodrake.world.changes import WorldChanges

#: the kinds of run a controller's chains can be followed in
RUNS = ("re", "subsampled", "noisy", "oracle", "oracle_re")


@dataclass
class FollowingScenario:
    """A trajectory-following run (the paper's cover-rate figure)."""

    trajectories: int = option(8, "test trajectories (paper: 500)")
    worlds: list[str] = option(HOUSES, "test houses")
    p: list[float] = option([0.9, 0.95, 0.98, 0.99, 0.995], "p_sparsify values")
    headline_p: float = option(0.99, "p_sparsify of the printed summary and of the noisy runs")
    controllers: list[str] = option(list(CONTROLLERS), "controllers to follow with")
    cwp: dict[str, str] = option({}, "NAME: another C_WP checkpoint to follow NAME's chains with "
                                     "(NAME's RE stays), or oracle:KEY=VALUE[:...], the A* "
                                     "oracle with a controlled error", flag="")
    re: dict[str, str] = option({}, "NAME: another RE checkpoint, trained for NAME's C_WP (the "
                                    "cwp one if given): its chains and its answers", flag="")
    chain_re: dict[str, str] = option({}, "NAME: the RE checkpoint that places NAME's anchors "
                                          "while NAME's RE answers the follower", flag="")
    sensitivity: str | None = option(None, "KEY=V1,V2,...: also follow each controller's RE "
                                           "chains at the headline p with the oracle C_WP with "
                                           "KEY set to each value")
    runs: list[str] = option(["re", "subsampled", "noisy", "oracle"],
                             "runs to make, of " + ", ".join(RUNS) + " (noisy, oracle and "
                             "oracle_re at the headline p only); figures of runs left out are "
                             "null")
    changes: WorldChanges = option(WorldChanges, "what the cars meet on their drives that the "
                                                 "routes never saw (boxes, people, blocked): "
                                                 "runs 'changed' (and 'changed_oracle' beside "
                                                 "'oracle') at the headline p", flag="")
    follower: dict[str, Setting] = option({}, "follower settings to change (FollowerConfig "
                                              "fields)", flag="")
    odometry: str = option("wheel", "the cars' and the drives' odometry: the true pose, or "
                                    "wheel odometry that drifts", choices=("perfect", "wheel"))
    slack: float = option(0.0, "sparsify slack where RE passes not even the next frame above p "
                               "(0: the paper's rule)")
    noise: float = option(0.33, "actuation noise std of the noisy runs")
    batch: int = option(48, "cars per engine batch")
    seed: int = option(0, "seed of the trajectories, starts and noise")
    data: str = option("data", "cache of the test trajectories")

    def validate(self, where: str = "trajectory-following scenario") -> "FollowingScenario":
        """Check every field (no file is read); a bad one raises a one-line
        TopodrakeError naming it."""
        check_count(f"{where}: trajectories", self.trajectories)
        check_count(f"{where}: batch", self.batch)
        check_seed(f"{where}: seed", self.seed)
        check_nonnegative(f"{where}: noise", self.noise)
        check_fraction(f"{where}: slack", self.slack)
        self.changes.check(f"{where}: changes")
        if not self.p or any(not 0 < p < 1 for p in self.p):
            raise TopodrakeError(f"{where}: p values must be in (0, 1), got {self.p}")
        if not 0 < self.headline_p < 1:
            raise TopodrakeError(f"{where}: headline_p must be in (0, 1), got {self.headline_p}")
        if not self.runs or set(self.runs) - set(RUNS):
            raise TopodrakeError(f"{where}: runs (--runs) takes {', '.join(RUNS)}, got "
                                 f"{','.join(self.runs) or 'none'}")
        if self.odometry not in ("perfect", "wheel"):
            raise TopodrakeError(f"{where}: odometry must be perfect or wheel, got "
                                 f"{self.odometry!r}")
        self.follower_config()
        return self

    def follower_config(self):
        """The cars' follower: the defaults changed by ``follower``, checked."""
        return follower_config(self.follower)

    def odometry_config(self):
        """The cars' and the drives' odometry model."""
        return odometry_model(self.odometry)
