"""The A* oracle C_WP with a controlled error: a cheap design bench for route following.

How good must C_WP be for the follower to keep its route? Following the
same RE chains with the exact oracle C_WP plus an error of a chosen kind and
size (and the learned RE: the follower still decides on the controller's
own RE) measures cover against error size without training a network.
A spec names the error, wherever a C_WP checkpoint may be named::

    oracle:KEY=VALUE[:KEY=VALUE...]      plain ``oracle``: the exact oracle

* ``anchor=S``: an error fixed per target, N(0, S m) per world coordinate,
  drawn from a generator seeded by the seed and the target's pose (so the
  same anchor gets the same error on every period, in every route and
  batch): the car aims at a displaced target;
* ``fresh=S``: a new N(0, S m) per car-frame coordinate on every answer;
* ``tail=F``: with probability F per answer the waypoint is rotated about
  the car by 45..180 deg (uniform) to a random side, a heavy tail (the
  learned lidar C_WP answers about one near waypoint in twelve more than
  45 deg off: ``tail=0.08``);
* ``seed=N`` (default 0).

The heading difference and overlaps stay the oracle's (exact). The same
spec and the same calls give the same answers.
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace
from typing import TYPE_CHECKING

import numpy as np

from topodrake.errors import TopodrakeError

if TYPE_CHECKING:
    from topodrake.contract.waypoint import WaypointPrediction

__all__ = ["NoisyOracle", "OracleError", "is_oracle_spec", "parse_oracle_spec"]

PREFIX = "oracle"


@dataclass(frozen=True)
class OracleError:
    """The error of a :class:`NoisyOracle` (see the module docstring)."""

    anchor: float = 0.0
    fresh: float = 0.0
    tail: float = 0.0
    seed: int = 0

    @property
    def text(self) -> str:
        """The canonical spec (keys that differ from the defaults, in order)."""
        return ":".join([PREFIX] + [f"{f.name}={getattr(self, f.name):g}" for f in fields(self)
                                    if getattr(self, f.name) != f.default])

    def with_value(self, key: str, value: str) -> "OracleError":
        """This error with ``key`` set to ``value`` (a spec value, checked)."""
        return replace(self, **{key: _value(key, value)})


def is_oracle_spec(text) -> bool:
    """Whether a C_WP name is an oracle spec rather than a checkpoint path."""
    return isinstance(text, str) and (text == PREFIX or text.startswith(PREFIX + ":"))


def _value(key: str, value: str):
    names = [f.name for f in fields(OracleError)]
    if key not in names:
        raise TopodrakeError(f"oracle spec: unknown key {key!r}; keys are {', '.join(names)}")
    try:
        v = int(value) if key == "seed" else float(value)
    except ValueError:
        raise TopodrakeError(f"oracle spec: {key}={value!r} is not "
                             f"{'an integer' if key == 'seed' else 'a number'}") from None
    if key == "tail" and not 0.0 <= v <= 1.0:
        raise TopodrakeError(f"oracle spec: tail={value} must be a probability in [0, 1]")
    if not (np.isfinite(v) and v >= 0):
        raise TopodrakeError(f"oracle spec: {key}={value} must be finite and >= 0")
    return v


def parse_oracle_spec(text: str) -> OracleError:
    """``oracle:KEY=VALUE[:KEY=VALUE...]`` as an :class:`OracleError`."""
    if not is_oracle_spec(text):
        raise TopodrakeError(f"{text!r} is not an oracle spec (oracle[:KEY=VALUE...])")
    error, seen = OracleError(), set()
    for item in text.split(":")[1:]:
        key, sep, value = item.partition("=")
        if not sep or not key or not value:
            raise TopodrakeError(f"oracle spec: {item!r} in {text!r} is not KEY=VALUE")
        if key in seen:
            raise TopodrakeError(f"oracle spec: key {key!r} given twice in {text!r}")
        seen.add(key)
        error = error.with_value(key, value)
    return error


class NoisyOracle:
    """:class:`~topodrake.learning.waypoint.policy.AStarOracle` in ``world`` plus the
    seeded error ``error`` (an :class:`OracleError` or a spec string).
    ``encode_target`` returns (N, 5): the target pose and its anchor error
    (world frame); ``predict`` also takes bare (N, 3) target poses."""

    observation = "pose"

    def __init__(self, world, error: OracleError | str = "oracle", k: int = 0,
                 frame_step: int = 3, **oracle_kw):
        from topodrake.learning.waypoint.policy import AStarOracle   # not at import: it loads torch

        self.error = parse_oracle_spec(error) if isinstance(error, str) else error
        self.oracle = AStarOracle(world, k=k, frame_step=frame_step, **oracle_kw)
        self.world, self.k, self.frame_step = world, k, frame_step
        self.name = self.error.text
        self.rng = np.random.default_rng([self.error.seed, 1])

    def anchor_error(self, poses: np.ndarray) -> np.ndarray:
        """(N, 2) world-frame error of each target pose (fixed by its pose and the seed)."""
        poses = np.ascontiguousarray(poses, np.float64).reshape(-1, 3)
        if self.error.anchor == 0:
            return np.zeros((len(poses), 2))
        return np.array([np.random.default_rng([self.error.seed, 2, *np.frombuffer(
            p.tobytes(), np.uint32).tolist()]).normal(0.0, self.error.anchor, 2) for p in poses])

    def encode_target(self, context: np.ndarray) -> np.ndarray:
        tgt = self.oracle.encode_target(context)
        return np.column_stack([tgt, self.anchor_error(tgt)])

    def predict(self, observation: np.ndarray, target) -> WaypointPrediction:
        tgt = np.asarray(target, np.float64)
        tgt = tgt.reshape(-1, tgt.shape[-1])
        if tgt.shape[1] == 3:
            tgt = np.column_stack([tgt, self.anchor_error(tgt)])
        pred = self.oracle.predict(observation, tgt[:, :3])
        n = len(pred.waypoint)
        poses = np.broadcast_to(np.asarray(observation, np.float64).reshape(-1, 3), (n, 3))
        pred.waypoint = self.perturb(pred.waypoint, poses[:, 2],
                                     np.broadcast_to(tgt[:, 3:], (n, 2)))
        return pred

    def perturb(self, waypoint: np.ndarray, heading: np.ndarray,
                anchor_error: np.ndarray) -> np.ndarray:
        """Car-frame waypoints (N, 2) of cars at ``heading`` (N,) plus the
        targets' world-frame ``anchor_error`` (N, 2), a fresh error and the
        tail's rotations (drawn from this oracle's generator)."""
        e = self.error
        c, s = np.cos(heading), np.sin(heading)
        ex, ey = np.asarray(anchor_error, np.float64).T
        wp = np.asarray(waypoint, np.float64) + np.column_stack([c * ex + s * ey, -s * ex + c * ey])
        n = len(wp)
        if e.fresh > 0:
            wp = wp + self.rng.normal(0.0, e.fresh, (n, 2))
        if e.tail > 0:
            hit = self.rng.random(n) < e.tail
            turn = np.radians(self.rng.uniform(45.0, 180.0, n)) * self.rng.choice([-1.0, 1.0], n)
            a = np.where(hit, turn, 0.0)
            ca, sa = np.cos(a), np.sin(a)
            wp = np.column_stack([ca * wp[:, 0] - sa * wp[:, 1], sa * wp[:, 0] + ca * wp[:, 1]])
        return wp
