"""Typed YAML configs through pydrake's ``yaml_load_typed``, with one-line errors."""

import dataclasses
import typing
from pathlib import Path

from topodrake.errors import TopodrakeError


def resolve_field_types(cls, seen=None) -> None:
    """Replace string annotations (``from __future__ import annotations``) by
    the types themselves, in ``cls`` and every nested dataclass: pydrake's
    ``yaml_load_typed`` reads ``dataclasses.fields(...).type`` as given and
    does not evaluate strings."""
    seen = set() if seen is None else seen
    if cls in seen:
        return
    seen.add(cls)
    hints = typing.get_type_hints(cls)
    for f in dataclasses.fields(cls):
        f.type = hints[f.name]
        _resolve_within(f.type, seen)


def _resolve_within(t, seen) -> None:
    # nested, listed (list[Config]) or optional and listed (list[Config] | None)
    if dataclasses.is_dataclass(t):
        resolve_field_types(t, seen)
    for arg in typing.get_args(t):
        _resolve_within(arg, seen)


def first_line(e: Exception) -> str:
    text = str(e).strip()
    return text.splitlines()[0] if text else type(e).__name__


def load_typed(schema, path, what: str):
    """Load ``path`` into dataclass ``schema``; a missing or bad file raises a
    one-line :class:`TopodrakeError` naming it (``what`` says what it is)."""
    from pydrake.common.yaml import yaml_load_typed

    resolve_field_types(schema)
    path = Path(path)
    if not path.is_file():
        raise TopodrakeError(f"{what} file {path} does not exist")
    try:
        return yaml_load_typed(schema=schema, filename=str(path))
    except Exception as e:  # pydrake raises RuntimeError with a multi-line message
        raise TopodrakeError(f"{what} {path}: {first_line(e)}") from None


def load_typed_data(schema, data: str, what: str):
    """Like :func:`load_typed` for YAML text."""
    from pydrake.common.yaml import yaml_load_typed

    resolve_field_types(schema)
    try:
        return yaml_load_typed(schema=schema, data=data)
    except Exception as e:
        raise TopodrakeError(f"{what}: {first_line(e)}") from None
