"""The files and folders a command writes, checked before its work starts.

:func:`check_output` refuses, in one :class:`~topodrake.errors.TopodrakeError`
line, a target whose format is unknown, a folder where a file is expected,
a parent that is a file or cannot be made or written, and (unless
``force``) an existing file of another kind, or an existing map, plot or
recording at all. :func:`check_output_folder` does the same for a folder a
command fills. :func:`lock_output` takes the lock of an output (a
``filelock`` lock on ``.NAME.lock`` beside it, :func:`lock_path`) for the
rest of the command, so that a second writer of the same output is refused
while the first runs. :func:`write_kept` writes a finished result and, when
that fails, keeps it elsewhere and says where.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

from topodrake.errors import TopodrakeError

#: kind -> {suffix: what such a file holds (as :func:`sniff` names it)}
KINDS = {
    "image": {".png": "png", ".pdf": "pdf", ".svg": "svg", ".jpg": "jpeg", ".jpeg": "jpeg"},
    "map": {".tdmap": "zip"},
    "html": {".html": "html", ".htm": "html"},
    "npz": {".npz": "zip"},
    "json": {".json": "json"},
    "graphml": {".graphml": "graphml"},
    "mcap": {".mcap": "mcap"},
}
#: kinds whose existing files are never replaced without --force: maps, plots, recordings
KEPT = ("map", "image", "html", "graphml", "mcap")
_DESCRIBE = {"png": "a PNG image", "pdf": "a PDF", "svg": "an SVG image", "jpeg": "a JPEG image",
             "zip": "a zip archive (a map or NumPy file)", "html": "an HTML page",
             "json": "JSON", "graphml": "a GraphML graph", "mcap": "an MCAP recording",
             None: "data of an unknown kind"}


def sniff(path) -> str | None:
    """What an existing file holds, from its first bytes (None: unknown)."""
    with open(path, "rb") as f:
        head = f.read(512)
    text = head.lstrip().lower()
    for magic, kind in ((b"\x89PNG", "png"), (b"%PDF", "pdf"), (b"\xff\xd8\xff", "jpeg"),
                        (b"PK\x03\x04", "zip"), (b"PK\x05\x06", "zip"),
                        (b"\x89MCAP0\r\n", "mcap")):
        if head.startswith(magic):
            return kind
    if text.startswith((b"<!doctype html", b"<html")):
        return "html"
    if text.startswith(b"<?xml") and b"<graphml" in text:
        return "graphml"
    if text.startswith((b"<?xml", b"<svg")):
        return "svg"
    if text.startswith((b"{", b"[")):
        return "json"
    return None


def _reason(e: OSError) -> str:
    import errno

    if e.errno == errno.ENOENT:
        return "it accepts no new files"
    return e.strerror or type(e).__name__


def check_folder(folder, option: str = "--out") -> Path:
    """``folder`` can be written, or made and then written: its nearest
    existing ancestor is a folder where this process may create entries."""
    folder = Path(folder)
    probe = folder
    try:
        while not probe.exists() and probe != probe.parent:
            probe = probe.parent
        if not probe.is_dir():
            raise TopodrakeError(f"{option}: {probe} is a file, not a folder")
        if probe == folder:
            fd, tmp = tempfile.mkstemp(prefix=".topodrake-probe-", dir=probe)
            os.close(fd)
            os.unlink(tmp)
        else:
            os.rmdir(tempfile.mkdtemp(prefix=".topodrake-probe-", dir=probe))
    except OSError as e:
        raise TopodrakeError(f"{option}: cannot write in {probe} ({_reason(e)})") from None
    return folder


def check_output(path, kind: str, *, force: bool = False, option: str = "--out",
                 replace: bool = False, grow: str = "") -> Path | None:
    """``path`` (None passes) is a file of ``kind`` (a key of :data:`KINDS`)
    that can be written; an existing non-empty file of another kind is
    refused unless ``force``, and one of its own kind too where ``kind`` is
    one of :data:`KEPT`, unless ``force`` or ``replace`` (the command grows
    it, or it is the command's own earlier output; ``grow`` names the option
    that grows it, for the message)."""
    if path is None:
        return None
    path = Path(path)
    formats = KINDS[kind]
    if path.is_dir():
        raise TopodrakeError(f"{option} {path} is a folder; give a file name")
    if path.suffix.lower() not in formats:
        fmt = f"unknown format {path.suffix!r}" if path.suffix else "no file extension"
        names = list(formats)
        ends = ", ".join(names[:-1]) + " or " + names[-1] if len(names) > 1 else names[0]
        raise TopodrakeError(f"{option} {path}: {fmt}; {'an' if kind[0] in 'aeiou' else 'a'} "
                             f"{kind} ends in {ends}")
    check_folder(path.parent, option)
    if path.is_file() and not force and path.stat().st_size:
        try:
            have = sniff(path)
        except OSError as e:
            raise TopodrakeError(f"{option} {path} exists and is unreadable ({_reason(e)})") from None
        if have != formats[path.suffix.lower()]:
            raise TopodrakeError(f"{option} {path} exists and holds {_DESCRIBE[have]}; pass "
                                 f"--force to overwrite it")
        if kind in KEPT and not replace:
            how = f"{grow} to grow it or --force to replace it" if grow else \
                "--force to replace it"
            raise TopodrakeError(f"{option} {path} exists; pass {how}")
    return path


def lock_path(path) -> Path:
    """The lock file of output ``path`` (a file or a folder): ``.NAME.lock`` beside it."""
    path = Path(os.path.abspath(path)) if Path(path).name in ("", ".", "..") else Path(path)
    if not path.name:                               # the root folder
        return path / ".topodrake.lock"
    return path.with_name(f".{path.name}.lock")


#: the locks this process holds, by lock file (released by :func:`release_locks`)
_HELD: dict = {}


def lock_output(path, option: str = "--out") -> Path | None:
    """Take the lock of output ``path`` (None passes) for the rest of the
    command (:func:`release_locks`); another process holding it is refused in
    one line. The folder of ``path`` is made if needed, to hold the lock file."""
    from filelock import FileLock, Timeout

    if path is None:
        return None
    path = Path(path)
    lock = lock_path(path)
    try:
        lock.parent.mkdir(parents=True, exist_ok=True)
        key = str(lock.resolve())
        if key in _HELD:
            return path
        held = FileLock(lock)
        held.acquire(timeout=0)
    except Timeout:
        raise TopodrakeError(f"{option} {path} is being written by another process (it holds "
                             f"{lock}); wait for it to end or choose another {option}") from None
    except OSError as e:
        raise TopodrakeError(f"{option}: cannot lock {path} ({_reason(e)})") from None
    _HELD[key] = held
    return path


def release_locks() -> None:
    """Release every lock :func:`lock_output` took (at the end of a command)."""
    while _HELD:
        _, held = _HELD.popitem()
        held.release()


def check_output_folder(path, *, marker: str | None = None, what: str = "",
                        force: bool = False, option: str = "--out") -> Path:
    """``path`` is a folder that can be made or written; with ``marker``, a
    non-empty folder must hold that file (it is ``what``, resumed or
    grown) unless ``force``."""
    folder = Path(path)
    if folder.exists() and not folder.is_dir():
        raise TopodrakeError(f"{option} {folder} is a file, not a folder")
    check_folder(folder, option)
    if marker and not force and folder.is_dir() and not (folder / marker).is_file() \
            and any(folder.iterdir()):
        raise TopodrakeError(f"{option} {folder} holds other files and no {what or marker}; give "
                             f"a new or empty folder, or pass --force")
    return folder


def write_kept(path, write, what: str = "the result") -> Path:
    """``write(path)``; when that fails, ``write`` to a file of the same name
    in the working folder or the temporary folder, and raise one line that
    names the failure and where ``what`` was kept."""
    path = Path(path)
    try:
        write(path)
        return path
    except OSError as e:
        failure = f"could not write {path} ({_reason(e)})"
    name = f"{path.stem}-kept-{os.getpid()}{path.suffix}"
    for folder in (Path.cwd(), Path(tempfile.gettempdir())):
        try:
            write(folder / name)
        except OSError:
            continue
        raise TopodrakeError(f"{failure}; kept {what} in {folder / name}")
    raise TopodrakeError(f"{failure}, nor anywhere else; {what} is lost")


def add_force_option(parser) -> None:
    """``--force``: replace existing outputs."""
    parser.add_argument("--force", action="store_true",
                        help="replace an existing output file (a map, plot or recording, or a "
                             "file that holds something else), or fill a folder that holds "
                             "other files")
