"""The follower's own RE calibration: the file beside an RE checkpoint, and who reads it."""

import json
import shutil

import numpy as np
import pytest

from topodrake.errors import TopodrakeError
from topodrake.fileio import file_sha1
from topodrake.learning.onpolicy.calibration import FollowerCalibrationConfig
from topodrake.learning.onpolicy.platt import SIDECAR, load_follower_platt
from topodrake.navigation.evaluate import route_calibrated

LIDAR = "checkpoints/lidar_k5/checkpoint.pt"
LIDAR_RE = "checkpoints/reach_lidar_k5/checkpoint.pt"


@pytest.fixture
def re_copy(tmp_path):
    """The lidar RE copied into an empty folder (no calibration beside it)."""
    dst = tmp_path / "reach" / "checkpoint.pt"
    dst.parent.mkdir()
    shutil.copy(LIDAR_RE, dst)
    return dst


def _write(re_path, **fields):
    blob = {"format": "topodrake-follower-calibration", "checkpoint_sha1": file_sha1(re_path),
            "follower_platt": [0.5, 0.2]}
    blob.update(fields)
    (re_path.parent / SIDECAR).write_text(json.dumps(blob))


def test_no_file_means_no_follower_calibration(re_copy):
    from topodrake.learning.reachability.estimator import Reachability

    assert load_follower_platt(re_copy) is None
    assert Reachability.from_checkpoint(re_copy, LIDAR).follower_platt is None


def test_the_follower_queries_use_the_calibration_beside_the_checkpoint(re_copy):
    from topodrake.learning.reachability.estimator import Reachability

    plain = Reachability.from_checkpoint(re_copy, LIDAR)
    _write(re_copy, follower_platt=[0.5, 0.2])
    reach = Reachability.from_checkpoint(re_copy, LIDAR)
    assert reach.follower_platt == (0.5, 0.2)
    assert reach.anchor_platt == plain.anchor_platt          # sparsification keeps its own
    p = np.array([0.1, 0.5, 0.9, 0.99])
    z = reach.temperature * np.log(p / (1 - p))
    np.testing.assert_allclose(route_calibrated(reach, p), 1 / (1 + np.exp(-(0.5 * z + 0.2))))
    a, b = plain.anchor_platt
    np.testing.assert_allclose(route_calibrated(plain, p), 1 / (1 + np.exp(-(a * z + b))))


@pytest.mark.parametrize("fields, what", [
    ({"checkpoint_sha1": "0" * 40}, "another"),
    ({"format": "something-else"}, "not a follower calibration"),
    ({"follower_platt": [0.5]}, "not a follower calibration"),
    ({"follower_platt": [-1.0, 0.0]}, "invalid follower_platt"),
])
def test_a_stale_or_malformed_calibration_is_refused(re_copy, fields, what):
    _write(re_copy, **fields)
    with pytest.raises(TopodrakeError, match=what):
        load_follower_platt(re_copy)


def test_a_file_that_is_not_json_is_refused(re_copy):
    (re_copy.parent / SIDECAR).write_text("{not json")
    with pytest.raises(TopodrakeError, match="not a follower calibration"):
        load_follower_platt(re_copy)


def test_config_refuses_empty_worlds_and_counts():
    with pytest.raises(TopodrakeError, match="world"):
        FollowerCalibrationConfig(worlds=()).check()
    with pytest.raises(TopodrakeError, match="must be >= 1"):
        FollowerCalibrationConfig(states_per_world=0).check()


def test_shipped_calibrations_belong_to_their_checkpoints():
    from pathlib import Path

    for path in sorted(Path("checkpoints").glob(f"*/{SIDECAR}")):
        re_path = path.parent / "checkpoint.pt"
        a, b = load_follower_platt(re_path)
        blob = json.loads(path.read_text())
        assert blob["states"] >= 100 and 0 < blob["success_rate"] < 1
        assert blob["ece_fitted"] <= blob["ece_anchor_platt"]
        assert blob["command"].startswith("topodrake train follower-calibration")
