"""Checks for numbers where they enter: command-line options and YAML configs.

Each check returns the value (converted) or raises a one-line
:class:`~topodrake.errors.TopodrakeError` that names the setting and the
allowed range, for example ``--noise must be a finite number >= 0, got -1``.
The command line wraps them as argparse types (:mod:`topodrake.apps.argtypes`);
config dataclasses call them from their ``validate`` methods.
"""

from __future__ import annotations

import math
import numbers

from topodrake.errors import TopodrakeError

#: Seeds feed numpy and Drake generators, which take 32-bit unsigned seeds.
MAX_SEED = 2 ** 32 - 1


def _fail(name: str, what: str, value) -> TopodrakeError:
    """The one-line error; an empty ``name`` leaves it out (argparse adds
    "argument --option:" itself)."""
    shown = f"{value:g}" if isinstance(value, float) else repr(value) if isinstance(value, str) \
        else str(value)
    return TopodrakeError(f"{name + ' ' if name else ''}must be {what}, got {shown}")


def _number(name: str, value, what: str) -> float:
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise _fail(name, what, value)
    v = float(value)
    if not math.isfinite(v):
        raise _fail(name, what, v)
    return v


def _integer(name: str, value, what: str) -> int:
    if isinstance(value, float) and value.is_integer():
        return int(value)
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise _fail(name, what, value)
    return int(value)


def check_finite(name: str, value) -> float:
    """A finite number."""
    return _number(name, value, "a finite number")


def check_nonnegative(name: str, value) -> float:
    """A finite number >= 0 (noise levels, margins, times that may be zero)."""
    what = "a finite number >= 0"
    v = _number(name, value, what)
    if v < 0:
        raise _fail(name, what, value)
    return v


def check_positive(name: str, value) -> float:
    """A finite number > 0 (speeds, durations, step sizes)."""
    what = "a finite number > 0"
    v = _number(name, value, what)
    if v <= 0:
        raise _fail(name, what, value)
    return v


def check_probability(name: str, value) -> float:
    """A probability strictly between 0 and 1 (thresholds such as p_sparsify)."""
    what = "a probability in (0, 1)"
    v = _number(name, value, what)
    if not 0.0 < v < 1.0:
        raise _fail(name, what, value)
    return v


def check_fraction(name: str, value) -> float:
    """A share in [0, 1] (mixing weights, augmentation rates)."""
    what = "a number in [0, 1]"
    v = _number(name, value, what)
    if not 0.0 <= v <= 1.0:
        raise _fail(name, what, value)
    return v


def check_count(name: str, value, minimum: int = 1) -> int:
    """An integer >= ``minimum`` (trials, pairs, batch sizes, workers)."""
    what = f"an integer >= {minimum}"
    v = _integer(name, value, what)
    if v < minimum:
        raise _fail(name, what, v)
    return v


def check_seed(name: str, value) -> int:
    """A seed: an integer in [0, 2**32 - 1]."""
    what = f"an integer in [0, {MAX_SEED}]"
    v = _integer(name, value, what)
    if not 0 <= v <= MAX_SEED:
        raise _fail(name, what, v)
    return v
