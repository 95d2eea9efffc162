"""Small tagged torch checkpoints: a format name and version beside the weights.

The place embedding and the SPTM retrieval network store ``{"format",
"version", "network", "sensor", **meta, "model"}`` with ``torch.save``;
:func:`load_tagged` reads one back with ``weights_only=True`` and refuses a
missing, corrupt, damaged or foreign file, or another version, in one line
naming the file. The blob carries the checksum of its payload
(:mod:`~topodrake.learning.sealed`), and a card beside it may record the
file's SHA-256 (:func:`~topodrake.fileio.check_intact`).
"""

from __future__ import annotations

import hashlib
import io
from dataclasses import asdict
from pathlib import Path
from typing import Callable

import torch

from topodrake.errors import TopodrakeError
from topodrake.fileio import atomic_write_bytes, check_intact, forget_card_sha256
from topodrake.learning.sealed import check_seal, seal


def save_tagged(path, fmt: str, version: int, model, sensor, **meta) -> Path:
    """Write ``model`` (with a dataclass ``cfg``) and ``sensor`` atomically."""
    blob = {"format": fmt, "version": version, "network": asdict(model.cfg),
            "sensor": asdict(sensor), **meta, "model": model.state_dict()}
    buf = io.BytesIO()
    torch.save(seal(blob), buf)
    forget_card_sha256(path)
    return atomic_write_bytes(path, buf.getvalue())


def load_tagged(path, fmt: str, version: int, what: str, build: Callable[[dict], object]):
    """``(build(blob), sha1 of the file)`` for a checkpoint of ``fmt`` and
    ``version``; ``what`` names it in errors ("place embedding checkpoint")."""
    path = Path(path)
    if not path.is_file():
        raise TopodrakeError(f"{what} {path} does not exist")
    check_intact(path, what)
    data = path.read_bytes()
    try:
        blob = torch.load(io.BytesIO(data), map_location="cpu", weights_only=True)
    except Exception as e:
        raise TopodrakeError(f"{what} {path} is corrupt or not a torch file "
                             f"({type(e).__name__})") from None
    if not isinstance(blob, dict) or blob.get("format") != fmt:
        raise TopodrakeError(f"{path} is not a {fmt} checkpoint")
    check_seal(blob, path, what)
    if blob.get("version") != version:
        raise TopodrakeError(f"{what} {path} has format version {blob.get('version')}; "
                             f"this topodrake reads {version}")
    try:
        built = build(blob)
    except TopodrakeError:
        raise
    except Exception as e:
        first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise TopodrakeError(f"{what} {path} is unreadable ({first})") from None
    return built, hashlib.sha1(data).hexdigest()
