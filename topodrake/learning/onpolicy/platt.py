"""The follower calibration file beside an RE checkpoint: its name and its reader.

:mod:`topodrake.learning.onpolicy.calibration` fits and writes it;
:meth:`topodrake.learning.reachability.estimator.Reachability.from_checkpoint` reads
it with :func:`load_follower_platt`.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from topodrake.errors import TopodrakeError
from topodrake.fileio import file_sha1

SIDECAR = "follower_calibration.json"
FORMAT = "topodrake-follower-calibration"


def load_follower_platt(re_path) -> tuple[float, float] | None:
    """The follower Platt (a, b) of ``follower_calibration.json`` beside
    the RE checkpoint ``re_path``; None when there is none. A file that is
    unreadable or made for other checkpoint contents is refused."""
    path = Path(re_path).parent / SIDECAR
    if not path.is_file():
        return None
    try:
        blob = json.loads(path.read_text())
        platt = blob["follower_platt"]
        a, b = float(platt[0]), float(platt[1])
        sha = blob["checkpoint_sha1"]
    except (ValueError, KeyError, TypeError, IndexError) as e:
        raise TopodrakeError(f"{path} is not a follower calibration ({type(e).__name__}: {e})"
                             ) from None
    if blob.get("format") != FORMAT:
        raise TopodrakeError(f"{path} is not a follower calibration (format "
                             f"{blob.get('format')!r})")
    if sha != file_sha1(re_path):
        raise TopodrakeError(f"{path} was fitted for another {Path(re_path).name} (sha1 "
                             f"{str(sha)[:10]}); refit it with topodrake train "
                             f"follower-calibration or delete it")
    if not (np.isfinite(a) and np.isfinite(b) and a > 0):
        raise TopodrakeError(f"{path} has an invalid follower_platt {platt}")
    return a, b
