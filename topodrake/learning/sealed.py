"""The checksum a torch checkpoint carries of its own payload.

:func:`seal` adds ``payload_sha256`` to a blob before ``torch.save``: the
SHA-256 of everything else in it (every tensor's dtype, shape and bytes,
every name, number and string, in a fixed order). :func:`check_seal`
recomputes it after ``torch.load`` and refuses a blob whose payload no
longer matches as damaged. Blobs written before the seal existed carry none
and are checked by their card and their archive's CRC-32 only
(:func:`topodrake.fileio.check_intact`).
"""

from __future__ import annotations

import hashlib

import torch

from topodrake.fileio import damaged

#: the key of the seal in a checkpoint's blob
SEAL = "payload_sha256"


def _feed(h, obj) -> None:
    if isinstance(obj, torch.Tensor):
        t = obj.detach().cpu().contiguous()
        h.update(f"T{t.dtype}{tuple(t.shape)}".encode())
        h.update(t.reshape(-1).view(torch.uint8).numpy().tobytes())
    elif isinstance(obj, dict):
        h.update(f"D{len(obj)}".encode())
        for key in sorted(obj, key=lambda k: (type(k).__name__, repr(k))):
            _feed(h, key)
            _feed(h, obj[key])
    elif isinstance(obj, (list, tuple)):
        h.update(f"L{len(obj)}".encode())
        for item in obj:
            _feed(h, item)
    elif isinstance(obj, str):
        data = obj.encode()
        h.update(f"S{len(data)}:".encode())
        h.update(data)
    elif isinstance(obj, bytes):
        h.update(f"B{len(obj)}:".encode())
        h.update(obj)
    else:                           # numbers, bools, None, dtypes: their exact repr
        text = f"{type(obj).__name__}:{obj!r}".encode()
        h.update(f"V{len(text)}:".encode())
        h.update(text)


def payload_sha256(blob: dict) -> str:
    """SHA-256 of a checkpoint blob's payload (all of it but the seal)."""
    h = hashlib.sha256()
    _feed(h, {k: v for k, v in blob.items() if k != SEAL})
    return h.hexdigest()


def seal(blob: dict) -> dict:
    """``blob`` with its payload's checksum under :data:`SEAL`."""
    return {**blob, SEAL: payload_sha256(blob)}


def check_seal(blob: dict, path, what: str) -> None:
    """Refuse a loaded blob whose payload differs from its seal (a blob
    without a seal passes)."""
    want = blob.get(SEAL)
    if want is None:
        return
    have = payload_sha256(blob)
    if have != want:
        raise damaged(what, path, f"its payload's SHA-256 {have[:12]}... differs from the "
                                  f"{str(want)[:12]}... it was saved with")
