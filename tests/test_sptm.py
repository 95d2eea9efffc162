"""SPTM baseline: the graph rules, localization and planning, the retrieval
network's checkpoint and training data (tiny synthetic data, no rendering)."""

import math

import numpy as np
import pytest
import torch

from topodrake.baselines.retrieval_net import (RetrievalNet, RetrievalNetConfig, RetrievalScorer,
                                               save_retrieval_checkpoint)
from topodrake.baselines.sptm import (SptmConfig, build_sptm_graph, localize, plan_sptm,
                                      subsample, window_quality)
from topodrake.baselines.train_retrieval import (FrameSet, RetrievalDataConfig, auroc,
                                                 sample_pairs)
from topodrake.errors import TopodrakeError


class PlaceNet:
    """Fake retrieval network: an image's feature is its place id (pixel
    [0, 0, 0]); the score of two ids is ``table[a, b]`` (default: 1 when
    the ids are equal, else 0)."""

    def __init__(self, table=None):
        self.table = np.eye(256, dtype=np.float32) if table is None else table

    def encode(self, images):
        return torch.from_numpy(np.asarray(images)[:, 0, 0, 0].astype(np.int64))[:, None]

    def score_features(self, fa, fb):
        return self.table[fa[:, 0].numpy(), fb[:, 0].numpy()]


def drive(places, name="d"):
    places = np.asarray(places, np.int64)
    obs = np.zeros((len(places), 2, 2, 3), np.uint8)
    obs[:, 0, 0, 0] = places
    poses = np.column_stack([places * 0.1, np.zeros(len(places)), np.zeros(len(places))])
    return obs, poses, name


def test_vertices_are_every_20th_frame_and_temporal_edges_stay_in_a_drive():
    assert list(subsample(45, 20)) == [0, 20, 40] and list(subsample(40, 20)) == [0, 20]
    m = build_sptm_graph([drive(np.arange(45), "a"), drive(100 + np.arange(40), "b")], PlaceNet())
    assert list(m.vertex_drive) == [0, 0, 0, 1, 1] and list(m.vertex_frame) == [0, 20, 40, 0, 20]
    edges = {tuple(sorted(e)) for e in m.graph.edges}
    assert edges == {(0, 1), (1, 2), (3, 4)}          # no shortcut: no frame of b looks like a's
    s = m.summary()
    assert (s["vertices"], s["edges"], s["shortcuts"], s["temporal_edges"]) == (5, 3, 0, 3)


def test_window_median_over_aligned_shifts_inside_both_drives():
    seen = {}

    def score(valid):
        seen["valid"] = valid.copy()
        return np.array([1.0, 0.0, 1.0])

    # frames 0 and 2 of 5-frame drives, window 2: shifts -2..2 -> valid where both exist: 0, 1, 2
    q = window_quality(score, np.array([0]), np.array([5]), np.array([2]), np.array([5]), 2)
    assert seen["valid"].tolist() == [[False, False, True, True, True]]
    assert q.tolist() == [1.0]
    even = window_quality(lambda v: np.array([0.98, 0.995, 0.999, 1.0]), np.array([0]),
                          np.array([4]), np.array([0]), np.array([4]), 3)
    assert even[0] == pytest.approx((0.995 + 0.999) / 2)  # numpy's median of an even count


@pytest.mark.parametrize("corrupt, shortcut", [(10, True), (11, False)])
def test_shortcut_needs_the_median_of_the_21_aligned_scores(corrupt, shortcut):
    a = np.arange(60)
    b = np.arange(60).copy()
    b[10:10 + corrupt] = 200                  # frames of b around its vertex 20 look elsewhere
    b[0:10] = 210                             # and its vertex 0 matches nothing
    b[40:] = 220                              # nor its vertex 40
    m = build_sptm_graph([drive(a, "a"), drive(b, "b")], PlaceNet())
    # vertices: a 0, 20, 40 -> 0, 1, 2; b 0, 20, 40 -> 3, 4, 5
    assert m.graph.has_edge(1, 4) is shortcut
    assert len(m.shortcuts) == int(shortcut)
    if shortcut:
        assert m.graph.edges[1, 4]["kind"] == "shortcut"


def test_shortcut_threshold_is_strict_and_same_drive_gap_is_five_vertices():
    table = np.zeros((256, 256), np.float32)
    table[1, 2] = table[2, 1] = 0.99          # exactly the threshold: no shortcut
    table[3, 4] = table[4, 3] = 0.9901
    np.fill_diagonal(table, 1.0)
    places = np.full(130, 50)                 # one drive, vertices at 0, 20, ..., 120 (7)
    places[0:20] = 7                          # vertex 0 ...
    places[80:100] = 7                        # ... looks like vertex 4 (4 apart: too close)
    places[100:120] = 7                       # ... and vertex 5 (5 apart: a loop closure)
    places[20:40] = 8
    m = build_sptm_graph([drive(places, "loop"), drive(np.r_[np.full(20, 1), np.full(20, 3)], "x"),
                          drive(np.r_[np.full(20, 2), np.full(20, 4)], "y")],
                         PlaceNet(table), SptmConfig(shortcut_window=3))
    # loop: vertices 0..6; x: 7 (place 1), 8 (place 3); y: 9 (place 2), 10 (place 4)
    assert m.graph.has_edge(0, 5) and not m.graph.has_edge(0, 4)
    assert not m.graph.has_edge(7, 9)          # 0.99 does not exceed 0.99
    assert m.graph.has_edge(8, 10)
    assert sorted(map(tuple, m.shortcuts[:, :2].astype(int))) == [(0, 5), (8, 10)]


def test_at_most_2000_best_shortcuts():
    assert SptmConfig().max_shortcuts == 2000 and SptmConfig().shortcut_threshold == 0.99
    table = np.ones((256, 256), np.float32)
    table[0, :] = table[:, 0] = 0.995         # pairs with drive 0's place are weaker
    table[0, 0] = 1.0
    drives = [drive([d], f"d{d}") for d in range(71)]    # 71 one-frame drives: 2485 candidates
    m = build_sptm_graph(drives, PlaceNet(table))
    assert len(m.candidates) == 71 * 70 // 2
    assert np.array_equal(m.candidates[:2000], m.shortcuts)
    assert len(m.shortcuts) == 2000 and m.graph.number_of_edges() == 2000
    q = m.shortcuts[:, 2]
    assert np.all(np.diff(q) <= 0) and q.min() == 1.0    # the 70 weaker ones are dropped first
    assert not m.graph.has_edge(0, 1)
    # ties keep the lower (i, j) first: the last kept is the 2000th pair of (1..70) in order
    pairs = [(i, j) for i in range(1, 71) for j in range(i + 1, 71)]
    assert tuple(m.shortcuts[-1, :2].astype(int)) == pairs[1999]
    small = build_sptm_graph(drives, PlaceNet(table), SptmConfig(max_shortcuts=3))
    assert [tuple(r) for r in small.shortcuts[:, :2].astype(int)] == [(1, 2), (1, 3), (1, 4)]


def test_top1_localization_and_a_planned_route():
    a = np.arange(60)
    b = np.r_[np.arange(100, 120), np.arange(20, 40), np.arange(140, 160)]  # b crosses a at 20
    m = build_sptm_graph([drive(a, "a"), drive(b, "b")], PlaceNet(), SptmConfig(shortcut_window=2))
    assert m.graph.has_edge(1, 4) and len(m.shortcuts) == 1
    start, goal = drive([100])[0][0], drive([40])[0][0]
    assert localize(m, start) == (3, 1.0) and localize(m, goal) == (2, 1.0)
    r = plan_sptm(m, start, goal, goal_pose=[4.0, 0.0, 0.0])
    assert r.reachable and r.vertices == [3, 4, 1, 2] and not r.reason
    route = r.route
    assert len(route) == 5 and list(route.vertices) == [3, 4, 1, 2, -1]
    assert route.contexts.shape == (5, 11, 2, 2, 3)
    # vertex 3 is frame 0 of b: its context is frames 0,0,0,0,0,0,3,6,9,12,15 (clamped)
    assert list(route.contexts[0, :, 0, 0, 0]) == [100] * 6 + [103, 106, 109, 112, 115]
    assert list(route.contexts[1, :, 0, 0, 0]) == [105, 108, 111, 114, 117, 20, 23, 26, 29, 32, 35]
    assert np.all(route.contexts[-1, :, 0, 0, 0] == 40)  # the goal repeated
    assert math.isnan(r.probability) and math.isnan(route.probability)
    assert np.all(route.edge_probability == 1.0) and len(route.edge_probability) == 4
    assert np.allclose(route.poses[-1], [4.0, 0.0, 0.0])
    assert np.allclose(route.poses[0], [10.0, 0.0, 0.0])  # metadata: place 100 * 0.1


def test_unreachable_goal_is_a_result_with_a_reason():
    m = build_sptm_graph([drive(np.arange(40), "a"), drive(100 + np.arange(40), "b")], PlaceNet())
    r = plan_sptm(m, drive([0])[0][0], drive([120])[0][0])
    assert not r.reachable and r.route is None
    assert "no path" in r.reason and "vertex 0" in r.reason and "vertex 3" in r.reason
    with pytest.raises(TopodrakeError, match="shape"):
        plan_sptm(m, np.zeros((4, 4, 3), np.uint8), drive([0])[0][0])


def test_retrieval_checkpoint_round_trip_and_refusals(tmp_path):
    torch.manual_seed(0)
    model = RetrievalNet(RetrievalNetConfig(image_size=8, channels=[4, 4, 4], feature=8, hidden=8))
    from topodrake.sensing.config import CameraConfig
    path = save_retrieval_checkpoint(tmp_path / "r" / "checkpoint.pt", model, CameraConfig(),
                                     metrics={"auroc": 0.5})
    net = RetrievalScorer.from_checkpoint(path)
    rng = np.random.default_rng(0)
    a = rng.integers(0, 255, (5, 64, 64, 3), dtype=np.uint8)
    b = rng.integers(0, 255, (5, 64, 64, 3), dtype=np.uint8)
    s = net.score(a, b)
    assert s.shape == (5,) and np.all((s >= 0) & (s <= 1))
    assert np.allclose(s, net.score(b, a), atol=1e-6)      # symmetric by construction
    assert len(net.fingerprint()) == 40
    foreign = tmp_path / "foreign.pt"
    torch.save({"format": "topodrake-place-embedding", "version": 1}, foreign)
    junk = tmp_path / "junk.pt"
    junk.write_bytes(b"not a torch file")
    for bad, msg in ((foreign, "is not a topodrake-sptm-retrieval checkpoint"),
                     (junk, "corrupt"), (tmp_path / "missing.pt", "does not exist")):
        with pytest.raises(TopodrakeError, match=msg) as e:
            RetrievalScorer.from_checkpoint(bad)
        assert "\n" not in str(e.value)


def test_training_pairs_are_labelled_by_time():
    lens = [60, 50, 70]
    frames = FrameSet.from_drives(
        [(np.zeros((n, 8, 8, 3), np.uint8), np.zeros((n, 3)), h) for n, h in zip(lens, [0, 0, 1])], 8)
    cfg = RetrievalDataConfig(train_worlds=["x", "y"], other_house_fraction=0.3)
    a, b, y = sample_pairs(frames, 4000, cfg, np.random.default_rng(0))
    t = np.arange(len(frames.drive)) - frames.drive_start[frames.drive]
    same = frames.drive[a] == frames.drive[b]
    dt = np.abs(t[a] - t[b])
    pos = y == 1
    assert np.all(same[pos]) and np.all(dt[pos] <= 5)
    assert np.all(~same[~pos] | (dt[~pos] > 20))
    assert np.all(same[~pos] | (frames.house[a[~pos]] != frames.house[b[~pos]]))
    assert 0.45 < pos.mean() < 0.55 and 0.2 < (~same[~pos]).mean() < 0.4
    again = sample_pairs(frames, 4000, cfg, np.random.default_rng(0))
    assert all(np.array_equal(u, v) for u, v in zip((a, b, y), again))


def test_auroc():
    assert auroc(np.array([0.1, 0.4, 0.35, 0.8]), np.array([0, 0, 1, 1])) == 0.75
    assert auroc(np.array([0.5, 0.5]), np.array([0, 1])) == 0.5
    assert math.isnan(auroc(np.array([0.5]), np.array([1])))


def test_shipped_config_loads_and_a_bad_one_is_refused(tmp_path):
    from topodrake.baselines.train_retrieval import load_retrieval_config

    cfg = load_retrieval_config("configs/sptm_retrieval.yaml")
    assert cfg.data.positive_max_frames == 5 and cfg.data.negative_min_frames == 20
    assert cfg.threads == 1
    bad = tmp_path / "bad.yaml"
    bad.write_text("data: {positive_max_frames: 30, negative_min_frames: 20}\n")
    with pytest.raises(TopodrakeError, match="negative_min_frames") as e:
        load_retrieval_config(bad)
    assert "\n" not in str(e.value)
