"""What the A* oracle controller reaches: rollouts that calibrate the geometric oracle RE.

The geometric oracle RE (:class:`topodrake.navigation.evaluate.GeometricReachability`
for the follower, :class:`topodrake.topomap.scorer.OracleScorer` for maps)
stands in for a perfect RE of the A* oracle C_WP. It should say what that
controller actually reaches, so it is fitted to the controller's own
closed-loop outcomes, labelled exactly as the learned RE's labels are
(:mod:`topodrake.learning.reachability.labels`: jittered sources on expert drives,
targets on the same drive at a signed arc distance or on another drive of
the house, actuation noise, success within 0.27 m or both overlaps above
0.7 before ``A* / 0.25 m/s``; collisions and losing sight fail).

:func:`oracle_reach_pairs` draws the pairs and rolls them out,
:func:`topodrake.topomap.scorer.pair_geometry` gives what the oracle reads,
:func:`fit_oracle` fits its parameters to the outcomes (maximum likelihood,
coordinate descent over candidate values) and :func:`calibration_scores`
rates any probabilities against them (ECE, AUROC, log-likelihood).
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
    from topodrake.learning.reachability.labels import ReachLabelConfig, rollout_to_targets
    from topodrake.learning.samples import SampleConfig, _arclength, apply_jitter, draw_jitter
    from topodrake.learning.waypoint.policy import AStarOracle
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


def _nll(p: np.ndarray, y: np.ndarray) -> float:
    p = np.clip(p, 1e-6, 1 - 1e-6)
    return float(-np.mean(y * np.log(p) + (1 - y) * np.log1p(-p)))


def calibration_scores(probability: np.ndarray, label: np.ndarray, bins: int = 10) -> dict:
    """ECE (``bins`` equal bins), AUROC and mean negative log-likelihood of
    predicted probabilities against 0/1 outcomes."""
    from topodrake.learning.reachability.calibration import auroc, ece

    p = np.asarray(probability, np.float64)
    y = np.asarray(label, np.float64)
    return {"ece": round(ece(p, y, bins), 4), "auroc": round(auroc(p, y), 4),
            "nll": round(_nll(p, y), 4)}


def fit_oracle(geometry: dict, label: np.ndarray, start, grid: dict, rounds: int = 4):
    """The :class:`~topodrake.topomap.scorer.OracleConfig` that maximises the
    likelihood of ``label`` by coordinate descent from ``start`` over the
    candidate values ``grid`` (field name -> values); returns (config, nll)."""
    from dataclasses import replace

    from topodrake.topomap.scorer import reach_from_geometry

    y = np.asarray(label, np.float64)
    best = start
    for _ in range(rounds):
        for name, values in grid.items():
            best = min((replace(best, **{name: v}) for v in values),
                       key=lambda c: _nll(reach_from_geometry(geometry, c), y))
    return best, _nll(reach_from_geometry(geometry, best), y)
