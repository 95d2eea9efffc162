"""Greedy trajectory sparsification with hand-made reachability functions."""

import numpy as np
import pytest

from topodrake.errors import TopodrakeError
from topodrake.learning.reachability.sparsify import sparsify


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


def test_slack_keeps_the_farthest_frame_nearly_as_reachable_as_the_next():
    # RE never reaches 0.99 from frames 0..9 (0.97 up to 4 frames ahead, then 0.9);
    # from frame 10 on it passes 0.99 up to 3 frames ahead
    def reach(i, js):
        if i < 10:
            return np.where(js - i <= 4, 0.97 - 0.001 * (js - i), 0.9)
        return np.where(js - i <= 3, 0.999, 0.5)

    paper = sparsify(20, reach, p=0.99)
    assert paper.tolist()[:11] == list(range(11))          # every frame an anchor
    # with slack the scan goes on while RE stays within 0.01 of the next frame's
    assert sparsify(20, reach, p=0.99, slack=0.01).tolist() == [0, 4, 8, 12, 15, 18, 19]
    # a slack smaller than the fall from the next frame's RE moves one frame at a time
    assert sparsify(20, reach, p=0.99, slack=0.0005).tolist()[:4] == [0, 1, 2, 3]
    # where the next frame passes p the slack changes nothing
    assert sparsify(20, lambda i, js: np.where(js - i <= 4, 0.999, 0.98), slack=0.05).tolist() \
        == [0, 4, 8, 12, 16, 19]


def test_a_hop_cap_keeps_anchors_within_reach_along_the_drive():
    """RE trusts every frame (a corridor); with hops capped at 1 m along a
    drive of frames 0.3 m apart the anchors fall every 3 frames, and a cap
    shorter than one frame's step still advances."""
    from topodrake.learning.reachability.sparsify import hop_caps

    xy = np.c_[0.3 * np.arange(12), np.zeros(12)]
    caps = hop_caps(xy, 1.0)
    assert caps.tolist() == [3, 4, 5, 6, 7, 8, 9, 10, 11, 11, 11, 11]
    assert hop_caps(xy, 0.0) is None
    trusted = lambda i, js: np.ones(len(js))        # noqa: E731
    assert sparsify(12, trusted).tolist() == [0, 11]
    assert sparsify(12, trusted, cap=caps).tolist() == [0, 3, 6, 9, 11]
    assert sparsify(12, trusted, cap=hop_caps(xy, 0.1)).tolist() == list(range(12))
    # RE's own limit still holds under a longer cap
    assert sparsify(12, lambda i, js: np.where(js - i <= 2, 0.999, 0.1),
                    cap=caps).tolist() == [0, 2, 4, 6, 8, 10, 11]


def test_bad_arguments():
    with pytest.raises(TopodrakeError, match="empty"):
        sparsify(0, lambda i, js: js)
    with pytest.raises(TopodrakeError, match="p_sparsify"):
        sparsify(5, lambda i, js: js, p=1.0)
    with pytest.raises(TopodrakeError, match="returned"):
        sparsify(5, lambda i, js: np.ones(1), window=3)
    with pytest.raises(TopodrakeError, match="slack"):
        sparsify(5, lambda i, js: js, slack=-0.1)
