"""Expert trajectories packed small, to carry them to a training machine.

A :class:`~topodrake.learning.samples.TrajectorySet` of all 96 training
houses holds about 3.7 million poses; as float64 that is ~90 MB, as the
demonstration folders ~100 MB. Packed, poses are rounded to 1 mm and
1e-4 rad and delta-coded along each trajectory (int32, then deflated): about
0.1 MB per house. Speed and steering are not kept (they only feed the
direct-control label), so samples made from a packed set are C_WP samples
(``make_samples(..., controls=False)``).

File format (``.npz``): ``format = "topodrake-trajpack"``, ``version``,
``worlds`` (JSON list), ``traj_world``, ``traj_offsets``, ``deltas`` (P, 3)
int32.
"""

from __future__ import annotations

import io
import json

import numpy as np

from topodrake.errors import TopodrakeError
from topodrake.fileio import atomic_write_bytes, read_tagged_npz
from topodrake.learning.samples import TrajectorySet

FORMAT = "topodrake-trajpack"
VERSION = 1
_SCALE = np.array([1000.0, 1000.0, 1e4])   # mm, 1e-4 rad


def pack_trajectories(trajs: TrajectorySet, path):
    """Write ``trajs`` packed to ``path`` (atomically)."""
    q = np.round(trajs.poses * _SCALE).astype(np.int64)
    d = np.diff(q, axis=0, prepend=np.zeros((1, 3), np.int64))
    d[trajs.traj_offsets[:-1]] = q[trajs.traj_offsets[:-1]]   # each drive starts absolute
    if np.abs(d).max(initial=0) >= 2 ** 31:
        raise TopodrakeError("trajectories too far from the origin to pack")
    buf = io.BytesIO()
    np.savez_compressed(buf, format=np.array(FORMAT), version=np.array(VERSION),
                        worlds=np.array(json.dumps(list(trajs.worlds))),
                        traj_world=trajs.traj_world.astype(np.int32),
                        traj_offsets=trajs.traj_offsets.astype(np.int64),
                        deltas=d.astype(np.int32))
    return atomic_write_bytes(path, buf.getvalue())


def load_packed_trajectories(path) -> TrajectorySet:
    """The trajectories of a packed file (states: poses, speed and steering 0)."""
    z = read_tagged_npz(path, FORMAT, VERSION, "trajectory pack")
    try:
        worlds = json.loads(str(z["worlds"]))
        traj_world, offsets, d = z["traj_world"], z["traj_offsets"], z["deltas"]
    except (KeyError, ValueError):
        raise TopodrakeError(f"{path} is corrupt or not a trajectory pack file") from None
    d = d.astype(np.int64)
    starts = offsets[:-1]
    # cumulative sum restarted at each drive's first row
    cs = np.cumsum(d, axis=0)
    base = np.repeat(cs[starts] - d[starts], np.diff(offsets), axis=0)
    poses = (cs - base) / _SCALE
    states = np.zeros((len(poses), 5))
    states[:, :3] = poses
    return TrajectorySet(list(worlds), traj_world.astype(np.int32), offsets.astype(np.int64),
                         poses, states)
