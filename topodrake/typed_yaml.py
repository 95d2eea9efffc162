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
    one-line :class:`TopodrakeError` naming it (``what`` says what it is).
    Without pydrake (a training machine) a plain loader of the same
    dataclasses stands in."""
    resolve_field_types(schema)
    path = Path(path)
    if not path.is_file():
        raise TopodrakeError(f"{what} file {path} does not exist")
    try:
        from pydrake.common.yaml import yaml_load_typed
    except ImportError:
        return _plain_load(schema, path.read_text(), f"{what} {path}")
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


def _plain_load(schema, text: str, where: str):
    """YAML text into dataclass ``schema`` without pydrake: unknown keys are
    errors, missing keys keep their defaults, nested dataclasses (also in
    lists, dicts and optionals) are built recursively."""
    import yaml

    resolve_field_types(schema)
    try:
        data = yaml.safe_load(text) or {}
    except yaml.YAMLError as e:
        raise TopodrakeError(f"{where}: {first_line(e)}") from None
    return _build(schema, data, where)


def _build(t, value, where: str):
    origin, args = typing.get_origin(t), typing.get_args(t)
    if dataclasses.is_dataclass(t):
        if not isinstance(value, dict):
            raise TopodrakeError(f"{where}: expected a mapping for {t.__name__}")
        names = {f.name: f for f in dataclasses.fields(t)}
        unknown = sorted(set(value) - set(names))
        if unknown:
            raise TopodrakeError(f"{where}: unknown key {unknown[0]!r} in {t.__name__}")
        return t(**{k: _build(names[k].type, v, f"{where}: {k}") for k, v in value.items()})
    if value is None:
        return None
    if origin in (list, tuple):
        return [_build(args[0], v, where) for v in value] if args else list(value)
    if origin is dict:
        return {k: _build(args[1], v, where) for k, v in value.items()} if args else dict(value)
    if args and type(None) in args:           # X | None
        inner = [a for a in args if a is not type(None)]
        return _build(inner[0], value, where)
    if t is float and isinstance(value, int):
        return float(value)
    return value
