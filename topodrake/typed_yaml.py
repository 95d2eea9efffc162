"""Typed YAML configs through pydrake's ``yaml_load_typed``, with one-line errors."""

import dataclasses
import typing
from pathlib import Path

import yaml

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
    text = path.read_text()
    root = _compose(text, f"{what} {path}")
    try:
        return yaml_load_typed(schema=schema, filename=str(path), child_name=child_name,
                               defaults=defaults)
    except Exception as e:  # pydrake raises RuntimeError with a multi-line message
        raise TopodrakeError(_located(f"{what} {path}", schema, root, child_name, e)) from None


def load_typed_data(schema, data: str, what: str, defaults=None):
    """Like :func:`load_typed` for YAML text."""
    resolve_field_types(schema)
    try:
        from pydrake.common.yaml import yaml_load_typed
    except ImportError:
        return _plain_load(schema, data, what, None, defaults)
    root = _compose(data, what)
    try:
        return yaml_load_typed(schema=schema, data=data, defaults=defaults)
    except Exception as e:
        raise TopodrakeError(_located(what, schema, root, None, e)) from None


def yaml_error(where: str, e: yaml.YAMLError) -> str:
    """One line for a YAML syntax error: ``where``, the line (and column)
    of the problem, and what it is."""
    mark = getattr(e, "problem_mark", None) or getattr(e, "context_mark", None)
    problem = getattr(e, "problem", None) or first_line(e)
    if mark is None:
        return f"{where}: {problem}"
    return f"{where} line {mark.line + 1} column {mark.column + 1}: {problem}"


def _compose(text: str, where: str):
    """The YAML node tree of ``text`` (lines kept for the errors); broken
    YAML raises a one-line TopodrakeError with its line."""
    try:
        return yaml.compose(text, Loader=yaml.SafeLoader)
    except yaml.YAMLError as e:
        raise TopodrakeError(yaml_error(where, e)) from None


def _located(where: str, schema, root, child_name, e: Exception) -> str:
    """The loader's error ``e`` with the key path and line of the first
    value of ``root`` that does not fit ``schema``, where one is found."""
    node = root
    if child_name is not None and isinstance(node, yaml.MappingNode):
        node = next((v for k, v in node.value if k.value == child_name), None)
    found = None if node is None else _misfit(schema, node, "")
    if found is None:
        return f"{where}: {first_line(e)}"
    key, line = found
    return f"{where} line {line}: {key or 'the document'}: {first_line(e)}"


def _fits_scalar(t, value: str) -> bool:
    try:
        if t is float:
            float(value)
        elif t is int:
            int(value, 0)
        elif t is bool:
            return value.lower() in ("true", "false", "yes", "no", "on", "off")
    except ValueError:
        return False
    return True


def _misfit(t, node, key: str):
    """(key path, line) of the first value under ``node`` that cannot be of
    type ``t``; None where all fit (or the type is not one checked here)."""
    line = node.start_mark.line + 1
    origin, params = typing.get_origin(t), typing.get_args(t)
    if isinstance(node, yaml.ScalarNode) and node.tag == "tag:yaml.org,2002:null":
        return None if (type(None) in params or node.value == "") else (key, line)
    if params and type(None) in params and origin not in (list, tuple, dict):
        inner = [a for a in params if a is not type(None)]
        return _misfit(inner[0], node, key) if len(inner) == 1 else None
    if dataclasses.is_dataclass(t):
        if not isinstance(node, yaml.MappingNode):
            return key, line
        fields = {f.name: f.type for f in dataclasses.fields(t)}
        for k, v in node.value:
            name = f"{key}.{k.value}" if key else str(k.value)
            if k.value not in fields:
                return name, k.start_mark.line + 1
            found = _misfit(fields[k.value], v, name)
            if found:
                return found
        return None
    if origin in (list, tuple):
        if not isinstance(node, yaml.SequenceNode):
            return key, line
        for i, v in enumerate(node.value):
            found = _misfit(params[0], v, f"{key}[{i}]") if params else None
            if found:
                return found
        return None
    if origin is dict:
        if not isinstance(node, yaml.MappingNode):
            return key, line
        for k, v in node.value:
            found = _misfit(params[1], v, f"{key}.{k.value}") if len(params) == 2 else None
            if found:
                return found
        return None
    if t in (float, int, bool, str):
        if not isinstance(node, yaml.ScalarNode):
            return key, line
        return None if _fits_scalar(t, node.value) else (key, line)
    return None


def _plain_load(schema, text: str, where: str, child_name: str | None = None, defaults=None):
    """YAML text into dataclass ``schema`` without pydrake: unknown keys are
    errors, missing keys keep their defaults (``defaults``' values where
    given), nested dataclasses (also in lists, dicts and optionals) are
    built recursively."""
    resolve_field_types(schema)
    try:
        data = yaml.safe_load(text) or {}
    except yaml.YAMLError as e:
        raise TopodrakeError(yaml_error(where, e)) from None
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
