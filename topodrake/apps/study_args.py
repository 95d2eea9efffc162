"""The command-line options and error handling every study script shares."""

from __future__ import annotations

from typing import Callable

from topodrake.apps import argtypes as at
from topodrake.errors import TopodrakeError
from topodrake.experiments.scenarios import load_scenario, scenario_names, with_changes

#: flags whose values every study checks the same way
_CHECKED = {"seed": at.seed, "noise": at.nonnegative}


def add_study_arguments(parser, data_help: str = "cache of demonstrations") -> None:
    """The options every Monte Carlo study shares: seed, data folder, noise,
    workers or Ray, output folder, JSON and progress switches."""
    parser.add_argument("--seed", type=at.seed, default=0, help="base seed of the trial seeds")
    parser.add_argument("--data", default="data", help=data_help)
    parser.add_argument("--noise", type=at.nonnegative, default=0.33,
                        help="actuation noise std of the noisy runs")
    parser.add_argument("--workers", type=at.count,
                        help="local worker processes (default: all cores)")
    parser.add_argument("--ray", metavar="ADDRESS", help="run the trials on a Ray cluster")
    parser.add_argument("--out", default="results", help="folder of the JSON and PNG results")
    parser.add_argument("--json", action="store_true", help="print the summary as one JSON object")
    parser.add_argument("--quiet", action="store_true", help="no progress bars")


def study_main(run: Callable, args) -> int:
    """``run(args)``; a TopodrakeError becomes one ``error:`` line and exit code 2."""
    import sys


    try:
        return run(args)
    except TopodrakeError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2


# ---------------------------------------------------------------- typed scenarios

def add_scenario_arguments(parser, schema, scenarios, default: str,
                           types: dict | None = None) -> None:
    """``--scenario NAME`` (of the YAML file ``scenarios``), ``--scenario-text
    YAML`` (fields over it, as Drake's hardware_sim takes them),
    ``--print-config`` (print the scenario as YAML and run nothing), and a
    flag for every field of ``schema`` that has one
    (:func:`topodrake.experiments.scenarios.option`): a flag given changes
    its field over the scenario and the text (:func:`scenario_of`).
    ``types`` maps field names to their flags' parsers where the field's type
    alone does not check enough (``{"trials": argtypes.count}``)."""
    import argparse


    parser.add_argument("--scenario", default=default,
                        help=f"named scenario of {_shown(scenarios)}: "
                             f"{', '.join(scenario_names(scenarios))}")
    parser.add_argument("--scenario-text", default="", metavar="YAML",
                        help="scenario fields to change, as YAML "
                             "(e.g. '{trials: 10}'; default: none)")
    parser.add_argument("--print-config", action="store_true",
                        help="print the scenario (with the flags given) as YAML and run nothing")
    defaults = schema()
    for dest, name, t, f in _flag_fields(schema):
        meta = f.metadata
        value = _get(defaults, dest)
        shown = ",".join(map(str, value)) if isinstance(value, list) else value
        quiet = value is None or isinstance(value, bool) or "default" in meta["help"]
        kwargs = {"dest": dest, "default": argparse.SUPPRESS,
                  "help": meta["help"] + ("" if quiet else f" (default: {shown})")}
        if t is bool:
            kwargs["action"] = "store_true"
        else:
            kwargs["type"] = (types or {}).get(name) or _CHECKED.get(name) or _parser_of(t, name)
            if meta.get("choices"):
                kwargs["choices"] = meta["choices"]
            else:
                kwargs["metavar"] = name.upper()
        parser.add_argument(meta.get("flag") or "--" + name.replace("_", "-"), **kwargs)


def scenario_of(schema, args, scenarios, changes: dict | None = None):
    """The scenario a study's command line names: ``args.scenario`` of the
    file ``scenarios``, ``args.scenario_text`` over it, then every field flag
    given, then ``changes`` (a mapping of fields the study's other flags
    give); checked."""
    given: dict = {}
    for dest, *_ in _flag_fields(schema):
        if hasattr(args, dest):
            node = given
            *parents, last = dest.split(".")
            for p in parents:
                node = node.setdefault(p, {})
            node[last] = getattr(args, dest)
    for key, value in (changes or {}).items():
        if isinstance(value, dict) and isinstance(given.get(key), dict):
            given[key] = {**given[key], **value}
        else:
            given[key] = value
    sc = load_scenario(schema, scenarios, args.scenario, args.scenario_text)
    return with_changes(sc, given)


def add_output_arguments(parser, json: bool = True, quiet: bool = True) -> None:
    """``--out``, ``--json`` and ``--quiet``: where a study writes and how it prints."""
    parser.add_argument("--out", default="results", help="folder of the JSON and PNG results")
    if json:
        parser.add_argument("--json", action="store_true",
                            help="print the summary as one JSON object")
    if quiet:
        parser.add_argument("--quiet", action="store_true", help="no progress bars")


def printed_config(sc, args) -> bool:
    """Whether ``--print-config`` was given; if so ``sc`` is printed as YAML."""
    if not args.print_config:
        return False
    from topodrake.experiments.scenarios import to_yaml

    print(to_yaml(sc), end="")
    return True


def json_object(flag: str, text: str | None) -> dict:
    """A flag's JSON object (``{}`` for none); a bad one is refused in one line."""
    import json


    if not text:
        return {}
    try:
        value = json.loads(text)
    except ValueError as e:
        raise TopodrakeError(f"{flag} {text!r} is not a JSON object ({e})") from None
    if not isinstance(value, dict):
        raise TopodrakeError(f"{flag} {text!r} is not a JSON object")
    return value


def _shown(path) -> str:
    from pathlib import Path

    try:
        return str(Path(path).resolve().relative_to(Path.cwd()))
    except ValueError:
        return str(path)


def _flag_fields(schema, prefix: str = ""):
    """(dest, name, type, field) of every field of ``schema`` with a flag,
    nested dataclasses' fields (``nested`` options) with dotted dests."""
    import dataclasses
    import typing

    hints = typing.get_type_hints(schema)
    for f in dataclasses.fields(schema):
        meta = f.metadata
        if "help" not in meta:
            continue
        if meta.get("nested"):
            yield from _flag_fields(hints[f.name], prefix + f.name + ".")
            continue
        if meta.get("flag") == "":
            continue
        t = hints[f.name]
        inner = [a for a in typing.get_args(t) if a is not type(None)]
        if typing.get_origin(t) is not list and type(None) in typing.get_args(t):
            t = inner[0]                      # X | None
        yield prefix + f.name, f.name, t, f


def _get(obj, dest: str):
    for part in dest.split("."):
        obj = getattr(obj, part)
    return obj


def _parser_of(t, name: str):
    """The string parser of a flag of type ``t``: a number, a string, or a
    comma-separated list ('none': an empty one)."""
    import argparse
    import typing

    if typing.get_origin(t) is list:
        item = _parser_of(typing.get_args(t)[0], name)

        def items(text: str):
            if text.strip().lower() in ("", "none", "off"):
                return []
            return [item(x.strip()) for x in text.split(",") if x.strip()]

        items.__name__ = f"comma-separated {item.__name__}s"
        return items

    def one(text: str):
        try:
            return t(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {t.__name__}, got {text!r}") from None

    one.__name__ = t.__name__
    return one
