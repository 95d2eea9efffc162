"""Demonstration sets: generation, resumption, refusal of foreign files."""

import json
import os
from pathlib import Path

import numpy as np
import pytest

from topodrake.demonstrations import CollectConfig, collect, load_demos, plan_jobs
from topodrake.errors import TopodrakeError

SAMPLE = str(Path(__file__).parent / "data" / "houseexpo_sample.json")
CONFIG = CollectConfig(protocol="random", count=5, seed=4, noise_std=0.33, chunk_size=2,
                       t_max_s=60.0)


@pytest.fixture(scope="module")
def demo_dir(tmp_path_factory):
    return collect(SAMPLE, tmp_path_factory.mktemp("demos") / "set", CONFIG, progress=False)


def test_collect_stores_every_drive(demo_dir):
    manifest, drives = load_demos(demo_dir)
    assert manifest["jobs"] == 5 and manifest["chunks"] == [f"chunk-{i:05d}.npz" for i in range(3)]
    assert len(drives) == 5
    for d in drives:
        assert len(d.poses) == len(d.controls) + 1 == len(d.waypoints) + 1
        assert np.allclose(d.poses[0], d.start)
        if d.success:
            assert np.hypot(*(d.poses[-1, :2] - d.goal[:2])) < 0.27 and np.isnan(d.goal[2])
    assert sum(d.success for d in drives) >= 4


def test_jobs_are_deterministic():
    from topodrake.world import load_world

    w = load_world(SAMPLE)
    a, b = plan_jobs(w, CONFIG), plan_jobs(w, CONFIG)
    assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])
    assert (np.hypot(*(a[0][:, :2] - a[1]).T) >= CONFIG.min_distance_m).all()
    pairs = plan_jobs(w, CollectConfig(protocol="pairs"))
    assert len(pairs[0]) == 90


def test_resume_redoes_only_missing_chunks(demo_dir, tmp_path):
    import shutil

    copy = tmp_path / "copy"
    shutil.copytree(demo_dir, copy)
    manifest = json.loads((copy / "manifest.json").read_text())
    manifest["chunks"].remove("chunk-00001.npz")            # as if interrupted
    (copy / "manifest.json").write_text(json.dumps(manifest))
    (copy / "chunk-00001.npz").unlink()
    before = os.stat(copy / "chunk-00000.npz").st_mtime_ns
    collect(SAMPLE, copy, CONFIG, progress=False)
    assert os.stat(copy / "chunk-00000.npz").st_mtime_ns == before
    _, original = load_demos(demo_dir)
    _, resumed = load_demos(copy)
    assert len(resumed) == len(original)
    by_seed = {d.seed: d for d in resumed}
    for d in original:      # same seeds give the same drives
        assert np.array_equal(by_seed[d.seed].poses, d.poses)


def test_other_config_in_same_folder_is_refused(demo_dir):
    with pytest.raises(TopodrakeError, match="another world or config"):
        collect(SAMPLE, demo_dir, CollectConfig(protocol="random", count=7), progress=False)


def test_foreign_and_corrupt_files_are_refused(demo_dir, tmp_path):
    import shutil

    with pytest.raises(TopodrakeError, match="no manifest"):
        load_demos(tmp_path)
    (tmp_path / "manifest.json").write_text("{not json")
    with pytest.raises(TopodrakeError, match="not valid JSON"):
        load_demos(tmp_path)
    (tmp_path / "manifest.json").write_text(json.dumps({"format": "something-else"}))
    with pytest.raises(TopodrakeError, match="not a topodrake-demos"):
        load_demos(tmp_path)
    (tmp_path / "manifest.json").write_text(json.dumps({"format": "topodrake-demos", "version": 99}))
    with pytest.raises(TopodrakeError, match="version 99"):
        load_demos(tmp_path)
    bad = tmp_path / "bad"
    shutil.copytree(demo_dir, bad)
    (bad / "chunk-00002.npz").write_bytes(b"PK\x03\x04 truncated")
    with pytest.raises(TopodrakeError, match="chunk-00002.npz"):
        load_demos(bad)


def test_pairs_drives_arrive_at_the_goal_place_pose(tmp_path):
    """Places are poses: every ordered-pair drive ends at its goal place's
    position and heading, so its last view is the place's view."""
    from topodrake.expert.approach import wrap
    from topodrake.world import load_world

    config = CollectConfig(protocol="pairs", chunk_size=45)
    folder = collect(SAMPLE, tmp_path / "pairs", config, progress=False)
    _, drives = load_demos(folder)
    places = load_world(SAMPLE).places
    assert len(drives) == len(places) * (len(places) - 1)
    arrived = 0
    for d in drives:
        assert any(np.allclose(d.goal, p) for p in places)
        if d.success:
            arrived += 1
            assert np.hypot(*(d.poses[-1, :2] - d.goal[:2])) < 0.27
            assert abs(np.degrees(wrap(d.poses[-1, 2] - d.goal[2]))) < 15.0
    assert arrived >= 0.95 * len(drives)
