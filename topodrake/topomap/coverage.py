"""Coverage: whether a plan's start or goal lies where the map's drives went.

RE rates a view against a vertex's context; in a building of look-alike
rooms and corridors it links a view to a place the drives never passed as
readily as to its own. The lidar scans tell them apart: a link end is
*registered* where the view's scan registers onto the vertex's scan with
the wide search a map's joins use (:func:`~topodrake.topomap.build.join_icp`,
metres and half a right angle apart) and the fit pairs at least
``links.cover`` of both scans' points (:func:`registered_links`). A start
or goal none of whose RE links is registered is not covered, and the plan
refuses it with that reason (:func:`uncovered_reason`); where one is, the
plan chooses among all its links as before (keeping only registered ones
cost test-house plans whose true goal link registers below the share:
docs/coverage.md). Maps that check no scans (a camera map without
its drives' scans, a pose oracle map) keep every link.
"""

from __future__ import annotations

import numpy as np

from topodrake.registration.icp import register
from topodrake.topomap.build import join_icp
from topodrake.topomap.scan_match import vertex_scans


def registration_shares(topomap, vertices: list[int], view_scan: np.ndarray) -> np.ndarray:
    """(V,) the share of points (the smaller of both scans') the wide
    registration of ``view_scan`` onto each vertex's scan pairs; 0 where
    the fit is rejected."""
    if not vertices:
        return np.zeros(0)
    res = register(np.asarray(view_scan, np.float64)[None],
                   np.asarray(vertex_scans(topomap, vertices), np.float64), None, join_icp())
    return np.where(res.accepted, np.minimum(res.inlier, res.inlier_back), 0.0)


def registered_links(topomap, links: list[tuple[int, float]], view_scan: np.ndarray,
                     share: float) -> tuple[list[tuple[int, float]], float]:
    """(the ``links`` (vertex, p) whose vertex's scan ``view_scan`` registers
    onto, pairing at least ``share`` of both scans' points; the best share
    of any link, 0 for none)."""
    shares = registration_shares(topomap, [v for v, _ in links], view_scan)
    kept = [link for link, s in zip(links, shares) if s >= share]
    return kept, float(shares.max(initial=0.0))


def uncovered_reason(end: str, links: int, best_share: float, share: float) -> str:
    """The reason a plan gives for a start or goal (``end``) whose ``links``
    RE links were all refused by their scans."""
    return (f"the {end} is not covered by the map: RE links it to {links} vertices, but its "
            f"scan registers onto none of theirs (best share of points paired "
            f"{best_share:.2f} < {share}); the map's drives did not pass there")
