"""What the A* oracle controller reaches: rollouts that calibrate the geometric oracle RE.

The geometric oracle RE (:class:`topodrake.navigation.evaluate.GeometricReachability`
for the follower, :class:`topodrake.topomap.scorer.OracleScorer` for maps)
stands in for a perfect RE of the A* oracle C_WP. It should say what that
controller actually reaches, so it is fitted to the controller's own
closed-loop outcomes, labelled exactly as the learned RE's labels are
(:mod:`topodrake.learning.reach_labels`: jittered sources on expert drives,
targets on the same drive at a signed arc distance or on another drive of
the house, actuation noise, success within 0.27 m or both overlaps above
0.7 before ``A* / 0.25 m/s``; collisions and losing sight fail).

:func:`oracle_reach_pairs` draws the pairs and rolls them out,
:func:`pair_geometry` gives the quantities the oracle reads (straight-line
distance, heading change, the smaller mutual image overlap, a clear straight
line), and :func:`fit_reach` fits the oracle's distance scale to the
outcomes (maximum likelihood over a grid).
"""

from __future__ import annotations

import numpy as np

from topodrake.errors import TopodrakeError


def oracle_reach_pairs(world, drives: list[np.ndarray], n: int, seed: int, *,
                       distance_min_m: float = -1.0, distance_max_m: float = 8.0,
                       same_trajectory: float = 0.6, other_within_m: float = 8.0,
                       noise_std: float = 0.33) -> dict:
    """``n`` labelled (source, target) pairs of the A* oracle controller in
    ``world`` over the drives' pose arrays: ``src`` (n, 3), ``tgt`` (n, 3),
    ``same`` (n,), ``outcome`` and ``label`` (n,)."""
    from topodrake.learning.policy import AStarOracle
    from topodrake.learning.reach_labels import ReachLabelConfig, rollout_to_targets
    from topodrake.learning.samples import SampleConfig, _arclength, apply_jitter, draw_jitter
    from topodrake.montecarlo import trial_seeds

    drives = [np.asarray(d, np.float64) for d in drives if len(d) > 1]
    if not drives:
        raise TopodrakeError(f"world {world.name!r}: no drives to draw oracle pairs from")
    rng = np.random.default_rng(seed)
    lengths = np.array([len(d) for d in drives])
    arcs = [_arclength(d) for d in drives]
    allp = np.concatenate(drives)
    src, tgt, same = [], [], []
    tries = 0
    while len(src) < n:
        tries += 1
        if tries > 50 * n + 1000:
            raise TopodrakeError(f"world {world.name!r}: could not draw {n} oracle pairs")
        i = int(rng.choice(len(drives), p=lengths / lengths.sum()))
        a = int(rng.integers(lengths[i]))
        if rng.random() < same_trajectory:
            s = arcs[i][a] + rng.uniform(distance_min_m, distance_max_m)
            if not 0.0 <= s <= arcs[i][-1]:
                continue
            t = drives[i][min(int(np.searchsorted(arcs[i], s)), lengths[i] - 1)]
            is_same = True
        else:
            near = np.flatnonzero(np.hypot(*(allp[:, :2] - drives[i][a, :2]).T) < other_within_m)
            t = allp[int(rng.choice(near))]
            is_same = False
        lat, dth = draw_jitter(rng, 1, SampleConfig())
        pose, free = apply_jitter(world, drives[i][a][None], lat, dth)
        if not free[0]:
            continue
        src.append(pose[0])
        tgt.append(t)
        same.append(is_same)
    src, tgt = np.array(src), np.array(tgt)
    cfg = ReachLabelConfig(noise_std=noise_std)
    out = rollout_to_targets(world, AStarOracle(world), src, tgt,
                             lambda sl: tgt[sl][:, None], np.array(trial_seeds(seed, n)), cfg)
    return {"src": src, "tgt": tgt, "same": np.array(same), **out}


def pair_geometry(world, a: np.ndarray, b: np.ndarray, sight_clearance_m: float = 0.12) -> dict:
    """The oracle's inputs for poses ``a`` -> ``b`` (N, 3): ``distance``,
    ``turn`` (absolute heading change), ``overlap`` (the smaller mutual image
    overlap) and ``sight`` (a straight line keeping ``sight_clearance_m``)."""
    from topodrake.expert.sight import segment_clear
    from topodrake.sensing.overlap import mutual_overlap

    a = np.asarray(a, np.float64).reshape(-1, 3)
    b = np.asarray(b, np.float64).reshape(-1, 3)
    g = world.grid
    clear, (ox, oy), res = g.clearance, g.origin, g.resolution
    return {"distance": np.hypot(*(b[:, :2] - a[:, :2]).T),
            "turn": np.abs((b[:, 2] - a[:, 2] + np.pi) % (2 * np.pi) - np.pi),
            "overlap": mutual_overlap(world, a, b).min(axis=1),
            "sight": np.array([bool(segment_clear(clear, ox, oy, res, sight_clearance_m,
                                                  *a[i, :2], *b[i, :2])) for i in range(len(a))])}


def _nll(p: np.ndarray, y: np.ndarray) -> float:
    p = np.clip(p, 1e-6, 1 - 1e-6)
    return float(-np.mean(y * np.log(p) + (1 - y) * np.log1p(-p)))


def fit_reach(geometry: dict, label: np.ndarray, model, grid: dict) -> tuple[dict, float]:
    """The parameters in the product ``grid`` (name -> candidate values) that
    maximise the likelihood of ``label`` under ``model(geometry, **params)``;
    returns (params, mean negative log-likelihood)."""
    import itertools

    names = list(grid)
    best, best_nll = None, np.inf
    y = np.asarray(label, np.float64)
    for values in itertools.product(*(grid[k] for k in names)):
        params = dict(zip(names, values))
        nll = _nll(model(geometry, **params), y)
        if nll < best_nll:
            best, best_nll = params, nll
    return best, best_nll
