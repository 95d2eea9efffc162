"""The reachability estimator RE at inference time, single pairs and all pairs.

``Reachability.probability(observation, target_features)`` is what the Drake
system and the follower ask ("can my controller get from here to that
anchor?"); the target side is cached exactly as for C_WP.

Map building asks RE about many pairs of frames of the same trajectories,
and every context overlaps its neighbours. :meth:`Reachability.frame_features`
therefore computes the first layer's two halves once per image (the current
half ``W_c * o`` and the target half ``W_t * o + b``), and
:meth:`Reachability.pairwise` adds them for any list of (source frame,
context frames) without touching an image again. :meth:`sparsify` runs the
greedy anchor selection of :mod:`topodrake.learning.reachability.sparsify` on top of it.

An RE calibrated with ``mirror_average`` (see
:mod:`topodrake.learning.reachability.train`) answers with the mean of the pair's
logit and of its mirror image's (both views flipped left-right), which
ranks pairs better than either alone; every path here (single pairs,
cached targets, all pairs) does the same, at twice the cost.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from topodrake.contract.frames import context_frames
from topodrake.errors import TopodrakeError
from topodrake.learning.inference import ObservationNetwork
from topodrake.learning.networks import mirrored
from topodrake.learning.onpolicy.platt import load_follower_platt
from topodrake.learning.reachability.controllers import checkpoint_temperature, load_reachability
from topodrake.learning.reachability.sparsify import sparsify


@dataclass
class FrameFeatures:
    """First-layer halves of T images: ``current`` (T, C0, ...) and
    ``target`` (T, C0, ...); ``mirrored``: the same of the mirrored images
    (for an RE with ``mirror_average``)."""

    current: torch.Tensor
    target: torch.Tensor
    mirrored: "FrameFeatures | None" = None

    def __len__(self) -> int:
        return len(self.current)


class Reachability(ObservationNetwork):
    """Probabilities from a trained RE (``network.output = "reach"``).

    ``temperature`` divides the logit (temperature scaling, fitted on
    validation rollouts; 1 = as trained). Queries between frames of one
    drive (:meth:`sparsify`, :meth:`pairwise`) use ``anchor_platt`` (a, b)
    instead, ``sigmoid(a * logit + b)`` fitted on rollouts of such hops:
    calibration holds for the pairs it was fitted on, and these hops
    succeed far more often than the average pair (default: the temperature,
    ``(1 / T, 0)``). ``follower_platt`` (a, b), when given, is the
    calibration of the follower's own queries (fitted on rollouts from the
    states the follower visits: :mod:`topodrake.learning.onpolicy.calibration`;
    :func:`topodrake.navigation.evaluate.route_calibrated` prefers it to
    ``anchor_platt``). ``mirror_average``: the logit is the mean of the pair's
    and its mirror image's (what the calibrations were fitted on)."""

    def __init__(self, model, sensor, name: str = "", controller: dict | None = None,
                 temperature: float = 1.0, anchor_platt: tuple[float, float] | None = None,
                 mirror_average: bool = False,
                 follower_platt: tuple[float, float] | None = None):
        if model.cfg.output != "reach":
            raise ValueError("Reachability needs a network with output 'reach'")
        super().__init__(model, sensor, name)
        self.controller = controller or {}
        self.temperature = float(temperature)
        a, b = (1.0 / self.temperature, 0.0) if anchor_platt is None else anchor_platt
        self.anchor_platt = (float(a), float(b))
        self.follower_platt = None if follower_platt is None else \
            (float(follower_platt[0]), float(follower_platt[1]))
        self.mirror_average = bool(mirror_average)

    @classmethod
    def from_checkpoint(cls, path, controller_checkpoint, temperature: float | None = None,
                        anchor_platt: tuple[float, float] | None = None) -> "Reachability":
        """Load an RE, refusing one trained for another controller. The
        calibrations default to the ones fitted after training (T = 1 if
        none; anchor hops fall back to the temperature), and the follower's
        to a ``follower_calibration.json`` beside the checkpoint made for
        this file (:func:`~topodrake.learning.onpolicy.platt.load_follower_platt`)."""
        ck = load_reachability(path, controller_checkpoint)
        t = checkpoint_temperature(ck.meta) if temperature is None else temperature
        extra = ck.meta.get("extra") or {}
        if anchor_platt is None and "anchor_platt" in extra:
            anchor_platt = tuple(extra["anchor_platt"])
        return cls(ck.model, ck.sensor, name=Path(path).parent.name,
                   controller=extra.get("controller"), temperature=t, anchor_platt=anchor_platt,
                   mirror_average=bool(extra.get("mirror_average", False)),
                   follower_platt=load_follower_platt(path))

    def _prob(self, z: torch.Tensor, platt: tuple[float, float] | None = None) -> np.ndarray:
        z = z / self.temperature if platt is None else platt[0] * z + platt[1]
        return torch.sigmoid(z).numpy().astype(np.float64)

    def _mean_logit(self, logit, plain: tuple, mirror) -> torch.Tensor:
        """``logit(*plain)``, or with ``mirror_average`` its mean with
        ``logit(*mirror())`` (the same pairs seen in a mirror)."""
        z = logit(*plain)
        return 0.5 * (z + logit(*mirror())) if self.mirror_average else z

    @torch.inference_mode()
    def encode_target(self, context: np.ndarray) -> torch.Tensor:
        """Target features (N, 2k+1, C0, ...); with ``mirror_average`` the
        mirrored context's follow on the same axis (N, 2 (2k+1), C0, ...)."""
        plain = super().encode_target(context)
        if not self.mirror_average:
            return plain
        flipped = self.plan.encode_target(mirrored(self.to_input(np.asarray(context))))
        return torch.cat([plain, flipped], dim=1)

    @torch.inference_mode()
    def probability(self, observation: np.ndarray, target) -> np.ndarray:
        """(N,) for current observations (N or 1, ...) and target features
        (N or 1, ...) from :meth:`encode_target`."""
        return self._prob(torch.as_tensor(self.logit(observation, target)))

    @torch.inference_mode()
    def logit(self, observation: np.ndarray, target) -> np.ndarray:
        """(N,) the uncalibrated logit behind :meth:`probability` (mean of the
        pair's and its mirror image's with ``mirror_average``)."""
        cur = self.to_input(np.asarray(observation))
        target = torch.as_tensor(target)
        want = self.cfg.frames * (2 if self.mirror_average else 1)
        if target.shape[1] != want:
            raise TopodrakeError(f"target features have {target.shape[1]} frames, this RE needs "
                                 f"{want}: encode targets with this RE's encode_target")
        views = [cur, mirrored(cur)] if self.mirror_average else [cur]
        z = self.plan.cached_views(views, target)["reach_logit"][..., 0]      # (N, views)
        return (0.5 * (z[:, 0] + z[:, 1]) if self.mirror_average else z[:, 0]).numpy()

    @torch.inference_mode()
    def probability_naive(self, observation: np.ndarray, context: np.ndarray) -> np.ndarray:
        """The full network on the stacked pairs (for tests and benchmarks)."""
        cur = self.to_input(np.asarray(observation))
        ctx = self.to_input(np.asarray(context))
        if cur.shape[0] == 1 and ctx.shape[0] > 1:
            cur = cur.expand(ctx.shape[0], *cur.shape[1:])
        return self._prob(self._mean_logit(lambda c, x: self.plan.naive(c, x)["reach_logit"][:, 0],
                                           (cur, ctx), lambda: (mirrored(cur), mirrored(ctx))))

    # -- all pairs -------------------------------------------------------------
    @torch.inference_mode()
    def frame_features(self, observations: np.ndarray, batch: int = 256) -> FrameFeatures:
        """Both first-layer halves of every image (T, ...), once (and of
        its mirror image with ``mirror_average``)."""
        views = (lambda x: x, mirrored) if self.mirror_average else (lambda x: x,)
        halves = [([], []) for _ in views]
        for lo in range(0, len(observations), batch):
            x = self.to_input(np.asarray(observations[lo:lo + batch]))
            for view, (cur, tgt) in zip(views, halves):
                cur.append(self.plan.first_current(view(x)))
                tgt.append(self.plan.first_target(view(x)))
        feats = [FrameFeatures(torch.cat(cur), torch.cat(tgt)) for cur, tgt in halves]
        return FrameFeatures(feats[0].current, feats[0].target,
                             feats[1] if self.mirror_average else None)

    def _pair_logits(self, feats: FrameFeatures, s: torch.Tensor, r: torch.Tensor) -> torch.Tensor:
        pre = feats.target[r] + feats.current[s].unsqueeze(1)
        n, m = pre.shape[:2]
        return self.plan.heads_of(self.plan.after_first(pre.reshape(n * m, *pre.shape[2:])),
                                  n)["reach_logit"][:, 0]

    @torch.inference_mode()
    def pairwise(self, feats: FrameFeatures, source: np.ndarray, context_rows: np.ndarray,
                 batch: int = 32, platt: tuple[float, float] | None = None) -> np.ndarray:
        """RE(frame ``source[m]``, context frames ``context_rows[m]``) (M,),
        frames of one drive (so with the anchor calibration, or ``platt``)."""
        source = np.asarray(source, np.int64)
        rows = np.asarray(context_rows, np.int64).reshape(len(source), -1)
        if rows.shape[1] != self.cfg.frames:
            raise ValueError(f"context rows need {self.cfg.frames} frames, got {rows.shape[1]}")
        if self.mirror_average and feats.mirrored is None:
            raise TopodrakeError("these frame features lack the mirror images this RE averages "
                                 "over; make them with its frame_features")
        out = np.empty(len(source))
        for lo in range(0, len(source), batch):
            s = torch.from_numpy(source[lo:lo + batch])
            r = torch.from_numpy(rows[lo:lo + batch])
            z = self._mean_logit(self._pair_logits, (feats, s, r), lambda: (feats.mirrored, s, r))
            out[lo:lo + batch] = self._prob(z, platt or self.anchor_platt)
        return out

    def context_rows(self, n_frames: int, targets: np.ndarray) -> np.ndarray:
        """(M, 2k+1) clamped context frames of target frames ``targets`` of one trajectory."""
        return context_frames(n_frames, np.asarray(targets, np.int64), self.k, self.frame_step)

    def sparsify(self, observations: np.ndarray, p: float = 0.99, window: int = 4,
                 feats: FrameFeatures | None = None,
                 platt: tuple[float, float] | None = None, slack: float = 0.0) -> np.ndarray:
        """Anchor frames of one trajectory's observations (T, ...) (with
        the anchor calibration, or ``platt``; ``slack``: see
        :func:`topodrake.learning.reachability.sparsify.sparsify`)."""
        feats = feats or self.frame_features(observations)
        n = len(feats)
        return sparsify(n, lambda i, js: self.pairwise(feats, np.full(len(js), i),
                                                       self.context_rows(n, js), platt=platt),
                        p, window, slack=slack)


def parse_estimators(text: str) -> dict:
    """``name=re.pt:cwp.pt,...`` -> {name: (re path, controller path)}."""
    out = {}
    for item in filter(None, (s.strip() for s in text.split(","))):
        try:
            name, paths = item.split("=", 1)
            reach, controller = paths.split(":", 1)
        except ValueError:
            raise TopodrakeError(f"--estimators entry {item!r} is not name=RE.pt:CWP.pt") from None
        for path in (reach, controller):
            if not Path(path).is_file():
                raise TopodrakeError(f"{name}: checkpoint {path} does not exist")
        out[name] = (reach, controller)
    if not out:
        raise TopodrakeError("no estimators given")
    return out
