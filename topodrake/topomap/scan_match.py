"""Scan matching: whether two lidar views are one place, not two look-alikes.

To the lidar RE two rooms of the same shape look alike (RE passes 0.99
between them both ways), so a map that joins drives or links a start on RE
alone jumps across the house. Registering one scan onto the other tells
them apart: at one place the walls, doorways and furniture line up, in a
look-alike room the fit leaves a share of points without a partner.
:func:`scans_match` asks the ICP fit (:mod:`topodrake.registration.icp`,
from the identity) to be accepted and to pair at least ``min_inlier`` of
each scan's points. It is a check on top of RE, applied where a map joins
drives (reuse, junctions) and where a plan links its start and goal
(:attr:`topodrake.topomap.graph.MapConfig.scan_match`). A camera map that
keeps the lidar scans its drives took with their frames checks its joins
the same way (:attr:`~topodrake.topomap.graph.MapConfig.camera_scans`): a
room that copies another's textures rarely copies its walls.
"""

from __future__ import annotations

import numpy as np


def checks_scans(topomap) -> bool:
    """Whether ``topomap`` checks its joins and links by scan matching: a
    lidar map with ``scan_match`` above 0."""
    return topomap.modality == "lidar" and topomap.config.scan_match > 0


def joins_by_scans(topomap) -> bool:
    """Whether building ``topomap`` checks its joins (reuse, junctions) by
    scan matching: a lidar map (:func:`checks_scans`), or a camera map that
    keeps its drives' scans, with ``camera_scans`` on."""
    if checks_scans(topomap):
        return True
    return (topomap.modality == "camera" and topomap.config.camera_scans
            and topomap.config.scan_match > 0 and topomap.bank.scans is not None)


def vertex_scans(topomap, vertices) -> np.ndarray:
    """The scans of ``vertices`` (V, beams) a map's joins are checked with:
    a lidar map's anchor observations, a camera map's kept scans."""
    rows = topomap.centers(vertices)
    if topomap.modality == "lidar":
        return topomap.bank.observations[rows]
    return topomap.bank.scans[rows]


def scans_match(source, target, min_inlier: float) -> np.ndarray:
    """(B,) bool: each scan of ``source`` (B, beams) registers onto the scan
    of ``target`` beside it (either may be one scan, shared by all): the
    fit is accepted and pairs at least ``min_inlier`` of both scans' points."""
    from topodrake.registration.icp import register

    source, target = np.asarray(source, np.float64), np.asarray(target, np.float64)
    if source.ndim == 1:
        source = source[None]
    if target.ndim == 1:
        target = target[None]
    if not len(source) or not len(target):
        return np.zeros(0, bool)
    res = register(source, target)
    return res.accepted & (np.minimum(res.inlier, res.inlier_back) >= min_inlier)
