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


def load_typed(schema, path, what: str, child_name: str | None = None, defaults=None):
    """Load ``path`` into dataclass ``schema``; a missing or bad file raises a
    one-line :class:`TopodrakeError` naming it (``what`` says what it is).
    ``child_name``: load the document's top-level key of that name instead
    of the whole document; ``defaults``: an instance whose values the YAML's
    keys change (nested dataclasses and mappings key by key), the schema's
    defaults otherwise. Without pydrake (a training machine) a plain loader
    of the same dataclasses stands in."""
    resolve_field_types(schema)
    path = Path(path)
    if not path.is_file():
        raise TopodrakeError(f"{what} file {path} does not exist")
    try:
        from pydrake.common.yaml import yaml_load_typed
    except ImportError:
        return _plain_load(schema, path.read_text(), f"{what} {path}", child_name, defaults)
    try:
        return yaml_load_typed(schema=schema, filename=str(path), child_name=child_name,
                               defaults=defaults)
    except Exception as e:  # pydrake raises RuntimeError with a multi-line message
        raise TopodrakeError(f"{what} {path}: {first_line(e)}") from None


def load_typed_data(schema, data: str, what: str, defaults=None):
    """Like :func:`load_typed` for YAML text."""
    resolve_field_types(schema)
    try:
        from pydrake.common.yaml import yaml_load_typed
    except ImportError:
        return _plain_load(schema, data, what, None, defaults)
    try:
        return yaml_load_typed(schema=schema, data=data, defaults=defaults)
    except Exception as e:
        raise TopodrakeError(f"{what}: {first_line(e)}") from None


def _plain_load(schema, text: str, where: str, child_name: str | None = None, defaults=None):
    """YAML text into dataclass ``schema`` without pydrake: unknown keys are
    errors, missing keys keep their defaults (``defaults``' values where
    given), nested dataclasses (also in lists, dicts and optionals) are
    built recursively."""
    import yaml

    resolve_field_types(schema)
    try:
        data = yaml.safe_load(text) or {}
    except yaml.YAMLError as e:
        raise TopodrakeError(f"{where}: {first_line(e)}") from None
    if child_name is not None:
        if not isinstance(data, dict) or child_name not in data:
            raise TopodrakeError(f"{where}: no key {child_name!r}")
        data = data[child_name] or {}
    return _build(schema, data, where, defaults)


def _build(t, value, where: str, default=None):
    origin, params = typing.get_origin(t), typing.get_args(t)
    if dataclasses.is_dataclass(t):
        if not isinstance(value, dict):
            raise TopodrakeError(f"{where}: expected a mapping for {t.__name__}")
        names = {f.name: f for f in dataclasses.fields(t)}
        unknown = sorted(set(value) - set(names))
        if unknown:
            raise TopodrakeError(f"{where}: unknown key {unknown[0]!r} in {t.__name__}")
        built = {k: _build(names[k].type, v, f"{where}: {k}",
                           None if default is None else getattr(default, k))
                 for k, v in value.items()}
        if default is None:
            return t(**built)
        import copy

        return dataclasses.replace(copy.deepcopy(default), **built)
    if origin is dict and isinstance(default, dict) and isinstance(value, dict):
        return {**default, **_build(t, value, where)}
    if value is None:
        return None
    if origin in (list, tuple):
        return [_build(params[0], v, where) for v in value] if params else list(value)
    if origin is dict:
        return {k: _build(params[1], v, where) for k, v in value.items()} if params else dict(value)
    if params and type(None) in params:           # X | None
        inner = [a for a in params if a is not type(None)]
        return _build(inner[0], value, where)
    if t is float and isinstance(value, int):
        return float(value)
    return value
