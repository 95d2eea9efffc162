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
:func:`house_pairs` keeps each house's labelled pairs in ``DATA/oracle_reach/``
and :func:`oracle_study` fits and rates the oracles over the houses of a
study's options, with its result document.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from topodrake.demonstrations import CollectConfig, collect, load_demos
from topodrake.errors import TopodrakeError
from topodrake.experiments.scenarios import option
from topodrake.fileio import atomic_write_bytes
from topodrake.learning.reachability.calibration import auroc, ece
from topodrake.learning.reachability.labels import ReachLabelConfig, rollout_to_targets
from topodrake.learning.samples import SampleConfig, _arclength, apply_jitter, draw_jitter
from topodrake.montecarlo import trial_seeds
from topodrake.navigation.evaluate import GeometricReachability
from topodrake.topomap.scorer import (
    CALIBRATED_ORACLE,
    TRUSTING_ORACLE,
    OracleConfig,
    pair_geometry,
    reach_from_geometry,
)
from topodrake.topomap.sources import demo_folder
from topodrake.validate import check_count, check_seed
from topodrake.world import load_world

HOUSES = "test-0,test-1,test-2,test-3,test-4"
FIELDS = ("src", "tgt", "same", "outcome", "label")
#: Candidate values of the fit (coordinate descent over the OracleConfig fields).
GRID = {"reach_m": [2.0, 2.5, 3.0, 4.0, 5.0, 6.0, 8.0, 10.0], "reach_soft_m": [0.1, 0.2, 0.5, 1.0],
        "bearing_rad": [0.8, 1.2, 1.6, 2.0, 2.4, 2.8, 3.2], "bearing_soft_rad": [0.1, 0.2, 0.4, 0.8],
        "turn_rad": [0.8, 1.2, 1.6, 2.0, 2.4], "turn_soft_rad": [0.1, 0.2, 0.4, 0.8],
        "min_overlap": [0.0, 0.02, 0.05, 0.1, 0.2, 0.3], "overlap_soft": [0.01, 0.02, 0.05, 0.1],
        "hidden": [0.0, 0.1, 0.2, 0.3, 0.5]}


def oracle_reach_pairs(world, drives: list[np.ndarray], n: int, seed: int, *,
                       distance_min_m: float = -1.0, distance_max_m: float = 8.0,
                       same_trajectory: float = 0.6, other_within_m: float = 8.0,
                       noise_std: float = 0.33) -> dict:
    """``n`` labelled (source, target) pairs of the A* oracle controller in
    ``world`` over the drives' pose arrays: ``src`` (n, 3), ``tgt`` (n, 3),
    ``same`` (n,), ``outcome`` and ``label`` (n,)."""
    from topodrake.learning.waypoint.policy import AStarOracle

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
    p = np.asarray(probability, np.float64)
    y = np.asarray(label, np.float64)
    return {"ece": round(ece(p, y, bins), 4), "auroc": round(auroc(p, y), 4),
            "nll": round(_nll(p, y), 4)}


def fit_oracle(geometry: dict, label: np.ndarray, start, grid: dict, rounds: int = 4):
    """The :class:`~topodrake.topomap.scorer.OracleConfig` that maximises the
    likelihood of ``label`` by coordinate descent from ``start`` over the
    candidate values ``grid`` (field name -> values); returns (config, nll)."""
    from dataclasses import replace


    y = np.asarray(label, np.float64)
    best = start
    for _ in range(rounds):
        for name, values in grid.items():
            best = min((replace(best, **{name: v}) for v in values),
                       key=lambda c: _nll(reach_from_geometry(geometry, c), y))
    return best, _nll(reach_from_geometry(geometry, best), y)


def house_pairs(spec: str, n: int, seed: int, data: Path, progress: bool) -> dict:
    """The labelled oracle pairs of one house (cached)."""
    import io


    key = demo_folder(spec).name
    path = data / "oracle_reach" / f"{key}-n{n}-s{seed}.npz"
    if path.is_file():
        with np.load(path, allow_pickle=False) as z:
            return {k: z[k] for k in FIELDS}
    folder = data / "demos" / "pairs-s0" / key
    collect(spec, folder, CollectConfig(protocol="pairs", seed=0), progress=progress)
    drives = [d.poses for d in load_demos(folder, successful_only=True)[1]]
    out = oracle_reach_pairs(load_world(spec), drives, n, seed)
    buf = io.BytesIO()
    np.savez_compressed(buf, **{k: out[k] for k in FIELDS})
    atomic_write_bytes(path, buf.getvalue())
    return {k: out[k] for k in FIELDS}


@dataclass
class OracleReachStudy:
    """The oracle-reach study's settings: its houses (catalogue names or map
    YAMLs), labelled pairs per house, the seed of the pairs and their
    noise, and the cache of demonstrations and pairs."""
    houses: list[str] = option(HOUSES.split(","), "test houses (catalogue names or map YAMLs)")
    pairs: int = option(800, "labelled pairs per house")
    seed: int = option(1, "seed of the pairs and their noise")
    data: str = option("data", "cache of demonstrations and pairs")

    def validate(self) -> "OracleReachStudy":
        """Check the numbers; a bad one raises a one-line TopodrakeError."""
        check_count("oracle-reach scenario: pairs", self.pairs)
        check_seed("oracle-reach scenario: seed", self.seed)
        return self


def oracle_study(study: OracleReachStudy, command: str, quiet: bool = False) -> dict:
    """The study's result document for ``study``; ``command`` is recorded;
    ``quiet``: no progress bars."""
    from tqdm import tqdm


    specs = [h for h in study.houses if h]
    if not specs:
        raise TopodrakeError("--houses names no house")
    t0 = time.perf_counter()
    geos, labels, follower = [], [], []
    for spec in tqdm(specs, desc="houses", disable=quiet):
        world = load_world(spec)
        pairs = house_pairs(spec, study.pairs, study.seed, Path(study.data), not quiet)
        geos.append(pair_geometry(world, pairs["src"], pairs["tgt"]))
        labels.append(pairs["label"])
        follower.append(GeometricReachability(world).probability(pairs["src"], pairs["tgt"]))
    geo = {k: np.concatenate([g[k] for g in geos]) for k in geos[0]}
    y = np.concatenate(labels).astype(np.float64)
    fitted, _ = fit_oracle(geo, y, CALIBRATED_ORACLE, GRID)
    paper = OracleConfig(reach_m=2.5, bearing_rad=float("inf"), turn_rad=1.2, min_overlap=0.3,
                         hidden=0.0)
    oracles = {name: calibration_scores(reach_from_geometry(geo, c), y)
               for name, c in (("paper_geometry", paper), ("map", OracleConfig()),
                               ("calibrated", CALIBRATED_ORACLE), ("trusting", TRUSTING_ORACLE),
                               ("fitted", fitted))}
    oracles["follower"] = calibration_scores(np.concatenate(follower), y)
    by_distance = {}
    for lo in range(8):
        m = geo["sight"] & (geo["distance"] >= lo) & (geo["distance"] < lo + 1)
        if m.any():
            by_distance[f"{lo}-{lo + 1}m"] = {"pairs": int(m.sum()), "success": round(float(y[m].mean()), 3)}
    summary = {"pairs": int(len(y)), "success": round(float(y.mean()), 4), "oracles": oracles,
               "fitted": {k: (None if not np.isfinite(v) else round(float(v), 4))
                          for k, v in asdict(fitted).items()},
               "success_by_distance": by_distance}
    return {"command": command, "seed": study.seed,
            "houses": specs, "pairs_per_house": study.pairs,
            "wall_time_s": round(time.perf_counter() - t0, 1),
            "note": "success_by_distance: pairs with a clear straight line, by straight distance",
            "summary": summary}
