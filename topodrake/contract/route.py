"""A route: what a follower needs to drive a plan, whoever made it.

The planner (:mod:`topodrake.topomap.plan`) turns a map path into a
:class:`Route`; a single demonstration sparsified into anchors is a route
too (:func:`route_from_trajectory`). The follower reads only the anchors'
observation contexts (and the edge probabilities); the poses ride along as
privileged metadata for plots and evaluation.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from topodrake.contract.frames import context_frames
from topodrake.errors import TopodrakeError
from topodrake.odometry import OdometryConfig, odometry_along
from topodrake.se2 import relative
from topodrake.sensing.observe import camera_scans


@dataclass
class Route:
    """Anchors in driving order.

    ``contexts`` (A, 2k+1, ...): each anchor's target context, past to
    future (camera uint8 images (H, W, 3), lidar ranges (beams,) or, for
    the pose oracle, poses (3,)); ``poses`` (A, 3): where each anchor was
    taken (metadata, never read by the follower); ``vertices``: the map
    vertex of each anchor (-1 when the route does not come from a map);
    ``edge_probability`` (A - 1,): the predicted probability of each hop;
    ``probability``: the whole route's (the product of its hops, and of the
    start and goal links when planned); ``start_probability``: RE of the
    start link that the planner made from the car's observation (1 when
    not planned); ``on_time``: the probability that the follower drives it
    within the time limit it was planned for (1 when planned without one).
    ``scans`` (A, beams): each anchor's lidar scan as the
    teach drive took it, where a camera route keeps one (a lidar route's
    are its contexts' centre frames); the route tracker registers the
    car's scan onto them."""

    contexts: np.ndarray
    poses: np.ndarray
    vertices: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    edge_probability: np.ndarray = field(default_factory=lambda: np.zeros(0))
    probability: float = 1.0
    modality: str = "camera"
    start_probability: float = 1.0
    legs: np.ndarray | None = None
    leg_paths: np.ndarray | None = None
    scans: np.ndarray | None = None
    on_time: float = 1.0

    def __post_init__(self) -> None:
        self.contexts = np.asarray(self.contexts)
        self.poses = np.asarray(self.poses, np.float64).reshape(-1, 3)
        n = len(self.contexts)
        if n < 1:
            raise TopodrakeError("a route needs at least one anchor")
        if len(self.poses) != n:
            raise TopodrakeError(f"a route of {n} anchors has {len(self.poses)} poses")
        if len(self.vertices) == 0:
            self.vertices = np.full(n, -1, np.int64)
        if len(self.edge_probability) == 0:
            self.edge_probability = np.ones(n - 1)
        self.vertices = np.asarray(self.vertices, np.int64)
        self.edge_probability = np.asarray(self.edge_probability, np.float64)
        self.legs = np.full((n - 1, 3), np.nan) if self.legs is None else \
            np.asarray(self.legs, np.float64)
        if self.legs.shape != (n - 1, 3):
            raise TopodrakeError(f"a route of {n} anchors needs ({n - 1}, 3) legs, got "
                                 f"{self.legs.shape}")
        if self.leg_paths is None:
            self.leg_paths = np.repeat(self.legs[:, None], 1, axis=1)
        self.leg_paths = np.asarray(self.leg_paths, np.float64)
        if self.leg_paths.ndim != 3 or self.leg_paths.shape[0] != n - 1 or \
                self.leg_paths.shape[2] != 3:
            raise TopodrakeError(f"a route of {n} anchors needs ({n - 1}, K, 3) leg paths, got "
                                 f"{self.leg_paths.shape}")
        if self.scans is not None:
            self.scans = np.asarray(self.scans, np.float64)
            if self.scans.ndim != 2 or len(self.scans) != n:
                raise TopodrakeError(f"a route of {n} anchors needs ({n}, beams) scans, got "
                                     f"{self.scans.shape}")
        if len(self.vertices) != n or len(self.edge_probability) != n - 1:
            raise TopodrakeError(f"a route of {n} anchors needs {n} vertices and {n - 1} edge "
                                 f"probabilities, got {len(self.vertices)} and "
                                 f"{len(self.edge_probability)}")

    def __len__(self) -> int:
        return len(self.contexts)

    @property
    def goal_pose(self) -> np.ndarray:
        return self.poses[-1]


LEG_POINTS = 8     # teach poses kept along each hop


def teach_legs(poses: np.ndarray, anchors: np.ndarray, odometry=None, seed: int = 0,
               points: int = LEG_POINTS) -> tuple[np.ndarray, np.ndarray]:
    """The hops between consecutive ``anchors`` (frames of a drive along
    ``poses`` (T, 3)) as the drive's odometry (``odometry``, an
    :class:`~topodrake.odometry.OdometryConfig` with the errors of ``seed``;
    default perfect) measured them: relative poses (A - 1, 3) and ``points``
    poses along each (A - 1, points, 3) (the route's ``legs`` and ``leg_paths``)."""
    cfg = odometry or OdometryConfig.perfect()
    poses = np.asarray(poses, np.float64).reshape(-1, 3)
    odo = poses if cfg.is_perfect else odometry_along(poses, cfg, seed)
    a = np.asarray(anchors, np.int64)
    frac = np.arange(1, points + 1) / points
    idx = np.rint(a[:-1, None] + frac[None] * (a[1:] - a[:-1])[:, None]).astype(np.int64)
    paths = relative(np.repeat(odo[a[:-1]], points, axis=0), odo[idx.ravel()])
    return relative(odo[a[:-1]], odo[a[1:]]), paths.reshape(len(idx), points, 3)


def route_from_trajectory(world, poses: np.ndarray, anchors: np.ndarray, network,
                          odometry=None, seed: int = 0, lidar=None) -> Route:
    """The route along frames ``anchors`` of one trajectory (``poses`` (T, 3)),
    with each anchor's context rendered for ``network`` (its ``observation``,
    ``k``, ``frame_step`` and ``sensor``; a pose oracle gets the poses) and
    its legs from the drive's odometry (:func:`teach_legs`). A camera
    route keeps each anchor's lidar scan (``lidar``'s, default the car's)."""
    poses = np.asarray(poses, np.float64)
    anchors = np.asarray(anchors, np.int64)
    if len(anchors) == 0 or anchors.min() < 0 or anchors.max() >= len(poses):
        raise TopodrakeError(f"anchors must be frames 0..{len(poses) - 1} of the trajectory")
    rows = context_frames(len(poses), anchors, network.k, network.frame_step)   # (A, 2k+1)
    ctx_poses = poses[rows]
    if network.observation == "pose":
        contexts = ctx_poses
    else:
        from topodrake.sensing.observe import observe

        obs = observe(world, network.observation, ctx_poses.reshape(-1, 3),
                      getattr(network, "sensor", None))
        contexts = obs.reshape(*rows.shape, *obs.shape[1:])
    legs, paths = teach_legs(poses, anchors, odometry, seed)

    return Route(contexts, poses[anchors], modality=network.observation, legs=legs,
                 leg_paths=paths,
                 scans=camera_scans(world, network.observation, poses[anchors], lidar))


def route_from_observations(observations: np.ndarray, poses: np.ndarray, anchors: np.ndarray,
                            k: int, frame_step: int, modality: str, odometry=None,
                            seed: int = 0, scans: np.ndarray | None = None) -> Route:
    """The route along frames ``anchors`` of one trajectory whose
    observations (T, ...) are already rendered (no rendering again):
    each anchor's 2k + 1 context frames, clamped to the trajectory; legs as
    in :func:`route_from_trajectory`; ``scans``: the anchors' lidar scans
    a camera route keeps (A, beams)."""
    poses = np.asarray(poses, np.float64)
    anchors = np.asarray(anchors, np.int64)
    if len(observations) != len(poses):
        raise TopodrakeError(f"{len(observations)} observations for {len(poses)} poses")
    if len(anchors) == 0 or anchors.min() < 0 or anchors.max() >= len(poses):
        raise TopodrakeError(f"anchors must be frames 0..{len(poses) - 1} of the trajectory")
    rows = context_frames(len(poses), anchors, k, frame_step)
    legs, paths = teach_legs(poses, anchors, odometry, seed)
    return Route(np.asarray(observations)[rows], poses[anchors], modality=modality, legs=legs,
                 leg_paths=paths, scans=scans)
