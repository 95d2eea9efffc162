"""The command-line options and error handling every study script shares."""

from __future__ import annotations

from typing import Callable


def add_study_arguments(parser, data_help: str = "cache of demonstrations") -> None:
    """The options every Monte Carlo study shares: seed, data folder, noise,
    workers or Ray, output folder, JSON and progress switches."""
    from topodrake.apps import argtypes as at

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

    from topodrake.errors import TopodrakeError

    try:
        return run(args)
    except TopodrakeError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
