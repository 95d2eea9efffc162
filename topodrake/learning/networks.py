"""The waypoint network C_WP (and its direct-control baseline), camera or lidar.

Architecture (the paper's Fig. 2, widths from :class:`NetworkConfig`)::

    for every context frame j of the target (2k + 1 frames, past to future):
        x_j = [o_cur, o_j, o_cur - o_j]                 (9 x S x S  or  3 x beams)
        f_j = Encoder(x_j)                              shared weights, (F,)
    h = ReLU(Conv1d over the 2k + 1 feature vectors)    kernel = 2k + 1 -> (C,)
    heads (MLPs on h): waypoint (x, y) in the car frame, heading difference
    (cos, sin), mutual overlap (2 logits); the direct-control baseline adds
    (acceleration, steering rate) and its waypoint head is ignored.

The encoder starts with one convolution over the stacked input, followed by
ReLU and an optional max-pool, then strided convolutions, then a linear
layer to F features. Because the first convolution is linear in its input,

    W * [c, o, c - o] + b  =  (W_c + W_d) * c  +  ((W_o - W_d) * o + b),

:meth:`WaypointNetwork.encode_target` computes the target half once per
anchor and :meth:`WaypointNetwork.forward_cached` adds the current image's
half (computed once per control step, not once per context frame). The
default profile puts most of the arithmetic into that first layer, so the
cached path is several times cheaper than the naive one; training uses the
same split (:meth:`WaypointNetwork.forward_split`), which is exact.

The default ("lean") profile: 64 x 64 input, first layer 8 x 8 stride 4 with
32 channels and a 2 x 2 max-pool (most of the arithmetic), then 3 x 3
stride-2 convolutions of 64 and 64 channels, BatchNorm after each
convolution (it acts on the summed pre-activation, so the split stays exact,
and :func:`fold_batchnorm` folds it away for inference), F = 128, C = 256.
The pool keeps the layers after the split small: without it (channels
32-32-64, ``first_pool: 1``, the profile of the k = 0 / 2 and lidar
checkpoints) the cached step is only 2.7-3x cheaper than the naive one at
batch 1, with it about 4x, and training is faster too. The paper's widths (64-128-256-512,
5 x 5 stride 2, no normalisation) are ``configs/waypoint_camera_k5_paper.yaml``.

Observations enter as float tensors: camera ``(N, 3, S, S)`` in [-0.5, 0.5]
(see :func:`camera_input`), lidar ``(N, 1, beams)`` in [0, 1] (see
:func:`lidar_input`).
"""

from __future__ import annotations

import functools
import itertools
from dataclasses import asdict, dataclass, field

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

from topodrake.errors import TopodrakeError

MODALITIES = ("camera", "lidar")
#: Head attribute and output key, in output order.
HEADS = (("waypoint", "waypoint"), ("heading", "heading"), ("overlap", "overlap_logits"),
         ("control", "control"), ("reach", "reach_logit"))
OUTPUTS = ("waypoint", "control", "reach")


@dataclass
class NetworkConfig:
    """Everything that fixes a network's shape (stored in every checkpoint)."""

    modality: str = "camera"        # camera | lidar
    output: str = "waypoint"        # waypoint (C_WP) | control (direct-control baseline)
    k: int = 5                      # context frames on each side of the target
    frame_step: int = 3             # Delta T: trajectory frames between context frames
    image_size: int = 64            # camera input side S (larger sensor images are area-downsampled)
    channels: list[int] = field(default_factory=lambda: [32, 64, 64])
    first_kernel: int = 8
    first_stride: int = 4
    first_pool: int = 2             # max-pool after the first convolution (1 = none)
    kernel: int = 3                 # kernel of the later (stride-2) convolutions
    feature_dim: int = 128          # F, per context frame
    combine_channels: int = 256     # C, output of the Conv1d across frames
    hidden: int = 256               # hidden width of each head
    norm: str = "batch"             # BatchNorm after every encoder convolution | "none" (paper)

    def validate(self, where: str = "network config") -> "NetworkConfig":
        if self.modality not in MODALITIES:
            raise TopodrakeError(f"{where}: modality must be one of {MODALITIES}, got {self.modality!r}")
        if self.norm not in ("none", "batch"):
            raise TopodrakeError(f"{where}: norm must be 'none' or 'batch', got {self.norm!r}")
        if self.output not in OUTPUTS:
            raise TopodrakeError(f"{where}: output must be one of {OUTPUTS}, got {self.output!r}")
        if self.k < 0 or self.frame_step < 1:
            raise TopodrakeError(f"{where}: need k >= 0 and frame_step >= 1, got k={self.k}, "
                                 f"frame_step={self.frame_step}")
        if not self.channels or min(self.channels) < 1:
            raise TopodrakeError(f"{where}: channels must be a non-empty list of positive widths")
        for name in ("image_size", "first_kernel", "first_stride", "first_pool", "kernel",
                     "feature_dim", "combine_channels", "hidden"):
            if getattr(self, name) < 1:
                raise TopodrakeError(f"{where}: {name} must be >= 1, got {getattr(self, name)}")
        return self

    @property
    def frames(self) -> int:
        return 2 * self.k + 1

    def to_dict(self) -> dict:
        return asdict(self)


def _conv_out(n: int, kernel: int, stride: int) -> int:
    return (n + 2 * (kernel // 2) - kernel) // stride + 1


def max_pool(x: torch.Tensor, k: int) -> torch.Tensor:
    """Max-pool the spatial axes of ``x`` ((B, C, H, W) or (B, C, L)) by ``k``
    with stride ``k``, dropping a remainder: what ``F.max_pool2d`` /
    ``F.max_pool1d`` compute, to the bit. Without autograd it is the maximum
    of the k^2 (k) strided views, which on this CPU runs 4-5x faster than
    torch's pooling kernel on NCHW maps (on channels-last ones about as
    fast; the pool was a quarter of a labelling rollout's time); in training torch's
    kernel stays, as its backward pass is about 2x faster than the views'."""
    if k == 1:
        return x
    dims = x.dim() - 2
    if x.requires_grad and torch.is_grad_enabled():
        return (F.max_pool2d if dims == 2 else F.max_pool1d)(x, k)
    first, second, *rest = (x[index] for index in _pool_windows(k, tuple(x.shape[2:])))
    out = torch.maximum(first, second)
    for view in rest:
        torch.maximum(out, view, out=out)
    return out


@functools.lru_cache(maxsize=64)
def _pool_windows(k: int, spatial: tuple) -> tuple:
    """The k^d strided-view indices of :func:`max_pool` (cached: building
    them cost more than the pool itself at batch 1)."""
    stop = [n - n % k for n in spatial]
    return tuple((..., *(slice(o, n, k) for o, n in zip(offset, stop)))
                 for offset in itertools.product(range(k), repeat=len(spatial)))


class PairEncoder(nn.Module):
    """Shared encoder of one (current, context frame) pair; 2-D (camera) or 1-D (lidar)."""

    def __init__(self, cfg: NetworkConfig, in_size: int):
        super().__init__()
        two_d = cfg.modality == "camera"
        conv = nn.Conv2d if two_d else nn.Conv1d
        bn = nn.BatchNorm2d if two_d else nn.BatchNorm1d
        norm = cfg.norm == "batch"
        self.sensor_channels = 3 if two_d else 1
        self.pool = cfg.first_pool
        ch = cfg.channels
        self.first = conv(3 * self.sensor_channels, ch[0], cfg.first_kernel,
                          stride=cfg.first_stride, padding=cfg.first_kernel // 2)
        # BatchNorm acts on the summed pre-activation, so the split stays exact
        self.first_norm = bn(ch[0]) if norm else nn.Identity()
        size = _conv_out(in_size, cfg.first_kernel, cfg.first_stride)
        if self.pool > 1:
            size //= self.pool
        rest = []
        for a, b in zip(ch[:-1], ch[1:]):
            rest += [conv(a, b, cfg.kernel, stride=2, padding=cfg.kernel // 2)]
            rest += [bn(b), nn.ReLU()] if norm else [nn.ReLU()]
            size = _conv_out(size, cfg.kernel, 2)
        if size < 1:
            raise TopodrakeError(f"network config: input size {in_size} is too small for "
                                 f"{len(ch)} convolutions")
        self.rest = nn.Sequential(*rest)
        flat = ch[-1] * size ** (2 if two_d else 1)
        self.fc = nn.Linear(flat, cfg.feature_dim)

    # -- the first layer, split into its current and target halves ----------
    def split_weights(self) -> tuple[torch.Tensor, torch.Tensor]:
        """(W_cur, W_tgt): W * [c, o, c - o] = W_cur * c + W_tgt * o."""
        s = self.sensor_channels
        w = self.first.weight
        wc, wo, wd = w[:, :s], w[:, s:2 * s], w[:, 2 * s:]
        return wc + wd, wo - wd

    def first_current(self, cur: torch.Tensor) -> torch.Tensor:
        w_cur, _ = self.split_weights()
        return self._conv_first(cur, w_cur, None)

    def first_target(self, ctx: torch.Tensor) -> torch.Tensor:
        _, w_tgt = self.split_weights()
        return self._conv_first(ctx, w_tgt, self.first.bias)

    def _conv_first(self, x, w, b):
        f = F.conv2d if x.dim() == 4 else F.conv1d
        return f(x, w, b, stride=self.first.stride, padding=self.first.padding)

    def after_first(self, pre: torch.Tensor) -> torch.Tensor:
        """Everything after the first layer's linear part: (B, C0, ...) -> (B, F)."""
        x = self.rest(max_pool(F.relu(self.first_norm(pre)), self.pool))
        return F.relu(self.fc(x.flatten(1)))

    def forward(self, cur: torch.Tensor, other: torch.Tensor) -> torch.Tensor:
        return self.after_first(self.first(torch.cat([cur, other, cur - other], dim=1)))


def _head(cin: int, hidden: int, out: int) -> nn.Sequential:
    return nn.Sequential(nn.Linear(cin, hidden), nn.ReLU(), nn.Linear(hidden, out))


class WaypointNetwork(nn.Module):
    """C_WP: ``forward(cur (N, ...), ctx (N, 2k+1, ...)) -> dict`` of head outputs.

    Outputs: ``waypoint`` (N, 2) metres in the car frame, ``heading`` (N, 2)
    (cos, sin) of target minus current heading, ``overlap_logits`` (N, 2)
    (R_cur->tgt, R_tgt->cur), and for the baseline ``control`` (N, 2) in
    units of :data:`CONTROL_SCALE`. With ``output = "reach"`` (the
    reachability estimator RE) the output is ``reach_logit`` (N, 1), plus
    ``overlap_logits`` (N, 2) of the pair as it starts, an auxiliary head
    that teaches the encoder to tell pairs that see nothing of each other.
    """

    def __init__(self, cfg: NetworkConfig, in_size: int):
        super().__init__()
        self.cfg = cfg.validate()
        self.in_size = int(in_size)
        self.encoder = PairEncoder(cfg, in_size)
        self.combine = nn.Conv1d(cfg.feature_dim, cfg.combine_channels, cfg.frames)
        c, hid = cfg.combine_channels, cfg.hidden
        if cfg.output == "reach":
            # The reachability estimator RE: the same design with one logit
            # (and the auxiliary overlap head).
            self.waypoint = self.heading = self.control = None
            self.overlap = _head(c, hid, 2)
            self.reach = _head(c, hid, 1)
        else:
            self.waypoint = _head(c, hid, 2)
            self.heading = _head(c, hid, 2)
            self.overlap = _head(c, hid, 2)
            self.control = _head(c, hid, 2) if cfg.output == "control" else None
            self.reach = None

    def _heads(self, feats: torch.Tensor, n: int) -> dict:
        # feats: (N * frames, F) ordered frame-major within each sample
        x = feats.view(n, self.cfg.frames, -1).transpose(1, 2)     # (N, F, frames)
        # The Conv1d spans all frames (one output position), so it is a
        # linear map of the flattened (F, frames) block; as a matrix product
        # it skips the convolution's set-up, which dominates at batch 1.
        h = F.relu(F.linear(x.flatten(1), self.combine.weight.flatten(1), self.combine.bias))
        out = {}
        for name, key in HEADS:
            head = getattr(self, name)
            if head is not None:
                out[key] = head(h)
        return out

    def forward(self, cur: torch.Tensor, ctx: torch.Tensor) -> dict:
        """Naive path: the full encoder on all 2k + 1 stacked pairs."""
        n, m = ctx.shape[:2]
        if m != self.cfg.frames:
            raise ValueError(f"expected {self.cfg.frames} context frames, got {m}")
        cur_rep = cur.unsqueeze(1).expand_as(ctx).reshape(n * m, *ctx.shape[2:])
        feats = self.encoder(cur_rep, ctx.reshape(n * m, *ctx.shape[2:]))
        return self._heads(feats, n)

    def forward_split(self, cur: torch.Tensor, ctx: torch.Tensor) -> dict:
        """Same outputs as :meth:`forward`, computing the first layer as two
        3-channel convolutions (the current image once per sample); used for
        training, where it saves most of the first layer's arithmetic."""
        return self.forward_cached(cur, self.encode_target(ctx))

    def encode_target(self, ctx: torch.Tensor) -> torch.Tensor:
        """Target half of the first layer, (N, 2k+1, C0, ...): cache it per anchor."""
        n, m = ctx.shape[:2]
        pre = self.encoder.first_target(ctx.reshape(n * m, *ctx.shape[2:]))
        return pre.view(n, m, *pre.shape[1:])

    def forward_cached(self, cur: torch.Tensor, target: torch.Tensor) -> dict:
        """Fast path: ``target`` (N or 1, 2k+1, ...) from :meth:`encode_target`;
        ``cur`` (N or 1, ...); a batch of one broadcasts against the other."""
        pre_cur = self.encoder.first_current(cur)                  # (N or 1, C0, ...)
        pre = target + pre_cur.unsqueeze(1)                        # broadcast over N
        n, m = pre.shape[:2]
        return self._heads(self.encoder.after_first(pre.reshape(n * m, *pre.shape[2:])), n)


def fold_batchnorm(model: WaypointNetwork) -> WaypointNetwork:
    """An equivalent inference-only copy without BatchNorm layers.

    In eval mode a BatchNorm is a per-channel affine map, so it folds into the
    convolution before it (``norm = "none"`` in the copy's config); the first
    layer's split into current and target halves stays exact. Models
    without BatchNorm are returned unchanged.
    """
    if model.cfg.norm != "batch":
        return model
    cfg = NetworkConfig(**{**model.cfg.to_dict(), "norm": "none"})
    out = WaypointNetwork(cfg, model.in_size)
    out.load_state_dict({k: v for k, v in model.state_dict().items()
                         if not k.startswith("encoder.")}, strict=False)

    def fold(conv, bn, into):
        scale = bn.weight / torch.sqrt(bn.running_var + bn.eps)
        shape = (-1,) + (1,) * (conv.weight.dim() - 1)
        with torch.no_grad():
            into.weight.copy_(conv.weight * scale.view(shape))
            into.bias.copy_((conv.bias - bn.running_mean) * scale + bn.bias)

    src, dst = model.encoder, out.encoder
    fold(src.first, src.first_norm, dst.first)
    convs = [m for m in src.rest if isinstance(m, (nn.Conv1d, nn.Conv2d))]
    norms = [m for m in src.rest if isinstance(m, (nn.BatchNorm1d, nn.BatchNorm2d))]
    for c, b, d in zip(convs, norms, [m for m in dst.rest if isinstance(m, (nn.Conv1d, nn.Conv2d))]):
        fold(c, b, d)
    dst.fc.load_state_dict(src.fc.state_dict())
    return out.eval()


#: The direct-control head predicts controls divided by these (accel m/s^2, steer rate rad/s).
CONTROL_SCALE = np.array([0.5, 3.2], np.float32)


def input_size(cfg: NetworkConfig, lidar_beams: int) -> int:
    """Spatial size the encoder sees: image side (camera) or beam count (lidar)."""
    return cfg.image_size if cfg.modality == "camera" else int(lidar_beams)


def camera_input(images: np.ndarray, size: int) -> torch.Tensor:
    """uint8 images (..., H, W, 3) -> float (..., 3, size, size) in [-0.5, 0.5].

    Images larger than ``size`` by an integer factor are area-averaged down
    (the sensor keeps the paper's 64 x 64; the network may see 32 x 32).
    """
    x = torch.from_numpy(np.ascontiguousarray(images))
    lead = x.shape[:-3]
    h, w = x.shape[-3:-1]
    if h % size or w % size:
        raise TopodrakeError(f"camera images of {h}x{w} cannot be reduced to the network's "
                             f"{size}x{size} input (needs an integer factor)")
    x = x.reshape(-1, h, w, 3).permute(0, 3, 1, 2).float()
    if h != size or w != size:
        x = F.avg_pool2d(x, (h // size, w // size))
    x = x * (1.0 / 255.0) - 0.5
    return x.reshape(*lead, 3, size, size)


def lidar_unit_ranges(ranges: np.ndarray, range_m: float) -> np.ndarray:
    """Ranges (..., beams) (inf = no hit) -> float32 (..., beams) in [0, 1]."""
    r = np.asarray(ranges, np.float32)
    return np.where(np.isfinite(r), np.minimum(r, range_m), range_m) / np.float32(range_m)


def lidar_input(ranges: np.ndarray, range_m: float) -> torch.Tensor:
    """Ranges (..., beams) (inf = no hit) -> float (..., 1, beams) in [0, 1]."""
    r = lidar_unit_ranges(ranges, range_m)
    return torch.from_numpy(np.ascontiguousarray(r, np.float32)).unsqueeze(-2)


def mirrored(x: torch.Tensor) -> torch.Tensor:
    """Network inputs seen in a mirror: camera images flipped left-right,
    lidar beams (spread symmetrically about the heading) reversed; both are
    the last axis."""
    return x.flip(-1)


def count_parameters(model: nn.Module) -> int:
    return int(sum(p.numel() for p in model.parameters()))
