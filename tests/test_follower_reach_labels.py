"""Reachability labels from the follower's own states, and their training config."""

import json

import numpy as np
import pytest

from topodrake.errors import TopodrakeError
from topodrake.learning.onpolicy.reach_labels import FollowerStateLabels, label_follower_states
from topodrake.learning.reachability.labels import load_reach_labels

LIDAR = "checkpoints/lidar_k5/checkpoint.pt"
LIDAR_RE = "checkpoints/reach_lidar_k5/checkpoint.pt"
IDENT = {"checkpoint": LIDAR, "sha1": "c" * 40}
REACH_IDENT = {"checkpoint": LIDAR_RE, "sha1": "r" * 40}


@pytest.fixture(scope="module")
def drives(test0_drives):
    """Two expert drives of test-0 as a TrajectorySet."""
    return test0_drives[1]


@pytest.fixture(scope="module")
def networks():
    from topodrake.learning.reachability.estimator import Reachability
    from topodrake.learning.waypoint.policy import LearnedWaypointPolicy

    return LearnedWaypointPolicy.from_checkpoint(LIDAR), Reachability.from_checkpoint(LIDAR_RE, LIDAR)


@pytest.fixture(scope="module")
def labelled(drives, networks, tmp_path_factory):
    policy, reach = networks
    out = tmp_path_factory.mktemp("follower-labels") / "set"
    label_follower_states(drives, policy, reach, out, 16, seed=4, controller=IDENT,
                          reach_identity=REACH_IDENT, drives_per_world=2, next_share=0.5,
                          progress=False)
    return out


def test_sources_are_visited_states_and_targets_the_anchors_aimed_at(drives, labelled):
    labels = load_reach_labels(labelled)
    assert 8 <= len(labels) <= 16
    assert set(np.unique(labels.label)) <= {0, 1}
    assert labels.same.all()
    t = labels.trajectories
    for i in range(len(labels)):
        drive = t.poses[t.rows(int(labels.traj[i]))]
        assert 0 <= labels.tgt[i] < len(drive)
        # src names the drive's frame nearest the visited state
        d = np.hypot(*(drive[:, :2] - labels.src_pose[i, :2]).T)
        assert labels.src[i] == int(np.argmin(d))
    # followed cars are not all on the drive's frames: some sources lie off them
    off = [np.hypot(*(t.poses[t.traj_offsets[labels.src_traj[i]] + labels.src[i], :2]
                      - labels.src_pose[i, :2])) for i in range(len(labels))]
    assert max(off) > 0.02
    manifest = json.loads((labelled / "manifest.json").read_text())
    assert manifest["follower_states"]["reach"] == REACH_IDENT
    assert manifest["follower_states"]["next_share"] == 0.5


def test_a_finished_house_is_not_labelled_again_and_other_settings_are_refused(
        drives, networks, labelled):
    policy, reach = networks
    chunk = labelled / "000-00000.npz"
    before = chunk.stat().st_mtime_ns
    label_follower_states(drives, policy, reach, labelled, 16, seed=4, controller=IDENT,
                          reach_identity=REACH_IDENT, drives_per_world=2, next_share=0.5,
                          progress=False)
    assert chunk.stat().st_mtime_ns == before
    with pytest.raises(TopodrakeError, match="follower_states"):
        label_follower_states(drives, policy, reach, labelled, 16, seed=4, controller=IDENT,
                              reach_identity=REACH_IDENT, drives_per_world=2, next_share=0.2,
                              progress=False)
    with pytest.raises(TopodrakeError, match="seed"):
        label_follower_states(drives, policy, reach, labelled, 16, seed=5, controller=IDENT,
                              reach_identity=REACH_IDENT, drives_per_world=2, next_share=0.5,
                              progress=False)


def _config(**follower):
    from topodrake.learning.reachability.train import ReachTrainConfig

    cfg = ReachTrainConfig(controller=LIDAR, init=LIDAR_RE)
    cfg.labels.follower = [FollowerStateLabels(**follower)]
    return cfg


def test_the_training_config_checks_follower_label_sets():
    _config(worlds=["train-60"]).validate()
    with pytest.raises(TopodrakeError, match="seed of its own"):
        _config(seed=0).validate()
    with pytest.raises(TopodrakeError, match="outside data.val_worlds"):
        _config(worlds=["test-0"]).validate()
    with pytest.raises(TopodrakeError, match="next_share"):
        _config(next_share=1.5).validate()
    cfg = _config()
    cfg.init = "controller"
    with pytest.raises(TopodrakeError, match="needs reach"):
        cfg.validate()
    cfg.labels.follower[0].reach = LIDAR_RE
    cfg.validate()
