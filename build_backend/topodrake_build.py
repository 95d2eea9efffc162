"""setuptools' build backend, refusing an unsupported Python first.

pip checks a local project's ``requires-python`` only after it has resolved
(and downloaded) every dependency when it is older than about 24.1 (Python
3.12.1 ships pip 23.2), so on an unsupported Python it fetches the whole
torch wheel before it refuses. Building the metadata is the first thing pip
asks of a local project or sdist; this backend refuses there, in one line,
before any dependency is looked up. Everything else is setuptools'.
"""

from __future__ import annotations

import platform
import re
from pathlib import Path

from setuptools import build_meta as _setuptools
from setuptools.build_meta import *  # noqa: F401,F403 (the PEP 517/660 hooks)

_PYPROJECT = Path(__file__).resolve().parent.parent / "pyproject.toml"


def requires_python() -> str:
    """The ``requires-python`` specifier of pyproject.toml ("" if absent)."""
    m = re.search(r'^requires-python\s*=\s*"([^"]*)"', _PYPROJECT.read_text(), re.MULTILINE)
    return m.group(1) if m else ""


def check_python(version: str | None = None) -> None:
    """SystemExit naming both versions unless ``version`` (default: this
    interpreter's) satisfies ``requires-python``."""
    from packaging.specifiers import SpecifierSet

    version = version or platform.python_version()
    spec = requires_python()
    if spec and not SpecifierSet(spec).contains(version, prereleases=True):
        raise SystemExit(f"topodrake needs Python {spec}; this is Python {version}. "
                         "Install it with a supported interpreter.")


def get_requires_for_build_wheel(config_settings=None):
    check_python()
    return _setuptools.get_requires_for_build_wheel(config_settings)


def get_requires_for_build_editable(config_settings=None):
    check_python()
    return _setuptools.get_requires_for_build_editable(config_settings)


def prepare_metadata_for_build_wheel(metadata_directory, config_settings=None):
    check_python()
    return _setuptools.prepare_metadata_for_build_wheel(metadata_directory, config_settings)


def prepare_metadata_for_build_editable(metadata_directory, config_settings=None):
    check_python()
    return _setuptools.prepare_metadata_for_build_editable(metadata_directory, config_settings)
