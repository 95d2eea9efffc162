"""studies/trajectory_following.py resumes: finished chains and follows are
kept with the settings that made them (topodrake.navigation.follow_trials)
and reused only under those settings."""

import json

import pytest

from topodrake.navigation import follow_trials


def test_a_rerun_reuses_finished_blocks_and_a_changed_setting_does_not(tmp_path, monkeypatch,
                                                                       load_study):
    study = load_study("trajectory_following")
    args = ["--trajectories", "1", "--worlds", "test-0", "--p", "0.99", "--controllers",
            "lidar_k5", "--data", str(tmp_path / "data"), "--out", str(tmp_path / "out"),
            "--quiet", "--json"]
    assert study.main(args) == 0
    first = json.loads((tmp_path / "out" / "trajectory_following.json").read_text())
    runs = sorted(p.name for p in (tmp_path / "out" / "trajectory_following_runs").iterdir())
    assert runs == ["lidar_k5-chains-p0.99.json", "lidar_k5-p0.99-every%d-test-0-0.json"
                    % first["results"]["lidar_k5"]["points"][0]["every_n"],
                    "lidar_k5-p0.99-noisy-test-0-0.json", "lidar_k5-p0.99-oracle-test-0-0.json",
                    "lidar_k5-p0.99-re-test-0-0.json"]
    summary = first["summary"]["lidar_k5"]
    assert set(summary) == {"cover", "cover_noisy", "cover_subsampled", "cover_oracle",
                            "anchors_per_m"}
    assert 0.0 <= summary["cover_oracle"] <= 1.0

    def no_rendering(self, m):
        raise AssertionError("rendered although every block was cached")

    monkeypatch.setattr(follow_trials.Observations, "__getitem__", no_rendering)
    assert study.main(args) == 0
    again = json.loads((tmp_path / "out" / "trajectory_following.json").read_text())
    assert again["summary"] == first["summary"]
    with pytest.raises(AssertionError, match="rendered"):
        study.main(args + ["--noise", "0.2"])          # another noise: nothing is reused


def test_the_run_cache_refuses_other_settings_and_unreadable_files(tmp_path):
    run_cache = follow_trials.RunCache
    cache = run_cache(tmp_path, {"seed": 0})
    cache.put("block", {"p": 0.99}, [1, 2])
    assert cache.get("block", {"p": 0.99}) == [1, 2]
    assert cache.get("block", {"p": 0.98}) is None
    assert run_cache(tmp_path, {"seed": 1}).get("block", {"p": 0.99}) is None
    (tmp_path / "block.json").write_text("{not json")
    assert cache.get("block", {"p": 0.99}) is None
    assert cache.get("missing", {"p": 0.99}) is None


def test_another_c_wp_is_named_per_controller_and_checked(tmp_path, load_study, capsys):
    study = load_study("trajectory_following")
    args = ["--controllers", "lidar_k5", "--out", str(tmp_path), "--quiet"]
    assert study.main(args + ["--cwp", "camera_k5=checkpoints/camera_k5/checkpoint.pt"]) == 2
    assert "NAME=CHECKPOINT with NAME one of ['lidar_k5']" in capsys.readouterr().err
    assert study.main(args + ["--cwp", f"lidar_k5={tmp_path / 'none.pt'}"]) == 2
    assert "does not exist" in capsys.readouterr().err


def test_another_re_is_named_per_controller_and_must_fit_its_c_wp(tmp_path, load_study, capsys):
    study = load_study("trajectory_following")
    args = ["--controllers", "lidar_k5", "--out", str(tmp_path), "--quiet", "--trajectories", "1"]
    assert study.main(args + ["--re", "camera_k5=checkpoints/reach_camera_k5/checkpoint.pt"]) == 2
    assert "NAME=CHECKPOINT with NAME one of ['lidar_k5']" in capsys.readouterr().err
    assert study.main(args + ["--re", f"lidar_k5={tmp_path / 'none.pt'}"]) == 2
    assert "does not exist" in capsys.readouterr().err
    # the on-policy RE belongs to the on-policy C_WP: with the shipped one it is refused
    assert study.main(args + ["--re", "lidar_k5=checkpoints/reach_lidar_k5_dagger/checkpoint.pt"]) == 2
    assert "was trained for controller" in capsys.readouterr().err


def test_the_oracle_with_a_controlled_error_follows_the_re_chains(tmp_path, load_study, capsys):
    """``--cwp NAME=oracle:...`` beside NAME's learned RE, and the sensitivity
    table: the same spec gives the same cover in both."""
    study = load_study("trajectory_following")
    args = ["--trajectories", "1", "--worlds", "test-0", "--p", "0.99", "--controllers",
            "lidar_k5", "--data", str(tmp_path / "data"), "--out", str(tmp_path / "out"),
            "--quiet", "--json", "--cwp", "lidar_k5=oracle:anchor=0.3"]
    assert study.main(args + ["--sensitivity", "anchor=0.3,1"]) == 0
    printed = json.loads(capsys.readouterr().out)
    table = printed["sensitivity"]["lidar_k5"]
    assert [r["spec"] for r in table["rows"]] == ["oracle:anchor=0.3", "oracle:anchor=1"]
    assert table["rows"][0]["cover"] == printed["lidar_k5"]["cover"]
    assert table["rows"][0]["trajectories"] == 1
    stored = json.loads((tmp_path / "out" / "trajectory_following.json").read_text())
    assert stored["sensitivity"] == printed["sensitivity"]
    assert stored["results"]["lidar_k5"]["controller"] == "oracle:anchor=0.3"
    assert study.main(args + ["--sensitivity", "bias=0.3"]) == 2
    assert "unknown key 'bias'" in capsys.readouterr().err


def test_runs_picks_what_is_followed_and_refuses_unknown_runs(tmp_path, load_study, capsys):
    study = load_study("trajectory_following")
    args = ["--trajectories", "1", "--worlds", "test-0", "--p", "0.99", "--controllers",
            "lidar_k5", "--data", str(tmp_path / "data"), "--out", str(tmp_path / "out"),
            "--quiet", "--json"]
    assert study.main(args + ["--runs", "re,bogus"]) == 2
    assert "--runs" in capsys.readouterr().err
    assert study.main(args + ["--runs", "re,oracle", "--odometry", "perfect"]) == 0
    runs = sorted(p.name for p in (tmp_path / "out" / "trajectory_following_runs").iterdir())
    assert runs == ["lidar_k5-chains-p0.99.json", "lidar_k5-p0.99-oracle-test-0-0.json",
                    "lidar_k5-p0.99-re-test-0-0.json"]
    summary = json.loads((tmp_path / "out" / "trajectory_following.json").read_text())["summary"]
    assert summary["lidar_k5"]["cover_noisy"] is None                   # not run
    assert 0.0 <= summary["lidar_k5"]["cover_oracle"] <= 1.0
