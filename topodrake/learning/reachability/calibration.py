"""Calibration of predicted probabilities against binary outcomes.

Used for the reachability estimator: does an RE of 0.9 mean that nine runs
in ten reach the target? All functions take predicted probabilities ``p``
(N,) in [0, 1] and outcomes ``y`` (N,) in {0, 1}.

* :func:`reliability` - per-bin mean prediction, empirical rate and count
  (equal-width bins over [0, 1]);
* :func:`ece` - expected calibration error, the count-weighted mean of
  |rate - mean prediction| over the bins (10 bins by default);
* :func:`brier` - mean squared error of the probabilities;
* :func:`auroc` - area under the ROC curve (rank statistic, ties counted
  one half);
* :func:`fit_temperature` - the temperature T that minimises the negative
  log-likelihood of ``sigmoid(logit / T)`` on validation data (temperature
  scaling; T > 1 softens over-confident predictions).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from topodrake.errors import TopodrakeError


def _check(p, y) -> tuple[np.ndarray, np.ndarray]:
    p = np.asarray(p, np.float64).ravel()
    y = np.asarray(y).ravel()
    if p.shape != y.shape:
        raise TopodrakeError(f"{p.size} predictions but {y.size} outcomes")
    if p.size == 0:
        raise TopodrakeError("no predictions to calibrate")
    if np.any((p < 0) | (p > 1)) or not np.all(np.isfinite(p)):
        raise TopodrakeError("predictions must be probabilities in [0, 1]")
    if not np.all((y == 0) | (y == 1)):
        raise TopodrakeError("outcomes must be 0 or 1")
    return p, y.astype(np.float64)


@dataclass
class Reliability:
    edges: np.ndarray        # (B + 1,)
    mean_pred: np.ndarray    # (B,) NaN for empty bins
    rate: np.ndarray         # (B,) empirical success rate, NaN for empty bins
    count: np.ndarray        # (B,)


def reliability(p, y, bins: int = 10) -> Reliability:
    p, y = _check(p, y)
    edges = np.linspace(0.0, 1.0, bins + 1)
    idx = np.clip(np.searchsorted(edges, p, side="right") - 1, 0, bins - 1)
    count = np.bincount(idx, minlength=bins)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean_pred = np.bincount(idx, p, bins) / count
        rate = np.bincount(idx, y, bins) / count
    return Reliability(edges, mean_pred, rate, count)


def ece(p, y, bins: int = 10) -> float:
    r = reliability(p, y, bins)
    full = r.count > 0
    return float(np.sum(r.count[full] * np.abs(r.rate[full] - r.mean_pred[full])) / r.count.sum())


def brier(p, y) -> float:
    p, y = _check(p, y)
    return float(np.mean((p - y) ** 2))


def auroc(p, y) -> float:
    """Probability that a random success scores above a random failure."""
    from scipy.stats import rankdata

    p, y = _check(p, y)
    pos = y == 1
    n_pos, n_neg = int(pos.sum()), int((~pos).sum())
    if n_pos == 0 or n_neg == 0:
        raise TopodrakeError("AUROC needs both successes and failures")
    ranks = rankdata(p)          # average ranks: ties count one half
    return float((ranks[pos].sum() - n_pos * (n_pos + 1) / 2) / (n_pos * n_neg))


def fit_temperature(logits, y, bounds: tuple[float, float] = (0.05, 20.0)) -> float:
    """Temperature minimising the validation NLL of ``sigmoid(logits / T)``."""
    from scipy.optimize import minimize_scalar

    z = np.asarray(logits, np.float64).ravel()
    _, y = _check(np.full(z.shape, 0.5), y)

    def nll(log_t):
        s = z / np.exp(log_t)
        # log(1 + e^s) - y s, computed stably
        return float(np.mean(np.logaddexp(0.0, s) - y * s))

    res = minimize_scalar(nll, bounds=(np.log(bounds[0]), np.log(bounds[1])), method="bounded")
    return float(np.exp(res.x))


def fit_platt(logits, y) -> tuple[float, float]:
    """Slope and bias (a, b) minimising the NLL of ``sigmoid(a * logits + b)``
    (Platt scaling: a temperature plus a shift of the logit's zero, which
    is what a different base rate of success asks for)."""
    from scipy.optimize import minimize
    from scipy.special import expit

    z = np.asarray(logits, np.float64).ravel()
    _, y = _check(np.full(z.shape, 0.5), y)

    def nll(ab):
        s = ab[0] * z + ab[1]
        q = expit(s) - y                            # d nll / d s
        return float(np.mean(np.logaddexp(0.0, s) - y * s)), np.array([np.mean(q * z), np.mean(q)])

    res = minimize(nll, np.array([1.0, 0.0]), jac=True, method="L-BFGS-B",
                   bounds=[(1e-3, 50.0), (-50.0, 50.0)])
    return float(res.x[0]), float(res.x[1])


def calibration_summary(p, y, bins: int = 10) -> dict:
    """ECE, Brier score and AUROC (None when one class is missing) as floats."""
    p, y = _check(p, y)
    try:
        auc = auroc(p, y)
    except TopodrakeError:
        auc = None
    return {"ece": ece(p, y, bins), "brier": brier(p, y), "auroc": auc, "n": int(p.size),
            "positive_rate": float(y.mean())}
