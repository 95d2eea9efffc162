"""argparse pieces shared by ``topodrake`` and the study scripts.

- option types that parse a string and apply a :mod:`topodrake.validate`
  check (``type=argtypes.nonnegative`` and so on), so that
  ``--noise -1`` ends in ``argument --noise: must be a finite number >= 0,
  got -1``;
- :class:`Parser`, an ``ArgumentParser`` whose errors are one line (no usage
  block) with exit status 2, whose help shows every option's default, and
  which takes negative numbers as option values;
- :func:`plain`, which turns a reST docstring line into plain help text.
"""

from __future__ import annotations

import argparse
import re
from typing import Callable

from topodrake import validate
from topodrake.errors import TopodrakeError


def _parsed(check: Callable, convert: Callable, kind: str) -> Callable[[str], object]:
    def parse(text: str):
        try:
            value = convert(text)
        except ValueError:
            value = text           # the check names the allowed range
        try:
            return check("", value)
        except TopodrakeError as e:
            raise argparse.ArgumentTypeError(str(e)) from None

    parse.__name__ = kind
    return parse


def _int(text: str) -> int:
    return int(text, 10)


nonnegative = _parsed(validate.check_nonnegative, float, "nonnegative")
positive = _parsed(validate.check_positive, float, "positive")
probability = _parsed(validate.check_probability, float, "probability")
fraction = _parsed(validate.check_fraction, float, "fraction")
count = _parsed(validate.check_count, _int, "count")
count0 = _parsed(lambda name, v: validate.check_count(name, v, 0), _int, "count0")
seed = _parsed(validate.check_seed, _int, "seed")


def indices(text: str) -> list[int]:
    """A comma-separated list of indices >= 0 (``"7,68"``), at least one."""
    try:
        out = [_int(t.strip()) for t in text.split(",") if t.strip()]
    except ValueError:
        out = []
    if not out or min(out) < 0:
        raise argparse.ArgumentTypeError(f"expected indices >= 0 separated by commas, got {text!r}")
    return out


_ROLE = re.compile(r":[\w:]+:`~?([^`]+)`")
_LITERAL = re.compile(r"``([^`]+)``|`([^`]+)`")


def plain(text: str) -> str:
    """``text`` without reST markup: roles (``:mod:`a.b```) become their
    target, literals their content."""
    text = _ROLE.sub(lambda m: m.group(1), text)
    return _LITERAL.sub(lambda m: m.group(1) or m.group(2), text)


class HelpFormatter(argparse.HelpFormatter):
    """Appends ``(default: X)`` to an option's help when it has a default
    worth showing (not None, not a switch) and the help does not already
    say it."""

    def _get_help_string(self, action):
        text = action.help or ""
        default = action.default
        if ("default" in text or default in (None, argparse.SUPPRESS, "")
                or isinstance(default, bool) or action.nargs == 0):
            return text
        return f"{text} (default: %(default)s)"


#: what reads as a value, never as an option: a number or a list of numbers
#: (``-1``, ``-0.5``, ``-1e-3``, ``-1,-1,0``)
NEGATIVE_VALUE = re.compile(r"^-(\d|\.\d)[\d.eE+\-]*(,[-+]?[\d.eE+\-]+)*$")


class Parser(argparse.ArgumentParser):
    """``ArgumentParser`` with one-line errors (exit 2), defaults in help,
    and negative numbers accepted as option values (``--start -1,-1,0``)."""

    def __init__(self, *args, **kwargs):
        kwargs.setdefault("formatter_class", HelpFormatter)
        super().__init__(*args, **kwargs)
        self._negative_number_matcher = NEGATIVE_VALUE

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message}\n")


class RawEpilogFormatter(HelpFormatter):
    """:class:`HelpFormatter` that keeps the epilog's lines as written."""

    def _fill_text(self, text, width, indent):
        if "\n" in text:
            return "".join(indent + line for line in text.splitlines(keepends=True))
        return super()._fill_text(text, width, indent)


def subcommands(parser: argparse.ArgumentParser, **kwargs):
    """``parser.add_subparsers(**kwargs)``; the parser without a command
    names its commands in one line (exit 2) instead of argparse's
    ``the following arguments are required``."""
    sub = parser.add_subparsers(**kwargs)

    def missing(args):
        names = ", ".join(sub.choices)
        raise TopodrakeError(f"{parser.prog} needs a command: {names} "
                             f"(see '{parser.prog} --help')")

    parser.set_defaults(func=missing)
    return sub
