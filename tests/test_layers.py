"""The layer contract: apps above experiments above the core, the core layered.

The contract itself is ``[tool.importlinter]`` in pyproject.toml. ``systems/``
installs as ``topodrake.systems`` through setuptools' ``package-dir``, which
import-linter's file walk does not follow, so the check runs on a mirror of
the package (links, no copies) with ``systems/`` in its place.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _mirror(tmp_path: Path) -> Path:
    pkg = tmp_path / "topodrake"
    pkg.mkdir()
    for entry in (ROOT / "topodrake").iterdir():
        if entry.name != "__pycache__":
            (pkg / entry.name).symlink_to(entry)
    (pkg / "systems").symlink_to(ROOT / "systems")
    return tmp_path


def test_imports_follow_the_layers(tmp_path):
    mirror = _mirror(tmp_path)
    lint = Path(sys.executable).with_name("lint-imports")
    env = {**os.environ, "PYTHONPATH": str(mirror)}
    res = subprocess.run([str(lint), "--config", str(ROOT / "pyproject.toml"), "--no-cache"],
                         cwd=mirror, env=env, capture_output=True, text=True)
    assert res.returncode == 0, res.stdout[-6000:] + res.stderr[-2000:]
    assert "1 kept, 0 broken" in res.stdout


def test_the_contract_sees_an_upward_import(tmp_path):
    """The check is live: a core module importing an app breaks it."""
    mirror = _mirror(tmp_path)
    world = mirror / "topodrake" / "world"
    world.unlink()
    world.mkdir()
    for entry in (ROOT / "topodrake" / "world").iterdir():
        if entry.name != "__pycache__":
            (world / entry.name).symlink_to(entry)
    (world / "upward.py").write_text("from topodrake.apps import cli\n")
    lint = Path(sys.executable).with_name("lint-imports")
    env = {**os.environ, "PYTHONPATH": str(mirror)}
    res = subprocess.run([str(lint), "--config", str(ROOT / "pyproject.toml"), "--no-cache"],
                         cwd=mirror, env=env, capture_output=True, text=True)
    assert res.returncode != 0
    assert "topodrake.world.upward -> topodrake.apps.cli" in res.stdout
