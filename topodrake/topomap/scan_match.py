"""Scan matching: whether two lidar views are one place, not two look-alikes.

:func:`scans_match` asks the ICP fit of one scan onto the other
(:mod:`topodrake.registration.icp`, from the identity) to be accepted and to
pair at least a share of each scan's points. A map checks its joins
(reuse, junctions) and a plan its start and goal links this way on top of
RE where :func:`checks_scans` or :func:`joins_by_scans` say so
(:attr:`~topodrake.topomap.graph.MapConfig.scan_match`; a camera map by the
lidar scans its drives took, with ``camera.scans``).
"""

from __future__ import annotations

import numpy as np

from topodrake.registration.icp import register


def checks_scans(topomap) -> bool:
    """Whether ``topomap`` checks its joins and links by scan matching: a
    lidar map with ``scan_match`` above 0."""
    return topomap.modality == "lidar" and topomap.config.scan_match > 0


def joins_by_scans(topomap) -> bool:
    """Whether building ``topomap`` checks its joins (reuse, junctions) by
    scan matching: a lidar map (:func:`checks_scans`), or a camera map that
    keeps its drives' scans, with ``camera.scans`` on."""
    if checks_scans(topomap):
        return True
    return (topomap.modality == "camera" and topomap.config.camera.scans
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
    source, target = np.asarray(source, np.float64), np.asarray(target, np.float64)
    if source.ndim == 1:
        source = source[None]
    if target.ndim == 1:
        target = target[None]
    if not len(source) or not len(target):
        return np.zeros(0, bool)
    res = register(source, target)
    return res.accepted & (np.minimum(res.inlier, res.inlier_back) >= min_inlier)
