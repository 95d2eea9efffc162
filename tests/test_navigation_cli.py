"""``topodrake navigate`` and ``topodrake demo``: input checks and the JSON line."""

import json

import numpy as np
import pytest

from topodrake.apps.cli import main


@pytest.mark.parametrize("extra, message", [
    (["--noise", "-0.1"], "--noise"),
    (["--noise", "nan"], "--noise"),
    (["--seed", "-3"], "--seed"),
    (["--t-max", "0"], "--t-max"),
    (["--p", "1.0"], "--p"),
    (["--replan", "-1"], "--replan"),
    (["--replan", "2"], "--replan needs a map file"),
    (["--update-map"], "--update-map needs a map file"),
])
def test_navigate_refuses_bad_numbers(capsys, extra, message):
    code = main(["navigate", "test-0", "--start", "16.4,14.9,2.95", "--goal", "3.0,23.6,-0.8",
                 *extra])
    err = capsys.readouterr().err.strip()
    assert code == 2 and message in err and len(err.splitlines()) == 1


def test_navigate_refuses_an_unknown_odometry_model(capsys):
    with pytest.raises(SystemExit) as stop:
        main(["navigate", "test-0", "--start", "16.4,14.9,2.95", "--goal", "3.0,23.6,-0.8",
              "--odometry", "gps"])
    err = capsys.readouterr().err.strip().splitlines()
    assert stop.value.code == 2 and "--odometry: invalid choice: 'gps'" in err[-1]


def test_navigate_refuses_a_bad_pose(capsys):
    code = main(["navigate", "test-0", "--start", "16.4,14.9", "--goal", "3.0,23.6,-0.8"])
    err = capsys.readouterr().err
    assert code == 2 and "--start must be X,Y,YAW" in err


def test_navigate_refuses_a_missing_map_file(capsys):
    code = main(["navigate", "nowhere.tdmap", "--start", "1,1,0", "--goal", "2,2,0"])
    assert code == 2 and "nowhere.tdmap" in capsys.readouterr().err


def test_demo_refuses_bad_places(capsys):
    code = main(["demo", "--start-place", "42", "--out", "/tmp/unused-demo"])
    assert code == 2 and "--start-place" in capsys.readouterr().err


@pytest.mark.parametrize("odometry", [None, "perfect"])
def test_navigate_json_prints_the_outcome_keys(capsys, tmp_path, odometry):
    """A short drive of the learned camera follower (time limit 2 s), on
    drifting wheel odometry by default."""
    plot = tmp_path / "nav.png"
    code = main(["navigate", "test-0", "--start", "16.42,14.88,2.95", "--goal", "8.22,14.08,-0.2",
                 "--t-max", "2", "--json", "--plot", str(plot)]
                + ([] if odometry is None else ["--odometry", odometry]))
    out = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert code == 3                        # a drive that did not reach its goal
    assert set(out) == {"outcome", "time_s", "probability", "anchors", "distance_m",
                        "distance_to_goal_m", "odometry"}
    assert out["odometry"] == (odometry or "wheel")
    assert out["outcome"] == "timeout" and out["time_s"] == pytest.approx(2.0)
    assert out["distance_to_goal_m"] > 1.0 and out["anchors"] >= 2
    assert 0.0 < out["probability"] <= 1.0 and out["distance_m"] > 0.1
    assert plot.stat().st_size > 10_000


def test_demo_refuses_a_missing_map_file(capsys):
    code = main(["demo", "--map", "nowhere.tdmap", "--out", "/tmp/unused-demo"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and "nowhere.tdmap" in err and len(err.splitlines()) == 1


def test_map_build_refuses_unknown_places(capsys, tmp_path):
    code = main(["map", "build", "test-0", "--modality", "oracle", "--places", "4,99",
                 "--out", str(tmp_path / "m.tdmap"), "--quiet"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and "no place 99" in err and len(err.splitlines()) == 1
    assert not (tmp_path / "m.tdmap").exists()


def test_navigate_drives_the_registration_controller_with_its_re(capsys):
    """``--controller registration``: the lidar teach-and-repeat C_WP with its
    shipped RE by default; another controller's RE is refused in one line."""
    code = main(["navigate", "test-0", "--start", "16.42,14.88,2.95", "--goal", "8.22,14.08,-0.2",
                 "--controller", "registration", "--t-max", "2", "--json"])
    out = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert code == 3
    assert out["outcome"] == "timeout" and out["time_s"] == pytest.approx(2.0)
    assert 0.0 < out["probability"] <= 1.0 and out["distance_m"] > 0.1
    code = main(["navigate", "test-0", "--start", "16.42,14.88,2.95", "--goal", "8.22,14.08,-0.2",
                 "--controller", "registration", "--reach",
                 "checkpoints/reach_lidar_k5/checkpoint.pt", "--t-max", "2"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and "trained for controller" in err and len(err.splitlines()) == 1


def test_navigate_takes_a_learned_controller_s_own_re(capsys):
    """``--controller`` of a shipped C_WP drives with the RE that ships for it,
    as ``demo`` does (a lidar C_WP never gets the camera RE)."""
    code = main(["navigate", "test-0", "--start", "16.42,14.88,2.95", "--goal", "8.22,14.08,-0.2",
                 "--controller", "checkpoints/lidar_k5/checkpoint.pt", "--t-max", "2", "--json"])
    captured = capsys.readouterr()
    assert code == 3, captured.err
    out = json.loads(captured.out.strip().splitlines()[-1])
    assert out["outcome"] == "timeout" and 0.0 < out["probability"] <= 1.0


def test_demo_takes_the_controller_only_without_a_map(capsys):
    code = main(["demo", "--map", "t0.tdmap", "--controller", "registration",
                 "--out", "/tmp/unused-demo"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and "without --map" in err and len(err.splitlines()) == 1


def test_a_lidar_reg_map_records_and_drives_the_registration_controller(capsys, tmp_path):
    """A map built with the registration C_WP's RE names that controller;
    navigate follows it with the registration C_WP."""
    from topodrake.topomap.mapfile import read_map_meta
    from topodrake.world import load_world

    path = tmp_path / "reg.tdmap"
    assert main(["map", "build", "test-0", "--modality", "lidar_reg", "--places", "4,9",
                 "--out", str(path), "--quiet"]) == 0
    capsys.readouterr()
    ident = read_map_meta(path)["identity"]
    assert ident["controller"] == "registration"
    assert ident["reach"] == "checkpoints/reach_lidar_reg/checkpoint.pt"
    p = load_world("test-0").places
    start, goal = (",".join(f"{v:.4f}" for v in p[i]) for i in (4, 9))
    code = main(["navigate", str(path), "--start", start, "--goal", goal, "--t-max", "2", "--json"])
    out = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert code == 3 and out["outcome"] == "timeout" and out["distance_m"] > 0.1
    assert main(["map", "plan", str(path), "--start", start, "--goal", goal, "--json"]) == 0
    plan = json.loads(capsys.readouterr().out)
    assert plan["anchors"] == out["anchors"] == len(plan["path"]) + 1   # one count of anchors
    # the drive folded into the map file's edges: what it reports is what the file holds
    code = main(["navigate", str(path), "--start", start, "--goal", goal, "--t-max", "25",
                 "--update-map", "--json"])
    out = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    from topodrake.topomap.mapfile import load_map
    from topodrake.topomap.recalibrate import experience_summary
    from topodrake.topomap.sources import make_scorer

    changed = out["updated_edges"]
    assert changed and all(c["p_after"] != c["p_before"] or c["passed"] for c in changed)
    held = experience_summary(load_map(path, make_scorer("lidar_reg")))
    assert held == {"edges_driven": len(changed), "passes": sum(c["passed"] for c in changed),
                    "failures": sum(c["failed"] for c in changed)}
    assert held["passes"] > 0 and (held["failures"] > 0) == (out["outcome"] not in
                                                             ("reached", "timeout"))


def test_demo_drives_the_registration_controller(capsys, tmp_path):
    """The learned demo with ``--controller registration``: the chain of one
    expert drive, sparsified by the registration C_WP's RE, followed in the
    Drake navigation diagram by that controller."""
    code = main(["demo", "--controller", "registration", "--out", str(tmp_path)])
    lines = capsys.readouterr().out.strip().splitlines()
    summary = json.loads(next(line for line in lines if line.startswith("{")))
    assert code == (0 if summary["outcome"] == "reached" else 3)
    assert summary["distance_to_goal_m"] <= 0.54 or summary["outcome"] != "reached"
    assert summary["controller"] == "registration" and summary["anchors"] >= 2
    assert summary["distance_m"] > 1.0 and 0.0 < summary["probability"] <= 1.0
    assert (tmp_path / "plan.png").stat().st_size > 10_000
    assert (tmp_path / "meshcat.html").is_file()


def test_each_shipped_controller_finds_its_shipped_re():
    """Without --reach, a shipped C_WP gets the RE trained for it (the demo's
    ``--controller checkpoints/lidar_k5/checkpoint.pt`` must not pair it
    with the camera RE); a C_WP without a shipped RE is named."""
    from topodrake.errors import TopodrakeError
    from topodrake.topomap.sources import default_reach

    assert default_reach("checkpoints/lidar_k5/checkpoint.pt").parent.name == "reach_lidar_k5"
    assert default_reach("checkpoints/camera_k5/checkpoint.pt").parent.name == "reach_camera_k5"
    assert default_reach("registration").parent.name == "reach_lidar_reg"
    assert default_reach("checkpoints/lidar_k5_scale/checkpoint.pt").parent.name == \
        "reach_lidar_k5_scale"
    assert default_reach("checkpoints/camera_k5_scale/checkpoint.pt").parent.name == \
        "reach_camera_k5_scale"
    with pytest.raises(TopodrakeError, match="no RE ships for the controller"):
        default_reach("checkpoints/camera_k5_dagger/checkpoint.pt")


def test_a_teach_drive_ends_at_its_first_closest_pass_of_the_goal():
    """An expert told to come within 0.1 m of the goal circles it; the teach
    drive ends where it first passed closest within the expert's own 0.27 m."""
    from topodrake.apps.navigate_cli import TEACH_STOP_M, teach_end

    goal = np.array([0.0, 0.0])
    x = np.array([2.0, 1.0, 0.5, 0.26, 0.15, 0.12, 0.2, 0.3, 0.25, 0.1])
    poses = np.column_stack([x, np.zeros_like(x), np.zeros_like(x)])
    assert teach_end(poses, goal) == 5
    assert teach_end(poses[:4], goal) == 3                 # still closing in at the end
    assert teach_end(poses[:3], goal) == 2                 # never within TEACH_STOP_M: the end
    assert x[teach_end(poses, goal)] < TEACH_STOP_M


def test_the_default_demo_plans_on_the_shipped_map_and_reaches(capsys, tmp_path, monkeypatch):
    """``topodrake demo --json`` from any folder: a plan on the shipped map of
    test-0 (card beside it, for the registration C_WP and its RE), driven in
    the Drake diagram to the goal place; one JSON object naming the map."""
    from topodrake.topomap.mapfile import read_map_meta
    from topodrake.topomap.sources import ROOT

    shipped = ROOT / "checkpoints" / "demo_map"
    card = json.loads((shipped / "card.json").read_text())
    meta = read_map_meta(shipped / card["file"])
    assert meta["world"] == card["world"] == "test-0" and meta["version"] == card["format_version"]
    assert (shipped / card["file"]).stat().st_size == card["size_bytes"] <= 10 * 2 ** 20
    monkeypatch.chdir(tmp_path)
    code = main(["demo", "--json", "--out", str(tmp_path / "demo")])
    lines = capsys.readouterr().out.strip().splitlines()
    assert len(lines) == 1
    out = json.loads(lines[0])
    # it arrives with a margin inside the 0.54 m success rule
    assert code == 0 and out["outcome"] == "reached" and out["distance_to_goal_m"] <= 0.44
    assert out["map"].endswith("checkpoints/demo_map/map.tdmap") and out["odometry"] == "wheel"
    assert out["controller"] == "registration" and 0.0 < out["probability"] < 1.0
    assert out["anchors"] > 10 and (tmp_path / "demo" / "plan.png").stat().st_size > 10_000
    # with a controller named the demo follows one expert drive, as before
    from topodrake.apps.demo import add_demo_parser, demo_map
    import argparse

    parser = argparse.ArgumentParser()
    add_demo_parser(parser.add_subparsers())
    assert demo_map(parser.parse_args(["demo", "--controller", "registration"])) is None
    assert demo_map(parser.parse_args(["demo", "--world", "test-1"])) is None
    assert demo_map(parser.parse_args(["demo", "--map", "m.tdmap"])) == "m.tdmap"
