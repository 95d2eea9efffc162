"""Following reference paths: jittered starts and progress along the path.

The trajectory-following study, the follower benchmark and on-policy data
collection follow chains of anchors taken from expert drives; a car starts
near the drive's first pose and is watched against the drive (its reference
path): :class:`PathWatch` keeps the farthest reference sample each car came
within ``TOLERANCE_M`` of (in order) and stops cars that strayed more than
``DIVERGE_M`` from it (the navigation engine's ``watch``).
"""

from __future__ import annotations

import numpy as np

from topodrake.contract.route import route_from_observations
from topodrake.rollout import standard_normal_noise
from topodrake.sensing.observe import camera_scans
from topodrake.vehicle import VehicleConfig, in_collision
from topodrake.world.changes import place_changes

TOLERANCE_M = 0.5      # a reference sample is covered when the robot comes this close
DIVERGE_M = 1.0        # the robot is stopped this far from the reference path
AHEAD = 120            # reference samples (about 6 m) searched ahead of the progress
BEHIND = 40            # the robot may fall back this many samples before it diverges


def path_length(poses: np.ndarray) -> np.ndarray:
    """Cumulative arc length (T,) of a trajectory."""
    return np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(poses[:, :2], axis=0).T))])


def jittered_start(world, pose: np.ndarray, rng) -> np.ndarray:
    """``pose`` moved 0.3 m to a random side and turned 9 deg to a random
    side (the other side, or no jitter, when that puts the car into a wall)."""
    side, turn = rng.choice([-1.0, 1.0], size=2)
    for sd, tn in ((side, turn), (-side, turn), (0.0, 0.0)):
        s = pose.copy()
        s[0] -= 0.3 * sd * np.sin(pose[2])
        s[1] += 0.3 * sd * np.cos(pose[2])
        s[2] += np.radians(9.0) * tn
        if not in_collision(np.array([[*s, 0.0, 0.0]]), world.grid.clearance_at, VehicleConfig())[0]:
            return s
    return pose.copy()


class PathWatch:
    """Progress along each car's reference path (the farthest sample, in
    order, it came within ``TOLERANCE_M`` of); stops cars that strayed more
    than ``DIVERGE_M`` from it (the engine's ``watch``)."""
    def __init__(self, references: list[np.ndarray]):
        self.refs = references
        self.progress = np.zeros(len(references), np.int64)

    def __call__(self, k: int, cars: np.ndarray, states: np.ndarray) -> np.ndarray:
        stop = np.zeros(len(cars), bool)
        for m, c in enumerate(cars):
            ref = self.refs[c]
            p = self.progress[c]
            lo = max(p - BEHIND, 0)
            d = np.hypot(*(ref[lo:, :2] - states[m, :2]).T)         # the path from just behind on
            ahead = np.flatnonzero(d[p - lo:p - lo + AHEAD] < TOLERANCE_M)
            if ahead.size:
                self.progress[c] = p + ahead.max()
            stop[m] = d.min() > DIVERGE_M
        return stop

    def cover(self, c: int) -> float:
        s = path_length(self.refs[c])
        return float(s[self.progress[c]] / s[-1]) if s[-1] > 0 else 1.0


def follow_chains_once(engine, references: list[np.ndarray], observations: list, chains: list,
                       k: int, frame_step: int, seeds, *, noisy: bool = False, record=None,
                       changes=None):
    """Follow ``chains[m]`` (anchor frames) of ``references[m]`` (poses of
    an expert drive in ``engine.world``, whose frames' observations for the
    route's anchors are ``observations[m]``; poses for a pose oracle) with
    ``engine``, each car from a :func:`jittered_start` drawn from
    ``seeds[m]``, for at most 2 x frames + 100 periods, with actuation noise
    from ``seeds[m] + 1`` when ``noisy``; cars stop where they stray more
    than ``DIVERGE_M`` from their drive. Under the engine's odometry model the
    routes' legs come from the drive's own drifting odometry (seeds[m] + 2)
    and each car's from seeds[m] + 3. ``record(k, cars, states)``, if
    given, sees every car's state after each period. ``changes``: a
    :class:`~topodrake.world.changes.WorldChanges` placed on each drive
    (seeds[m] + 4) that the cars meet and the routes never saw. Returns the
    engine's :class:`~topodrake.navigation.engine.NavigationResult`, the
    :class:`PathWatch` (its ``cover(m)``) and, with ``changes``, what was
    placed per car (None where the drive had no room for it)."""
    modality = engine.kind         # a pose oracle beside a sensor network reads the anchors' poses
    # the legs as the teach drive's odometry measured them (seed + 2), the repeat's own
    # odometry errors from seed + 3
    odometry = engine.config.odometry
    # a camera route keeps its anchors' lidar scans, as the teach drive's lidar took them
    lidar = engine.config.rollout.lidar
    routes = [route_from_observations(
        obs, ref, chain, k, frame_step, modality, odometry, int(s) + 2,
        scans=camera_scans(engine.world, modality, np.asarray(ref)[np.asarray(chain), :3], lidar))
        for obs, ref, chain, s in zip(observations, references, chains, seeds)]
    starts = np.array([jittered_start(engine.world, ref[0], np.random.default_rng(s))
                       for ref, s in zip(references, seeds)])
    limits = np.array([(2 * len(ref) + 100) * 0.1 for ref in references])
    noise = standard_normal_noise([int(s) + 1 for s in seeds], int(round(limits.max() / 0.1))) \
        if noisy else None
    watch = PathWatch(list(references))

    def watch_and_record(step, cars, states):
        if record is not None:
            record(step, cars, states)
        return watch(step, cars, states)

    placed = car_changes = None
    if changes is not None and changes.any:
        car_changes, placed = place_changes(engine.world, [np.asarray(r)[:, :2] for r in references],
                                            changes, [int(s) + 4 for s in seeds], starts)
    res = engine.run(starts, routes, noise=noise, t_max_s=limits, watch=watch_and_record,
                     odometry_seeds=[int(s) + 3 for s in seeds], changes=car_changes)
    return (res, watch) if changes is None else (res, watch, placed)
