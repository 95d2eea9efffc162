"""The C_WP error anatomy bench: length and direction apart, bands, paired differences."""

from __future__ import annotations

import numpy as np
import pytest

from topodrake.errors import TopodrakeError
from topodrake.experiments.waypoint_anatomy import anatomy, bench_waypoint, paired_difference


def _labels(n=400, seed=0):
    rng = np.random.default_rng(seed)
    ang = rng.uniform(-1.0, 1.0, n)
    length = rng.uniform(0.5, 2.5, n)
    label = np.column_stack([length * np.cos(ang), length * np.sin(ang)])
    distance = rng.uniform(-0.5, 3.0, n)
    return label, distance, ang, length


def test_a_waypoint_too_short_has_length_error_only():
    label, distance, _, _ = _labels()
    got = anatomy(0.8 * label, label, distance)
    assert got["direction_error_m"] == pytest.approx(0.0, abs=1e-6)
    assert got["angle_error_deg"] == pytest.approx(0.0, abs=1e-4)
    assert got["length_error_m"] == pytest.approx(got["error_m"], rel=1e-3)
    assert got["length_error_m"] == pytest.approx(0.2 * np.linalg.norm(label, axis=1).mean(), rel=1e-3)


def test_a_turned_waypoint_has_direction_error_only():
    label, distance, ang, length = _labels()
    turned = np.column_stack([length * np.cos(ang + 0.2), length * np.sin(ang + 0.2)])
    got = anatomy(turned, label, distance)
    assert got["length_error_m"] == pytest.approx(0.0, abs=1e-6)
    assert got["angle_error_deg"] == pytest.approx(np.degrees(0.2), rel=1e-4)
    assert got["direction_error_m"] == pytest.approx(got["error_m"], rel=1e-4)


def test_bands_split_the_samples_and_the_tail_share_is_counted():
    label, distance, _, _ = _labels()
    pred = label.copy()
    far = distance >= 2.0
    pred[far] += [1.0, 0.0]                     # only far targets are off, by 1 m
    got = anatomy(pred, label, distance)
    assert sum(b["share"] for b in got["bands"].values()) == pytest.approx(1.0, abs=0.01)
    assert got["bands"]["2..3"]["error_m"] == pytest.approx(1.0, abs=1e-5)
    assert got["bands"]["0..1"]["error_m"] == pytest.approx(0.0, abs=1e-6)
    assert got["median_m"] == pytest.approx(0.0, abs=1e-6)      # fewer than half are off
    assert got["worst_tenth_share"] == pytest.approx(min(1.0, 40 / far.sum()), abs=0.01)
    with pytest.raises(ValueError, match="no samples"):
        anatomy(np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0))


def test_paired_difference_sees_a_shift_and_not_noise():
    rng = np.random.default_rng(1)
    a = rng.exponential(0.2, 3000)
    shifted = paired_difference(a, a + 0.01 + rng.normal(0, 0.005, 3000))
    assert shifted["ci95_m"][0] > 0.0 and shifted["mean_m"] == pytest.approx(0.01, abs=0.001)
    same = paired_difference(a, a + rng.normal(0, 0.05, 3000))
    assert same["ci95_m"][0] < 0.0 < same["ci95_m"][1]


def test_shipped_lidar_cwp_points_where_the_labels_point(test0_drives):
    from topodrake.learning.checkpoint import load_checkpoint
    from topodrake.learning.samples import make_samples
    from topodrake.experiments.waypoint_anatomy import predict_waypoints

    _, drives = test0_drives
    samples = make_samples(drives, 60, 1)
    ck = load_checkpoint("checkpoints/lidar_k5_scale/checkpoint.pt")
    pred = predict_waypoints(ck, samples)
    got = anatomy(pred, np.asarray(samples.waypoint), np.asarray(samples.distance))
    # a C_WP whose inputs or frames were mixed up points anywhere: 90 deg on average
    assert got["angle_error_deg"] < 25.0 and got["median_m"] < 0.4


def test_bench_refuses_no_checkpoint_and_other_outputs(tmp_path):
    with pytest.raises(TopodrakeError, match="at least one"):
        bench_waypoint([], ["test-0"], data=str(tmp_path))
    with pytest.raises(TopodrakeError, match="not a waypoint C_WP"):
        bench_waypoint(["checkpoints/direct_k0/checkpoint.pt"], ["test-0"], data=str(tmp_path))
