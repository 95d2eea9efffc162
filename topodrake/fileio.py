"""Atomic file writes: a temporary file in the same folder, then a rename."""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path

from topodrake.errors import TopodrakeError


def atomic_write_bytes(path, data: bytes) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    try:
        # mkstemp makes the file private (0600); give it the permissions a
        # plain open() would (0666 minus the umask).
        umask = os.umask(0)
        os.umask(umask)
        os.fchmod(fd, 0o666 & ~umask)
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def atomic_write_json(path, obj) -> Path:
    return atomic_write_bytes(path, (json.dumps(obj, indent=2) + "\n").encode())


def read_manifest(folder, fmt: str, version: int, what: str, keys=()) -> dict:
    """``folder/manifest.json`` of a versioned data folder, checked: a missing,
    unreadable or foreign manifest, another version or a missing key raises
    one :class:`TopodrakeError` line naming the folder."""
    path = Path(folder) / "manifest.json"
    try:
        m = json.loads(path.read_text())
    except FileNotFoundError:
        raise TopodrakeError(f"{folder} is not {what}: no manifest.json") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise TopodrakeError(f"{path} is not valid JSON ({getattr(e, 'msg', e)})") from None
    except OSError as e:
        raise TopodrakeError(f"{path} is unreadable ({type(e).__name__})") from None
    if not isinstance(m, dict) or m.get("format") != fmt:
        raise TopodrakeError(f"{path} is not a {fmt} manifest")
    if m.get("version") != version:
        raise TopodrakeError(f"{path} has format version {m.get('version')}; this topodrake reads {version}")
    for key in keys:
        if key not in m:
            raise TopodrakeError(f"{path} lacks the key {key!r}")
    return m


def file_sha1(path) -> str:
    """SHA-1 of a file's bytes (the identity of a checkpoint)."""
    import hashlib

    h = hashlib.sha1()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def read_tagged_npz(path, fmt: str, version: int, what: str) -> dict:
    """Every array of a ``.npz`` written with ``format = fmt`` and ``version``
    tags (no pickles); a missing, corrupt or other file raises a one-line
    :class:`TopodrakeError` naming ``path`` (``what`` says what it should be)."""
    import numpy as np

    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as z:
            if "format" not in z.files or str(z["format"]) != fmt:
                raise TopodrakeError(f"{path} is not a {fmt} file")
            if int(z["version"]) != version:
                raise TopodrakeError(f"{path} has {what} version {int(z['version'])}; "
                                     f"this topodrake reads {version}")
            return {k: z[k] for k in z.files}
    except TopodrakeError:
        raise
    except FileNotFoundError:
        raise TopodrakeError(f"{what} file {path} does not exist") from None
    except Exception as e:
        raise TopodrakeError(f"{path} is corrupt or not a {what} file ({type(e).__name__})") from None
