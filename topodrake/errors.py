"""The one error type topodrake raises for bad input.

Every user-facing problem (a malformed map file, an unreachable goal, a pose
outside the map, ...) is a :class:`TopodrakeError` whose message is a single
line naming the file or value and the problem. The CLI prints that line and
exits with status 2; library users can catch it.
"""


class TopodrakeError(ValueError):
    """Bad input, with a one-line message that names the problem."""

    exit_code = 2
