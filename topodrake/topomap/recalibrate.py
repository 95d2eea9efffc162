"""Edges from experience: what driving an edge tells, folded into its probability.

RE rates an edge once, when the map is built; driving it tells more. Each
edge a car drove keeps RE's rating (``p_re``) and counts of the times a car
passed it and failed on it (a failure: from its last visited anchor to its
active one, :func:`topodrake.navigation.replan.failing_edge`). Its
probability is the mean of a Beta posterior whose prior is RE's rating,
worth ``prior_weight`` drives::

    p = (prior_weight * p_re + passed) / (prior_weight + passed + failed)

With the default weight of 4, one failure takes a 0.99 edge to 0.79 and a
second to 0.66; passes raise it toward 1. The planner then prefers ways
that worked, and a plan's probability moves toward what the car achieves
(SGM prunes failed edges online; here they stay, less probable). The
counts and RE's rating are saved with the map, so experience adds up
across runs (``navigate --update-map``, ``map refit``).
"""

from __future__ import annotations

import numpy as np

from topodrake.errors import TopodrakeError

PRIOR_WEIGHT = 4.0


def edge_posterior(p_re, passed, failed, prior_weight: float = PRIOR_WEIGHT) -> np.ndarray:
    """The probability of edges rated ``p_re`` by RE after ``passed`` and
    ``failed`` drives (arrays broadcast)."""
    if not (np.isfinite(prior_weight) and prior_weight > 0):
        raise TopodrakeError(f"the prior weight of RE's rating must be > 0, got {prior_weight}")
    p_re, passed, failed = (np.asarray(a, np.float64) for a in (p_re, passed, failed))
    if np.any(passed < 0) or np.any(failed < 0):
        raise TopodrakeError("edge traversal counts must be >= 0")
    return (prior_weight * p_re + passed) / (prior_weight + passed + failed)


def record_traversals(topomap, passed=(), failed=(), prior_weight: float = PRIOR_WEIGHT
                      ) -> list[dict]:
    """Count each edge ``(u, v)`` of ``passed`` and ``failed`` (repeats count
    each time; edges the map does not hold are skipped) and set the
    probability of every edge counted to :func:`edge_posterior`. Returns one
    ``{"edge", "p_before", "p_after", "passed", "failed"}`` per edge touched."""
    counts: dict[tuple[int, int], list[int]] = {}
    for column, edges in ((0, passed), (1, failed)):
        for u, v in edges:
            e = (int(u), int(v))
            if topomap.graph.has_edge(*e):
                counts.setdefault(e, [0, 0])[column] += 1
    out = []
    for (u, v), (n_pass, n_fail) in counts.items():
        data = topomap.graph.edges[u, v]
        before = float(data["p"])
        data.setdefault("p_re", before)
        data["passed"] = int(data.get("passed", 0)) + n_pass
        data["failed"] = int(data.get("failed", 0)) + n_fail
        topomap.set_edge_probability(u, v, float(edge_posterior(
            data["p_re"], data["passed"], data["failed"], prior_weight)))
        out.append({"edge": [u, v], "p_before": round(before, 6),
                    "p_after": round(float(data["p"]), 6),
                    "passed": data["passed"], "failed": data["failed"]})
    return out


def experience_summary(topomap) -> dict:
    """How much driving a map has taken in: edges driven, passes and failures."""
    driven = [d for _, _, d in topomap.graph.edges(data=True) if "p_re" in d]
    return {"edges_driven": len(driven),
            "passes": int(sum(d.get("passed", 0) for d in driven)),
            "failures": int(sum(d.get("failed", 0) for d in driven))}
