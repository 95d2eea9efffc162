"""Where numba keeps topodrake's compiled kernels between processes.

Every kernel is compiled with ``cache=True``. Numba's own cache stamps each
function with its source file only, so a kernel would keep a stale compiled
copy of a constant or helper it takes from another module. The cache
directory is therefore keyed by a hash of every module that defines a
kernel and of the topodrake modules they import (transitively): any edit to
that code starts a fresh directory, and unchanged code loads in well under a
second instead of compiling again.

The base directory is the first writable one of ``$TOPODRAKE_CACHE_DIR``,
``$XDG_CACHE_HOME/topodrake`` (``~/.cache/topodrake``) and a per-user folder
under the system temporary directory; an installation in a read-only
location still caches. ``NUMBA_CACHE_DIR``, when set, wins and is used as
given. Keyed folders unused for :data:`PRUNE_AFTER_DAYS` are removed.
"""

from __future__ import annotations

import hashlib
import os
import re
import shutil
import sys
import tempfile
import time
from pathlib import Path

PACKAGE = Path(__file__).resolve().parent
PRUNE_AFTER_DAYS = 14

# Module-level imports only: a kernel can use only module globals, so imports
# inside functions are no kernel's dependency.
_IMPORT = re.compile(r"^(?:from|import)\s+topodrake((?:\.\w+)*)", re.MULTILINE)


def _module_file(dotted: str, package: Path = PACKAGE) -> Path | None:
    """The source file of ``topodrake<dotted>`` (a module or a package)."""
    base = package.joinpath(*dotted.strip(".").split(".")) if dotted else package
    for candidate in (base.with_suffix(".py"), base / "__init__.py"):
        if candidate.is_file():
            return candidate
    return None


def kernel_sources(package: Path = PACKAGE) -> list[Path]:
    """Modules that define numba kernels and every topodrake module they
    import, directly or not (sorted)."""
    texts: dict[Path, str] = {}

    def text(path: Path) -> str:
        if path not in texts:
            texts[path] = path.read_text(encoding="utf-8", errors="replace")
        return texts[path]

    todo = [p for p in package.rglob("*.py") if "@nb.njit" in text(p) or "@numba.njit" in text(p)]
    seen: set[Path] = set()
    while todo:
        path = todo.pop()
        if path in seen:
            continue
        seen.add(path)
        for dotted in _IMPORT.findall(text(path)):
            # "from topodrake.a.b import c" may name module a.b or a.b.c.
            found = _module_file(dotted, package)
            if found is not None and found not in seen:
                todo.append(found)
    return sorted(seen)


def source_key(package: Path = PACKAGE) -> str:
    """A short hash of the kernel sources, the Python and the numba version."""
    import numba

    h = hashlib.blake2b(digest_size=8)
    h.update(f"{sys.version_info[:2]} {numba.__version__}".encode())
    for path in kernel_sources(package):
        h.update(path.relative_to(package).as_posix().encode())
        h.update(path.read_bytes())
    return h.hexdigest()


def _writable(path: Path) -> bool:
    try:
        path.mkdir(parents=True, exist_ok=True)
        tempfile.TemporaryFile(dir=path).close()
        return True
    except OSError:
        return False


def candidate_bases() -> list[Path]:
    """Base cache directories in order of preference."""
    out = []
    if os.environ.get("TOPODRAKE_CACHE_DIR"):
        out.append(Path(os.environ["TOPODRAKE_CACHE_DIR"]))
    xdg = os.environ.get("XDG_CACHE_HOME")
    out.append(Path(xdg) / "topodrake" if xdg else Path.home() / ".cache" / "topodrake")
    uid = os.getuid() if hasattr(os, "getuid") else os.environ.get("USERNAME", "user")
    out.append(Path(tempfile.gettempdir()) / f"topodrake-{uid}")
    return out


def _prune(numba_dir: Path, keep: Path) -> None:
    cutoff = time.time() - PRUNE_AFTER_DAYS * 86400
    try:
        for old in numba_dir.iterdir():
            if old != keep and old.is_dir() and old.stat().st_mtime < cutoff:
                shutil.rmtree(old, ignore_errors=True)
    except OSError:
        pass


def choose_cache_dir(bases: list[Path] | None = None, key: str | None = None) -> Path | None:
    """The keyed numba cache directory under the first writable base, or
    None when none is writable (numba then uses its own locations)."""
    key = key or source_key()
    for base in candidate_bases() if bases is None else bases:
        path = base / "numba" / key
        if _writable(path):
            try:
                os.utime(path)   # marks it as in use for pruning
            except OSError:
                pass
            _prune(path.parent, path)
            return path
    return None


def configure() -> Path | None:
    """Point numba's cache at :func:`choose_cache_dir` unless the user set
    ``NUMBA_CACHE_DIR``; must run before any kernel module is imported.
    Returns the directory in use (None: numba's defaults)."""
    import numba

    if os.environ.get("NUMBA_CACHE_DIR"):
        return Path(os.environ["NUMBA_CACHE_DIR"])
    try:
        path = choose_cache_dir()
    except OSError:
        path = None
    if path is not None:
        numba.config.CACHE_DIR = str(path)
    return path
