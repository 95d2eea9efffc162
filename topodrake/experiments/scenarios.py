"""Studies as typed scenarios: one dataclass per study, named scenarios in a YAML file.

As Drake's ``examples/hardware_sim`` does: a study's settings are one
dataclass (:class:`~topodrake.experiments.plan_scenario.PlanningScenario`,
:class:`~topodrake.experiments.follow_scenario.FollowingScenario`, ...);
a YAML file maps scenario names to the fields they change
(``studies/scenarios/<study>.yaml``); :func:`load_scenario` reads one by
name and applies YAML text on top of it (``--scenario-text``), and
:func:`with_changes` applies a mapping of changed fields (what a study's
command-line flags give). Nested configs (``follower``, ``map``, ``replan``)
change key by key, lists are replaced whole. :func:`option` declares a field
with the help text its command-line flag shows.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

from topodrake.errors import TopodrakeError
from topodrake.typed_yaml import load_typed, load_typed_data


def option(default, help: str, *, flag: str | None = None, choices=None, nested: bool = False):
    """A scenario field: its default (a dataclass type, list or dict is made
    fresh for every instance), its help (the flag's and the YAML key's),
    the command-line flag that sets it (default ``--field-name``; ``""``:
    none), the values it takes, and ``nested``: a nested dataclass whose own
    fields carry flags."""
    meta = {"help": help, "flag": flag, "choices": tuple(choices) if choices else None,
            "nested": nested}
    if isinstance(default, type):
        return dataclasses.field(default_factory=default, metadata=meta)
    if isinstance(default, (list, dict)):
        return dataclasses.field(default_factory=lambda: type(default)(default), metadata=meta)
    return dataclasses.field(default=default, metadata=meta)


def scenario_names(path) -> list[str]:
    """The scenario names of a scenarios YAML file, in file order."""
    import yaml

    path = Path(path)
    try:
        data = yaml.safe_load(path.read_text()) or {}
    except (OSError, yaml.YAMLError) as e:
        raise TopodrakeError(f"scenarios file {path}: {type(e).__name__}: {e}") from None
    if not isinstance(data, dict):
        raise TopodrakeError(f"scenarios file {path}: expected a mapping of scenario names")
    return list(data)


def load_scenario(schema, path, name: str, text: str | None = None):
    """Scenario ``name`` of the YAML file ``path`` (each top-level key a
    scenario: the fields it changes from ``schema``'s defaults), then the
    YAML ``text`` on top of it; checked by its ``validate``. An unknown
    name, key or value is refused in one line."""
    names = scenario_names(path)
    if name not in names:
        raise TopodrakeError(f"unknown scenario {name!r} in {path}; choose from "
                             f"{', '.join(names)}")
    sc = load_typed(schema, path, f"scenario {name!r} of", child_name=name, defaults=schema())
    if text and text.strip():
        sc = load_typed_data(schema, text, "--scenario-text", defaults=sc)
    return sc.validate()


def with_changes(sc, changes: dict):
    """``sc`` with ``changes`` (a mapping of fields, nested mappings for
    nested configs) applied as YAML over it, checked."""
    import yaml


    if not changes:
        return sc.validate()
    return load_typed_data(type(sc), yaml.safe_dump(changes), "options", defaults=sc).validate()


def to_yaml(sc) -> str:
    """A scenario as the YAML that loads it back."""
    import yaml

    return yaml.safe_dump(dataclasses.asdict(sc), sort_keys=False)
