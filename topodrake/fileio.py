"""Atomic file writes (a temporary file in the same folder, then a rename),
file hashes, and the integrity checks of the files topodrake reads back.

A checkpoint or map file may have a card beside it (``card.json`` naming
the file under ``"checkpoint"`` or ``"file"``, or ``NAME.card.json``) that
records the file's SHA-256 under ``"sha256"``; :func:`check_intact` refuses a
file whose bytes no longer match it, or a zip archive (a torch checkpoint, a
map) whose entries fail their CRC-32, as damaged.
"""

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


def _file_hash(path, name: str) -> str:
    import hashlib

    h = hashlib.new(name)
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def file_sha1(path) -> str:
    """SHA-1 of a file's bytes (the identity of a checkpoint)."""
    return _file_hash(path, "sha1")


def file_sha256(path) -> str:
    """SHA-256 of a file's bytes (its checksum, as cards record it)."""
    return _file_hash(path, "sha256")


#: the card of a checkpoint or map: ``card.json`` in its folder (naming it), or ``NAME.card.json``
CARD = "card.json"


def card_of(path) -> Path | None:
    """The card that describes file ``path``: ``NAME.card.json`` beside it, or
    ``card.json`` in its folder when that names the file (under
    ``"checkpoint"`` or ``"file"``); None when there is none."""
    path = Path(path)
    own = path.with_name(f"{path.stem}.card.json")
    if own.is_file():
        return own
    shared = path.with_name(CARD)
    if shared.is_file():
        try:
            card = json.loads(shared.read_text())
        except (OSError, ValueError):
            return None
        named = [card.get(key) for key in ("checkpoint", "file")] if isinstance(card, dict) else []
        if any(isinstance(n, str) and Path(n).name == path.name for n in named):
            return shared
    return None


def card_sha256(path) -> tuple[Path, str] | None:
    """``(card, SHA-256 it records)`` for file ``path``; None without a card
    or a recorded checksum."""
    card = card_of(path)
    if card is None:
        return None
    try:
        sha = json.loads(card.read_text()).get("sha256")
    except (OSError, ValueError, AttributeError):
        return None
    return (card, sha) if isinstance(sha, str) else None


def forget_card_sha256(path) -> None:
    """A file is written anew: its card (if any) no longer vouches for its
    bytes, so the card's ``sha256`` is dropped (the writer that makes the
    card records the new one)."""
    found = card_sha256(path)
    if found is None:
        return
    card = json.loads(found[0].read_text())
    card.pop("sha256", None)
    atomic_write_json(found[0], card)


def damaged(what: str, path, why: str) -> TopodrakeError:
    """The one-line error of a damaged file."""
    return TopodrakeError(f"{what} {path} is damaged ({why}); it was not loaded")


def check_card(path, what: str) -> None:
    """Refuse ``path`` as damaged when its bytes' SHA-256 differs from the
    one its card records (:func:`card_sha256`); a file without a card, or a
    card without a checksum, passes."""
    found = card_sha256(path)
    if found is not None:
        card, want = found
        have = file_sha256(path)
        if have != want:
            raise damaged(what, path, f"its SHA-256 {have[:12]}... differs from the "
                                      f"{want[:12]}... its {card.name} records")


def is_zip(path) -> bool:
    """The file starts as a zip archive does."""
    with open(path, "rb") as f:
        return f.read(4) in (b"PK\x03\x04", b"PK\x05\x06")


def check_intact(path, what: str) -> None:
    """Refuse ``path`` as damaged when its card's SHA-256 (:func:`check_card`)
    differs from its bytes', or when it is a zip archive (torch checkpoints,
    maps) that is cut short or whose entries fail their CRC-32. Files that
    are not zip archives pass on to their reader."""
    import zipfile

    path = Path(path)
    check_card(path, what)
    if not is_zip(path):
        return
    try:
        with zipfile.ZipFile(path) as z:
            bad = z.testzip()
    except (zipfile.BadZipFile, EOFError, ValueError, OSError) as e:
        raise damaged(what, path, f"a broken or truncated archive: {e}") from None
    except Exception as e:      # zlib.error and kin: a damaged compressed entry
        raise damaged(what, path, f"{type(e).__name__}: {e}") from None
    if bad is not None:
        raise damaged(what, path, f"entry {bad!r} fails its CRC-32")


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
