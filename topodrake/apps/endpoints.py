"""The start and goal of a query, as a pose or as a world's named place.

``map plan`` and ``navigate`` take each end either as a pose
(``--start X,Y,YAW``) or as the index of one of the world's places
(``--start-place N``, :attr:`topodrake.world.world.World.places`), never
both. :func:`add_endpoint_options` adds the four options,
:func:`check_endpoints` refuses both or neither before any work, and
:func:`endpoint_poses` turns them into poses once the world is known (a
place the world does not have is refused in one line naming the world and
how many places it has).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from topodrake.apps import argtypes as at
from topodrake.demonstrations import read_manifest
from topodrake.errors import TopodrakeError
from topodrake.topomap.mapfile import read_map_meta
from topodrake.world import load_world


def add_endpoint_options(p) -> None:
    """``--start``/``--start-place`` and ``--goal``/``--goal-place``."""
    for end in ("start", "goal"):
        p.add_argument(f"--{end}", metavar="X,Y,YAW",
                       help=f"{end} pose (m, m, rad); or --{end}-place")
        p.add_argument(f"--{end}-place", type=at.count0, metavar="N",
                       help=f"{end} at the world's place N ('topodrake world info' lists them); "
                            f"or --{end}")


def parse_pose(text: str, what: str) -> np.ndarray:
    """``"X,Y,YAW"`` -> (3,) (metres, metres, radians)."""
    try:
        values = [float(v) for v in str(text).split(",")]
    except ValueError:
        values = []
    if len(values) != 3 or not all(math.isfinite(v) for v in values):
        raise TopodrakeError(f"--{what} must be X,Y,YAW (three finite numbers), got {text!r}")
    return np.array(values)


def check_endpoints(args) -> None:
    """Each end given once, as a pose or as a place; poses parsed."""
    for end in ("start", "goal"):
        pose, place = getattr(args, end), getattr(args, f"{end}_place")
        if pose is not None and place is not None:
            raise TopodrakeError(f"give the {end} as --{end} X,Y,YAW or as --{end}-place N, "
                                 f"not both")
        if pose is None and place is None:
            raise TopodrakeError(f"the {end} is missing: give --{end} X,Y,YAW or --{end}-place N")
        if pose is not None:
            parse_pose(pose, end)


def uses_places(args) -> bool:
    return args.start_place is not None or args.goal_place is not None


def endpoint_poses(args, world) -> tuple[np.ndarray, np.ndarray]:
    """(start, goal) poses of checked ``args`` (:func:`check_endpoints`) in ``world``."""
    out = []
    for end in ("start", "goal"):
        place = getattr(args, f"{end}_place")
        out.append(parse_pose(getattr(args, end), end) if place is None
                   else world.place_pose(place, f"--{end}-place"))
    return out[0], out[1]


def source_world(source):
    """The world of a map file, a demonstration folder or a world name (its
    places), read without loading the map or the drives."""
    source = Path(source)
    if source.suffix == ".tdmap":
        if not source.is_file():
            raise TopodrakeError(f"map file {source} does not exist")
        return load_world(read_map_meta(source)["world"])
    if source.is_dir():
        return load_world(read_manifest(source)["world"])
    return load_world(str(source))


def resolve_endpoints(args, source) -> tuple[np.ndarray, np.ndarray]:
    """(start, goal) poses of ``args``, checked (:func:`check_endpoints`);
    places are looked up in the world of ``source`` (a map file,
    demonstration folder or world), before any other work."""
    check_endpoints(args)
    world = source_world(source) if uses_places(args) else None
    return endpoint_poses(args, world)
