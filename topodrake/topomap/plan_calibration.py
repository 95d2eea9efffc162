"""A plan's chance of success, calibrated on trials in houses other than the test houses.

A plan's probability is the product of its edges' RE, each rated from the
anchor itself and not from where the car will be after the hops before it,
so it says little about whether the car arrives. A :class:`PlanCalibration`
maps what the planner knows of a plan (its log probability and its number of
anchors) to a chance of success by logistic regression, fitted on planning
trials of one method (map and follower) outside the test houses: the
calibration houses ``calib-0..4``, which no network trains in (a follower
succeeds more often in the houses it was trained in), or training houses
its networks never saw. It ships
beside the RE it was fitted for (``checkpoints/<reach>/plan_calibration.json``)
and the planner reports its answer as ``success_probability``.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from topodrake.errors import TopodrakeError
from topodrake.fileio import atomic_write_json

FORMAT = "topodrake-plan-calibration"
VERSION = 1
FILENAME = "plan_calibration.json"
#: what the calibration reads of a plan
FEATURES = ("log_probability", "anchors_per_10")
#: L2 penalty on the coefficients (not the intercept): a weak prior that keeps
#: a fit on a few hundred trials of nearly equal plans finite
L2 = 1.0
_P_FLOOR = 1e-6


def plan_features(probability, anchors) -> np.ndarray:
    """(N, 2) features of N plans: log of the plan probability (floored at
    1e-6) and the route's anchors over 10."""
    p = np.asarray(probability, np.float64).reshape(-1)
    n = np.asarray(anchors, np.float64).reshape(-1)
    if p.shape != n.shape:
        raise TopodrakeError(f"{p.size} plan probabilities for {n.size} anchor counts")
    if not (np.all(np.isfinite(p)) and np.all(np.isfinite(n))):
        raise TopodrakeError("plan probabilities and anchor counts must be finite")
    return np.stack([np.log(np.clip(p, _P_FLOOR, 1.0)), n / 10.0], axis=1)


def _read_json(path: Path, what: str = ""):
    """A JSON file's contents; a missing or unreadable file is refused in one line."""
    try:
        return json.loads(path.read_text())
    except FileNotFoundError:
        raise TopodrakeError(f"{what}{path} does not exist") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise TopodrakeError(f"{what}{path} is not readable JSON: {e}") from None


def _sigmoid(z: np.ndarray) -> np.ndarray:
    return 0.5 * (1.0 + np.tanh(0.5 * z))


@dataclass
class PlanCalibration:
    """Logistic regression from :func:`plan_features` to success."""

    method: str
    coef: list[float]
    intercept: float
    fitted_on: dict = field(default_factory=dict)    # houses, trials, success rate, source
    features: tuple[str, ...] = FEATURES

    def __post_init__(self):
        if tuple(self.features) != FEATURES:
            raise TopodrakeError(f"plan calibration features {list(self.features)} are not "
                                 f"{list(FEATURES)}")
        coef = [float(c) for c in self.coef]
        if len(coef) != len(FEATURES) or not all(math.isfinite(c) for c in coef + [float(self.intercept)]):
            raise TopodrakeError(f"plan calibration needs {len(FEATURES)} finite coefficients "
                                 f"and a finite intercept, got {self.coef!r}, {self.intercept!r}")
        self.coef, self.intercept, self.features = coef, float(self.intercept), FEATURES

    def predict(self, probability, anchors) -> np.ndarray:
        """Chance of success of plans with these probabilities and anchor counts."""
        x = plan_features(probability, anchors)
        return _sigmoid(x @ np.asarray(self.coef) + self.intercept)

    def save(self, path) -> Path:
        """Write the calibration as JSON (atomically)."""
        d = asdict(self)
        d["features"] = list(FEATURES)
        return atomic_write_json(Path(path), {"format": FORMAT, "version": VERSION, **d})

    @classmethod
    def load(cls, path) -> "PlanCalibration":
        """A calibration file, checked; a bad file is refused in one line."""
        path = Path(path)
        d = _read_json(path, "plan calibration ")
        if not isinstance(d, dict) or d.get("format") != FORMAT:
            raise TopodrakeError(f"{path} is not a plan calibration (format {FORMAT!r})")
        if d.get("version") != VERSION:
            raise TopodrakeError(f"plan calibration {path} has version {d.get('version')!r}; "
                                 f"this topodrake reads {VERSION}")
        try:
            return cls(method=str(d["method"]), coef=list(d["coef"]),
                       intercept=float(d["intercept"]), fitted_on=dict(d.get("fitted_on", {})),
                       features=tuple(d.get("features", ())))
        except (KeyError, TypeError, ValueError) as e:
            raise TopodrakeError(f"plan calibration {path} is malformed: {e}") from None


def fit_plan_calibration(method: str, probability, anchors, success,
                         fitted_on: dict | None = None, iterations: int = 50) -> PlanCalibration:
    """Fit by Newton's method (L2-penalised logistic regression) on planned
    trials: their plan probabilities, anchor counts and outcomes."""
    x = plan_features(probability, anchors)
    y = np.asarray(success, np.float64).reshape(-1)
    if y.shape[0] != x.shape[0]:
        raise TopodrakeError(f"{x.shape[0]} plans for {y.shape[0]} outcomes")
    if x.shape[0] < 20:
        raise TopodrakeError(f"fitting a plan calibration needs at least 20 planned trials, "
                             f"got {x.shape[0]}")
    if y.min() == y.max():
        raise TopodrakeError("fitting a plan calibration needs both successes and failures")
    a = np.concatenate([x, np.ones((len(x), 1))], axis=1)
    w = np.zeros(a.shape[1])
    w[-1] = math.log(y.mean() / (1.0 - y.mean()))
    penalty = np.diag([L2] * x.shape[1] + [0.0])
    for _ in range(iterations):
        q = _sigmoid(a @ w)
        grad = a.T @ (q - y) + penalty @ w
        hess = (a * (q * (1.0 - q))[:, None]).T @ a + penalty
        step = np.linalg.solve(hess + 1e-9 * np.eye(len(w)), grad)
        w -= step
        if np.abs(step).max() < 1e-10:
            break
    info = dict(fitted_on or {})
    info.update(trials=int(len(y)), success_rate=round(float(y.mean()), 4))
    return PlanCalibration(method=method, coef=[float(v) for v in w[:-1]], intercept=float(w[-1]),
                           fitted_on=info)


def calibration_beside(reach_checkpoint) -> PlanCalibration | None:
    """The calibration shipped beside an RE checkpoint, or None."""
    path = Path(str(reach_checkpoint)).parent / FILENAME
    return PlanCalibration.load(path) if path.is_file() else None


def fit_from_records(records: list[dict], method: str, source: str = "",
                     command: str = "") -> PlanCalibration:
    """Fit ``method``'s calibration on a planning study's per-trial records
    (its planned trials). Records of test houses are refused: a calibration
    judged on the test houses must not have seen them."""
    mine = [r for r in records if r.get("method") == method]
    if not mine:
        have = sorted({str(r.get("method")) for r in records})
        raise TopodrakeError(f"no trials of method {method!r} in the records (they hold "
                             f"{', '.join(have) or 'none'})")
    test = sorted({r["house"] for r in mine if str(r.get("house", "")).startswith("test-")})
    if test:
        raise TopodrakeError(f"the records hold test houses ({', '.join(test)}); fit the plan "
                             f"calibration on calibration houses (calib-0..4) or training houses")
    planned = [r for r in mine if r.get("planned")]
    try:
        p = [float(r["plan_probability"]) for r in planned]
        n = [int(r["plan_anchors"]) for r in planned]
        y = [bool(r["success"]) for r in planned]
    except (KeyError, TypeError, ValueError) as e:
        raise TopodrakeError(f"a planned trial of {method!r} lacks {e} (plan_probability, "
                             f"plan_anchors, success)") from None
    houses = sorted({str(r["house"]) for r in mine})
    cal = fit_plan_calibration(method, p, n, y, {"houses": houses, "source": source,
                                                  "command": command})
    cal.fitted_on["ece_raw"] = calibration(p, y)[1]
    cal.fitted_on["ece_fitted"] = calibration(cal.predict(p, n), y)[1]
    return cal


def read_trial_records(files) -> tuple[list[dict], list[str]]:
    """The per-trial records of planning study results (``planning.json``
    files) and each file's command; a file without records, or a trial
    (house, method, map, trial) recorded twice, is refused in one line."""
    records, seen, commands = [], set(), []
    for f in map(Path, files):
        study = _read_json(f)
        if not isinstance(study, dict) or not isinstance(study.get("trials"), list):
            raise TopodrakeError(f"{f} holds no per-trial records ('trials'): give the planning "
                                 f"study's planning.json")
        for r in study["trials"]:
            key = (r.get("house"), r.get("method"), r.get("map", "all"), r.get("trial"))
            if key in seen:
                raise TopodrakeError(f"trial {key} is recorded twice (again in {f})")
            seen.add(key)
            records.append(r)
        commands.append(str(study.get("command", "")))
    return records, commands


def calibration(probability, success, bins: int = 10) -> tuple[list[dict], float | None]:
    """Predicted plan probability against observed success: ``bins`` equal
    bins over [0, 1] (the last one closed), each {lo, hi, count, predicted
    (mean probability), observed (success rate)}, and the expected
    calibration error sum_b n_b / n |predicted_b - observed_b| (None
    without trials). NaN probabilities (SPTM's) are left out."""
    p = np.asarray(probability, np.float64).reshape(-1)
    s = np.asarray(success, np.float64).reshape(-1)
    if len(p) != len(s):
        raise TopodrakeError(f"{len(p)} probabilities for {len(s)} outcomes")
    keep = np.isfinite(p)
    p, s = np.clip(p[keep], 0.0, 1.0), s[keep]
    edges = np.linspace(0.0, 1.0, bins + 1)
    idx = np.minimum((p * bins).astype(np.int64), bins - 1)
    rows, ece = [], 0.0
    for b in range(bins):
        m = idx == b
        c = int(m.sum())
        row = {"lo": round(float(edges[b]), 4), "hi": round(float(edges[b + 1]), 4), "count": c,
               "predicted": round(float(p[m].mean()), 4) if c else None,
               "observed": round(float(s[m].mean()), 4) if c else None}
        if c:
            ece += c * abs(float(p[m].mean()) - float(s[m].mean()))
        rows.append(row)
    return rows, (round(ece / len(p), 4) if len(p) else None)
