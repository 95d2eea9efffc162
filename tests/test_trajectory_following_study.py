"""studies/trajectory_following.py resumes: finished chains and follows are
kept with the settings that made them (topodrake.experiments.follow_trials)
and reused only under those settings."""

import json

import pytest

from study_run import run_study
from topodrake.experiments import follow_trials
from topodrake.experiments.follow_scenario import FollowingScenario
from topodrake.experiments.follow_study import following


def _follow(tmp_path, command="test", **changed) -> dict:
    """The library's run of the scenario the study's command line
    ``--trajectories 1 --worlds test-0 --p 0.99 --controllers lidar_k5 --data
    TMP/data --out TMP/out --quiet`` gives, with ``changed`` fields."""
    sc = FollowingScenario(**{"trajectories": 1, "worlds": ["test-0"], "p": [0.99],
                              "controllers": ["lidar_k5"], "data": str(tmp_path / "data"),
                              **changed})
    return following(sc, command, tmp_path / "out", quiet=True)


def _refused(*argv) -> str:
    """The error of a study run refused with exit status 2."""
    code, _, err = run_study("trajectory_following", *argv)
    assert code == 2
    return err


def test_a_rerun_reuses_finished_blocks_and_a_changed_setting_does_not(tmp_path, monkeypatch):
    """The study's run, then the library's run of the same options: every
    block comes from the run cache."""
    args = ["--trajectories", "1", "--worlds", "test-0", "--p", "0.99", "--controllers",
            "lidar_k5", "--data", str(tmp_path / "data"), "--out", str(tmp_path / "out"),
            "--quiet", "--json"]
    code, _, err = run_study("trajectory_following", *args)
    assert code == 0, err
    first = json.loads((tmp_path / "out" / "trajectory_following.json").read_text())
    runs = sorted(p.name for p in (tmp_path / "out" / "trajectory_following_runs").iterdir())
    assert runs == ["lidar_k5-chains-p0.99.json", "lidar_k5-p0.99-every%d-test-0-0.json"
                    % first["results"]["lidar_k5"]["points"][0]["every_n"],
                    "lidar_k5-p0.99-noisy-test-0-0.json", "lidar_k5-p0.99-oracle-test-0-0.json",
                    "lidar_k5-p0.99-re-test-0-0.json"]
    summary = first["summary"]["lidar_k5"]
    assert set(summary) == {"cover", "cover_noisy", "cover_subsampled", "cover_oracle",
                            "cover_oracle_re", "anchors_per_m"}
    assert summary["cover_oracle_re"] is None                            # not asked for
    assert 0.0 <= summary["cover_oracle"] <= 1.0

    def no_rendering(self, m):
        raise AssertionError("rendered although every block was cached")

    monkeypatch.setattr(follow_trials.Observations, "__getitem__", no_rendering)
    again = _follow(tmp_path, "python studies/trajectory_following.py")
    assert again["summary"] == first["summary"]
    assert first["scenario"] == again["scenario"] and first["scenario"]["p"] == [0.99]
    with pytest.raises(AssertionError, match="rendered"):
        _follow(tmp_path, noise=0.2)                   # another noise: nothing is reused


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


def test_another_c_wp_is_named_per_controller_and_checked(tmp_path):
    args = ["--controllers", "lidar_k5", "--out", str(tmp_path), "--quiet"]
    assert "NAME=CHECKPOINT with NAME one of ['lidar_k5']" in _refused(
        *args, "--cwp", "camera_k5=checkpoints/camera_k5/checkpoint.pt")
    assert "does not exist" in _refused(*args, "--cwp", f"lidar_k5={tmp_path / 'none.pt'}")


def test_another_re_is_named_per_controller_and_must_fit_its_c_wp(tmp_path):
    args = ["--controllers", "lidar_k5", "--out", str(tmp_path), "--quiet", "--trajectories", "1"]
    assert "NAME=CHECKPOINT with NAME one of ['lidar_k5']" in _refused(
        *args, "--re", "camera_k5=checkpoints/reach_camera_k5/checkpoint.pt")
    assert "does not exist" in _refused(*args, "--re", f"lidar_k5={tmp_path / 'none.pt'}")
    # the on-policy RE belongs to the on-policy C_WP: with the shipped one it is refused
    assert "was trained for controller" in _refused(
        *args, "--re", "lidar_k5=checkpoints/reach_lidar_k5_dagger/checkpoint.pt")


def test_the_oracle_with_a_controlled_error_follows_the_re_chains(tmp_path):
    """``--cwp NAME=oracle:...`` beside NAME's learned RE, and the sensitivity
    table: the same spec gives the same cover in both."""
    args = ["--trajectories", "1", "--worlds", "test-0", "--p", "0.99", "--controllers",
            "lidar_k5", "--data", str(tmp_path / "data"), "--out", str(tmp_path / "out"),
            "--quiet", "--json", "--cwp", "lidar_k5=oracle:anchor=0.3"]
    code, out, err = run_study("trajectory_following", *args, "--sensitivity", "anchor=0.3,1")
    assert code == 0, err
    printed = json.loads(out)
    table = printed["sensitivity"]["lidar_k5"]
    assert [r["spec"] for r in table["rows"]] == ["oracle:anchor=0.3", "oracle:anchor=1"]
    assert table["rows"][0]["cover"] == printed["lidar_k5"]["cover"]
    assert table["rows"][0]["trajectories"] == 1
    stored = json.loads((tmp_path / "out" / "trajectory_following.json").read_text())
    assert stored["sensitivity"] == printed["sensitivity"]
    assert stored["results"]["lidar_k5"]["controller"] == "oracle:anchor=0.3"
    assert "unknown key 'bias'" in _refused(*args, "--sensitivity", "bias=0.3")


def test_runs_picks_what_is_followed_and_refuses_unknown_runs(tmp_path):
    args = ["--trajectories", "1", "--worlds", "test-0", "--p", "0.99", "--controllers",
            "lidar_k5", "--data", str(tmp_path / "data"), "--out", str(tmp_path / "out"),
            "--quiet", "--json"]
    assert "--runs" in _refused(*args, "--runs", "re,bogus")
    code, _, err = run_study("trajectory_following", *args, "--runs", "re,oracle",
                             "--odometry", "perfect")
    assert code == 0, err
    runs = sorted(p.name for p in (tmp_path / "out" / "trajectory_following_runs").iterdir())
    assert runs == ["lidar_k5-chains-p0.99.json", "lidar_k5-p0.99-oracle-test-0-0.json",
                    "lidar_k5-p0.99-re-test-0-0.json"]
    summary = json.loads((tmp_path / "out" / "trajectory_following.json").read_text())["summary"]
    assert summary["lidar_k5"]["cover_noisy"] is None                   # not run
    assert 0.0 <= summary["lidar_k5"]["cover_oracle"] <= 1.0


def test_the_oracle_re_run_follows_with_the_controller_and_the_geometric_re(tmp_path, monkeypatch, patch_everywhere):
    """``--runs oracle_re``: the controller's own C_WP drives, the geometric
    oracle RE answers the follower, and the chains stay the learned RE's."""
    import topodrake.navigation.engine as engine_module
    from topodrake.navigation.evaluate import GeometricReachability

    made = []
    real = engine_module.NavigationEngine

    class Watched(real):
        def __init__(self, world, policy, reach, config=None):
            made.append((type(policy).__name__, type(reach).__name__))
            super().__init__(world, policy, reach, config)

    patch_everywhere("topodrake.navigation.engine.NavigationEngine", Watched)
    doc = _follow(tmp_path, runs=["re", "oracle_re"], odometry="perfect")
    assert len(made) == 2
    (cwp_re, re_re), (cwp_oracle, re_oracle) = made
    assert cwp_oracle == cwp_re and "Oracle" not in cwp_oracle       # the same learned C_WP
    assert re_oracle == GeometricReachability.__name__ and re_re != re_oracle
    summary = doc["summary"]["lidar_k5"]
    assert 0.0 <= summary["cover_oracle_re"] <= 1.0 and summary["cover_oracle"] is None
    runs = sorted(p.name for p in (tmp_path / "out" / "trajectory_following_runs").iterdir())
    assert "lidar_k5-p0.99-oracle_re-test-0-0.json" in runs


def test_another_re_places_the_anchors_while_the_controllers_re_answers(tmp_path, monkeypatch, patch_everywhere):
    """``--chain-re``: the chains are the placing RE's sparsification, the
    follower asks the controller's RE, and both are recorded."""
    import topodrake.navigation.engine as engine_module

    placed, answered = [], []
    real_chains, real_engine = follow_trials.chains_of, engine_module.NavigationEngine

    def watched_chains(obs, reach, *a, **kw):
        placed.append(reach.name)
        return real_chains(obs, reach, *a, **kw)

    class Watched(real_engine):
        def __init__(self, world, policy, reach, config=None):
            answered.append(reach.name)
            super().__init__(world, policy, reach, config)

    monkeypatch.setattr(follow_trials, "chains_of", watched_chains)
    patch_everywhere("topodrake.navigation.engine.NavigationEngine", Watched)
    dagger = "checkpoints/lidar_k5_dagger/checkpoint.pt"
    doc = _follow(tmp_path, runs=["re"], odometry="perfect", cwp={"lidar_k5": dagger},
                  re={"lidar_k5": "checkpoints/reach_lidar_k5_onpolicy/checkpoint.pt"},
                  chain_re={"lidar_k5": "checkpoints/reach_lidar_k5_dagger/checkpoint.pt"})
    assert placed == ["reach_lidar_k5_dagger"] and answered == ["reach_lidar_k5_onpolicy"]
    result = doc["results"]["lidar_k5"]
    assert result["chain_reach"].endswith("reach_lidar_k5_dagger/checkpoint.pt")
    assert result["reach"].endswith("reach_lidar_k5_onpolicy/checkpoint.pt")


def test_the_placing_re_is_named_per_controller_and_must_fit_its_c_wp(tmp_path):
    args = ["--controllers", "lidar_k5", "--out", str(tmp_path), "--quiet", "--trajectories", "1",
            "--data", str(tmp_path / "data"), "--worlds", "test-0", "--p", "0.99"]
    assert "NAME=CHECKPOINT with NAME one of ['lidar_k5']" in _refused(
        *args, "--chain-re", "camera_k5=checkpoints/reach_camera_k5/checkpoint.pt")
    assert "does not exist" in _refused(*args, "--chain-re", f"lidar_k5={tmp_path / 'none.pt'}")
    assert "was trained for controller" in _refused(
        *args, "--chain-re", "lidar_k5=checkpoints/reach_lidar_k5_dagger/checkpoint.pt")


def test_the_registration_system_places_anchors_with_one_re_and_follows_with_another():
    from topodrake.experiments.follow_study import parse_chain_reach
    from topodrake.experiments.follow_trials import CONTROLLERS

    specs = {"lidar_reg": CONTROLLERS["lidar_reg"], "lidar_k5": CONTROLLERS["lidar_k5"]}
    assert specs["lidar_reg"][1] == "checkpoints/reach_lidar_reg_tracked/checkpoint.pt"
    assert parse_chain_reach(None, specs) == {
        "lidar_reg": "checkpoints/reach_lidar_reg/checkpoint.pt"}
    # another RE under --re does both jobs, unless --chain-re says otherwise
    other = "lidar_reg=checkpoints/reach_lidar_reg/checkpoint.pt"
    assert parse_chain_reach(None, specs, [other]) == {}
    assert parse_chain_reach(["lidar_reg=checkpoints/reach_lidar_reg_tracked/checkpoint.pt"],
                             specs, [other]) == {
        "lidar_reg": "checkpoints/reach_lidar_reg_tracked/checkpoint.pt"}
    assert parse_chain_reach(None, {"lidar_k5": specs["lidar_k5"]}) == {}


def test_the_default_scenario_is_the_default_run_and_flags_change_it():
    import yaml
    from dataclasses import asdict

    from topodrake.experiments.scenarios import load_scenario, scenario_names

    path = "studies/scenarios/trajectory_following.yaml"
    assert load_scenario(FollowingScenario, path, "default") == FollowingScenario()
    for name in scenario_names(path):
        load_scenario(FollowingScenario, path, name)
    code, out, err = run_study("trajectory_following", "--print-config")
    assert code == 0, err
    assert yaml.safe_load(out) == asdict(FollowingScenario())
    check = ["--trajectories", "60", "--controllers", "lidar_reg,lidar_k5_scale", "--p", "0.99"]
    code, out, err = run_study("trajectory_following", *check, "--print-config")
    assert code == 0, err
    assert out == run_study("trajectory_following", "--scenario", "outcome_check",
                            "--print-config")[1]
    code, out, err = run_study("trajectory_following", "--cwp", "lidar_k5=oracle:anchor=0.3",
                               "--follower", '{"legs_m": 0}', "--scenario-text",
                               "{runs: [re], noise: 0.2}", "--print-config")
    sc = yaml.safe_load(out)
    assert code == 0 and sc["cwp"] == {"lidar_k5": "oracle:anchor=0.3"} and sc["runs"] == ["re"]
    assert sc["follower"] == {"legs_m": 0} and sc["noise"] == 0.2
