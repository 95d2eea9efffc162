"""Online recalibration: edges a car failed on become less probable.

RE rates an edge once, when the map is built; driving it tells more. After
a run, each edge the follower gave up on (from its last visited anchor to
its active one, :func:`topodrake.navigation.replan.failing_edge`) has its
probability multiplied by ``factor``, so that the next plan prefers other
ways and a path's probability keeps closer to what the car achieves. The
map is then saved over its file (atomically) by the caller.
"""

from __future__ import annotations

from topodrake.errors import TopodrakeError

FACTOR = 0.5


def lower_failed_edges(topomap, edges, factor: float = FACTOR) -> list[dict]:
    """Multiply the probability of each edge ``(u, v)`` in ``edges`` (that
    the map holds; repeats count once) by ``factor``; returns one
    ``{"edge": [u, v], "p_before": p, "p_after": q}`` per edge lowered."""
    if not 0.0 < factor < 1.0:
        raise TopodrakeError(f"the recalibration factor must be in (0, 1), got {factor}")
    out = []
    for u, v in dict.fromkeys((int(a), int(b)) for a, b in edges):
        data = topomap.graph.get_edge_data(u, v)
        if data is None:
            continue
        before = float(data["p"])
        topomap.set_edge_probability(u, v, before * factor)
        out.append({"edge": [u, v], "p_before": round(before, 6),
                    "p_after": round(float(topomap.graph.edges[u, v]["p"]), 6)})
    return out
