"""A lean inference path of a trained waypoint network (no autograd, no modules).

At batch 1 (one car in the Drake diagram) the network's arithmetic is small
and the fixed cost of calling some twenty ``nn.Module`` objects, allocating
every activation and converting between layouts is a large share of a
control step. :class:`InferencePlan` holds the weights of an inference copy
of :class:`~topodrake.learning.networks.WaypointNetwork` (BatchNorm already
folded, first-layer split frozen) as plain tensors and runs the same
operations as functional calls with in-place activations. It serves both the
naive path (full network on the stacked pairs) and the cached path (target
half of the first layer precomputed), so the two stay comparable, and it
gives the module's outputs to float rounding (``tests/test_learning.py``).
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

from topodrake.errors import TopodrakeError
from topodrake.learning.networks import HEADS, camera_input, fold_batchnorm, lidar_input, max_pool
from topodrake.sensing.observe import observe


class InferencePlan:
    """Plain-tensor forward passes of an eval-mode, BatchNorm-free network."""

    #: Samples per pass of a large batch. The summed first-layer maps of a
    #: pass (samples x 2k+1 frames) are memory-bound beyond the caches: at
    #: 32 camera samples (3.6 MB) a pass runs 2-2.5x faster per sample than
    #: at 512 (here, one or two threads).
    chunk: int = 32

    def __init__(self, model):
        if model.cfg.norm != "none":
            raise ValueError("InferencePlan needs a network without BatchNorm "
                             "(fold it first: networks.fold_batchnorm)")
        enc = model.encoder
        self.frames = model.cfg.frames
        self.two_d = isinstance(enc.first, nn.Conv2d)
        self.conv = F.conv2d if self.two_d else F.conv1d
        self.pool = enc.pool
        self._buffer = None
        with torch.no_grad():
            w_cur, w_tgt = (w.detach().clone().contiguous() for w in enc.split_weights())
            self.w_cur, self.w_tgt = w_cur, w_tgt
            self.w_full = enc.first.weight.detach().clone()
            self.b_first = enc.first.bias.detach().clone()
            self.first_args = (enc.first.stride, enc.first.padding)
            self.rest = [(m.weight.detach().clone(), m.bias.detach().clone(), m.stride, m.padding)
                         for m in enc.rest if isinstance(m, (nn.Conv1d, nn.Conv2d))]
            self.fc = (enc.fc.weight.detach().clone(), enc.fc.bias.detach().clone())
            self.combine = (model.combine.weight.detach().flatten(1).clone(),
                            model.combine.bias.detach().clone())
            # The heads' hidden layers stacked into one matrix product, their
            # output layers into one block-diagonal one (exact; fewer calls).
            present = [(name, key) for name, key in HEADS if getattr(model, name) is not None]
            heads = [getattr(model, name) for name, _ in present]
            self.head_names = [key for _, key in present]
            self.head_hidden = (torch.cat([h[0].weight for h in heads]).detach().clone(),
                                torch.cat([h[0].bias for h in heads]).detach().clone())
            self.head_out = (torch.block_diag(*[h[2].weight for h in heads]).detach().clone(),
                             torch.cat([h[2].bias for h in heads]).detach().clone())
            self.head_sizes = [h[2].out_features for h in heads]

    def _scratch(self, shape) -> torch.Tensor:
        """A reused buffer for the summed first layer of a cached step, laid
        out channels-last for 2-D maps (a few MB at :attr:`chunk` samples,
        which a fresh allocation would map from the kernel page by page at
        every step). Channels-last because the pool (2-3x) and the next
        convolution (up to 1.7x) run faster on it than on NCHW maps here;
        target features in another layout are converted by the add.
        Everything computed from it is a new tensor, so reusing it is safe."""
        numel = math.prod(shape)
        if self._buffer is None or self._buffer.numel() < numel:
            self._buffer = torch.empty(numel)
        flat = self._buffer[:numel]
        if not self.two_d:
            return flat.view(shape)
        *lead, c, h, w = shape
        d = len(lead)
        return flat.view(*lead, h, w, c).permute(*range(d), d + 2, d, d + 1)

    # -- pieces -------------------------------------------------------------------
    def first_current(self, cur: torch.Tensor) -> torch.Tensor:
        stride, padding = self.first_args
        return self.conv(cur, self.w_cur, None, stride=stride, padding=padding)

    def first_target(self, ctx: torch.Tensor) -> torch.Tensor:
        stride, padding = self.first_args
        return self.conv(ctx, self.w_tgt, self.b_first, stride=stride, padding=padding)

    def after_first(self, pre: torch.Tensor) -> torch.Tensor:
        # pooling first: ReLU and max commute, so the ReLU runs on the smaller maps
        x = max_pool(pre, self.pool).relu_()
        for w, b, stride, padding in self.rest:
            x = self.conv(x, w, b, stride=stride, padding=padding).relu_()
        return F.linear(x.flatten(1), *self.fc).relu_()

    def heads_of(self, feats: torch.Tensor, n: int) -> dict:
        x = feats.view(n, self.frames, -1).transpose(1, 2).flatten(1)
        h = F.linear(x, *self.combine).relu_()
        y = F.linear(F.linear(h, *self.head_hidden).relu_(), *self.head_out)
        return dict(zip(self.head_names, torch.split(y, self.head_sizes, dim=1)))

    # -- whole passes -------------------------------------------------------------
    def encode_target(self, ctx: torch.Tensor) -> torch.Tensor:
        """(N, 2k+1, C, ...) -> target half of the first layer (N, 2k+1, C0, ...)."""
        n, m = ctx.shape[:2]
        pre = self.first_target(ctx.reshape(n * m, *ctx.shape[2:]))
        return pre.view(n, m, *pre.shape[1:])

    def cached(self, cur: torch.Tensor, target: torch.Tensor) -> dict:
        """``cur`` (N or 1, C, ...), ``target`` (N or 1, 2k+1, C0, ...)."""
        return {k: v[:, 0] for k, v in self.cached_views([cur], target).items()}

    def cached_views(self, views: list, target: torch.Tensor) -> dict:
        """V views of the current observations in one pass: view v (each
        (N or 1, C, ...)) against frames ``v (2k+1) : (v+1) (2k+1)`` of
        ``target`` (N or 1, V (2k+1), C0, ...); outputs (N, V, ...). One
        pass instead of V: at the batch of one car a pass costs mostly its
        fixed overhead (RE's mirror average asks two views). Large batches
        run in chunks of :attr:`chunk` samples."""
        v, b, f = len(views), len(views[0]), self.frames
        n = max(len(target), b)
        if n > self.chunk:
            parts = [self.cached_views([x if b == 1 else x[lo:lo + self.chunk] for x in views],
                                       target if len(target) == 1 else target[lo:lo + self.chunk])
                     for lo in range(0, n, self.chunk)]
            return {k: torch.cat([p[k] for p in parts]) for k in parts[0]}
        term = self.first_current(torch.cat(views) if v > 1 else views[0])   # (V B, C0, ...)
        term = term.view(v, b, 1, *term.shape[1:]).transpose(0, 1)          # (B, V, 1, C0, ...)
        tgt = target.view(len(target), v, f, *target.shape[2:])
        pre = torch.add(tgt, term, out=self._scratch((n, v, f, *target.shape[2:])))
        out = self.heads_of(self.after_first(pre.view(n * v * f, *target.shape[2:])), n * v)
        return {k: x.view(n, v, *x.shape[1:]) for k, x in out.items()}

    def naive(self, cur: torch.Tensor, ctx: torch.Tensor) -> dict:
        """The full first layer on every stacked [cur, frame, cur - frame]."""
        n, m = ctx.shape[:2]
        frames = ctx.reshape(n * m, *ctx.shape[2:])
        cur_rep = cur.unsqueeze(1).expand(n, m, *cur.shape[1:]).reshape(n * m, *cur.shape[1:])
        stride, padding = self.first_args
        pre = self.conv(torch.cat([cur_rep, frames, cur_rep - frames], dim=1), self.w_full,
                        self.b_first, stride=stride, padding=padding)
        return self.heads_of(self.after_first(pre), n)


class ObservationNetwork:
    """A trained network behind raw observations: the base of the C_WP policy
    and of the reachability estimator.

    Holds an inference copy of the model (BatchNorm folded) and its
    :class:`InferencePlan`; converts raw observations (camera uint8 images
    (..., H, W, 3) or lidar ranges (..., beams)) to network inputs, and
    encodes targets: ``encode_target(context (N, 2k+1, ...))`` returns the
    target half of the first layer (N, 2k+1, C0, ...), computed once per
    target and reused while it stays the same."""
    def __init__(self, model, sensor, name: str = ""):
        self.model = fold_batchnorm(model.eval())   # BatchNorm folded into the convolutions
        # Inference runs on a frozen copy of the weights (training the model
        # further does not change this object).
        self.plan = InferencePlan(self.model)
        self.cfg = model.cfg
        self.sensor = sensor
        self.name = name
        self.observation = self.cfg.modality
        self.k = self.cfg.k
        self.frame_step = self.cfg.frame_step

    def to_input(self, raw: np.ndarray) -> torch.Tensor:
        """Raw observations (..., H, W, 3) uint8 / (..., beams) -> network tensors."""
        if self.observation == "camera":
            return camera_input(raw, self.cfg.image_size)
        return lidar_input(raw, self.sensor.range_m)

    def observe(self, world, poses: np.ndarray) -> np.ndarray:
        """This network's raw observations (its sensor) at ``poses`` (N, 3) in ``world``."""
        return observe(world, self.observation, poses, self.sensor)

    @torch.inference_mode()
    def encode_target(self, context: np.ndarray) -> torch.Tensor:
        x = self.to_input(np.asarray(context))
        if x.shape[1] != self.cfg.frames:
            raise TopodrakeError(f"target context has {x.shape[1]} frames; this network needs "
                                 f"{self.cfg.frames}")
        return self.plan.encode_target(x)
