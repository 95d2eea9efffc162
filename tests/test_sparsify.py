"""Greedy trajectory sparsification with hand-made reachability functions."""

import numpy as np
import pytest

from topodrake.errors import TopodrakeError
from topodrake.topomap import sparsify


def test_anchors_every_reach_limit():
    # reachable iff the target is at most 4 frames ahead
    calls = []

    def reach(i, js):
        calls.append(len(js))
        return np.where(js - i <= 4, 0.999, 0.1)

    a = sparsify(20, reach, p=0.99, window=3, max_window=3)
    assert a.tolist() == [0, 4, 8, 12, 16, 19]
    assert max(calls) <= 3                       # evaluated in windows
    calls.clear()
    assert sparsify(20, reach, p=0.99, window=2, max_window=8).tolist() == [0, 4, 8, 12, 16, 19]
    assert calls[:2] == [2, 4]                   # windows double while every frame passes


def test_first_failure_stops_the_scan_even_if_later_frames_pass():
    # frame 3 is "behind a corner": from anchor 0 the scan must stop there
    def reach(i, js):
        return np.where((js == 3) & (i == 0), 0.2, 0.999)

    assert sparsify(10, reach, window=4).tolist() == [0, 2, 9]
    assert sparsify(10, reach, window=1).tolist() == [0, 2, 9]


def test_walk_always_advances_and_keeps_the_last_frame():
    assert sparsify(5, lambda i, js: np.zeros(len(js))).tolist() == [0, 1, 2, 3, 4]
    assert sparsify(6, lambda i, js: np.ones(len(js))).tolist() == [0, 5]
    assert sparsify(1, lambda i, js: np.ones(len(js))).tolist() == [0]


def test_bad_arguments():
    with pytest.raises(TopodrakeError, match="empty"):
        sparsify(0, lambda i, js: js)
    with pytest.raises(TopodrakeError, match="p_sparsify"):
        sparsify(5, lambda i, js: js, p=1.0)
    with pytest.raises(TopodrakeError, match="returned"):
        sparsify(5, lambda i, js: np.ones(1), window=3)
