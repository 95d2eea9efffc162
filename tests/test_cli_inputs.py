"""Bad input answers in one line with exit 2, naming the file, the key and
the line where one exists, before any work: scenarios, training configs."""

import logging

import pytest

from cli_run import one_line, run

CONFIG = "configs/waypoint_camera_k5.yaml"


def _write(tmp_path, name, text):
    path = tmp_path / name
    path.write_text(text)
    return path


@pytest.mark.parametrize("text, words", [
    ("start: [1, 2]\n", ["start", "[x, y, heading]"]),
    ("goal: [1, 2, 3, 4]\n", ["goal", "[x, y]"]),
    ("start: [1, 1, 1.0e300]\n", ["start heading", "angle"]),
    ("start_place: 2\nstart: [1, 1, 0]\n", ["line 2", "start_place or start, not both"]),
    ("goal: [3, 3]\ngoal_place: 4\n", ["line 1", "goal_place or goal, not both"]),
])
def test_bad_scenario_ends_refused(capsys, tmp_path, text, words):
    sc = _write(tmp_path, "s.yaml", text)
    code, _, err = run(capsys, "drive", sc)
    one_line(code, err, str(sc), *words)


def test_scenario_wrong_type_names_key_and_line(capsys, tmp_path):
    sc = _write(tmp_path, "s.yaml", "seed: 3\nnoise_std: lots\n")
    code, _, err = run(capsys, "drive", sc)
    one_line(code, err, str(sc), "line 2", "noise_std", "'lots'")


def test_scenario_nested_wrong_type_names_key_path(capsys, tmp_path):
    sc = _write(tmp_path, "s.yaml", "camera:\n  width: 64\n  hfov_deg: wide\n")
    code, _, err = run(capsys, "drive", sc)
    one_line(code, err, str(sc), "line 3", "camera.hfov_deg")


def test_broken_scenario_yaml_names_line(capsys, tmp_path):
    sc = _write(tmp_path, "s.yaml", "seed: 1\ncamera: {width: 64\n  height: 3\n")
    code, _, err = run(capsys, "drive", sc)
    one_line(code, err, str(sc), "line 3")


def _config(tmp_path, old, new):
    text = open(CONFIG).read()
    assert old in text
    return _write(tmp_path, "c.yaml", text.replace(old, new, 1))


def test_training_config_wrong_type_names_key_path(capsys, tmp_path):
    cfg = _config(tmp_path, "lr: 0.001", "lr: lots")
    line = 1 + open(cfg).read().split("lr: lots")[0].count("\n")
    code, _, err = run(capsys, "train", "waypoint", "--config", cfg, "--out", tmp_path / "o")
    one_line(code, err, str(cfg), f"line {line}", "lr:", "'lots'")


def test_training_config_nested_wrong_type_names_key_path(capsys, tmp_path):
    cfg = _config(tmp_path, "channels: [32, 64, 64]", "channels: 5")
    code, _, err = run(capsys, "train", "waypoint", "--config", cfg, "--out", tmp_path / "o")
    one_line(code, err, str(cfg), "network.channels")
    assert not (tmp_path / "o").exists()


def test_broken_training_config_yaml_names_line(capsys, tmp_path):
    cfg = _config(tmp_path, "lr: 0.001", "lr: [0.001")
    code, _, err = run(capsys, "train", "waypoint", "--config", cfg, "--out", tmp_path / "o")
    one_line(code, err, str(cfg), "line ")


def test_map_build_add_keeps_the_maps_modality(capsys, tmp_path, small_map):
    import shutil

    lidar = tmp_path / "l.tdmap"
    shutil.copy(small_map("lidar"), lidar)
    before = lidar.read_bytes()
    code, _, err = run(capsys, "map", "build", "test-0", "--modality", "camera", "--add",
                       "--out", lidar, "--quiet")
    one_line(code, err, str(lidar), "lidar map", "--modality camera")
    assert lidar.read_bytes() == before


def test_map_build_demos_of_another_world_named(capsys, tmp_path):
    demos = "data/demos/pairs-s0/test-0"
    code, _, err = run(capsys, "map", "build", "test-1", "--demos", demos, "--places", "1,9",
                       "--out", tmp_path / "m.tdmap", "--quiet")
    one_line(code, err, demos, "'test-0'", "not of 'test-1'")


def test_map_info_edge_kinds_sum_to_the_edges(capsys, small_map):
    code, out, err = run(capsys, "map", "info", small_map("oracle"), "--json")
    assert code == 0, err
    info = __import__("json").loads(out)
    assert "junction_edges" in info
    assert info["trajectory_edges"] + info["cross_edges"] + info["junction_edges"] == info["edges"]


@pytest.mark.parametrize("level", ["debug", "info", "warning", "error"])
def test_log_level_configures_logging(capsys, level):
    code, out, err = run(capsys, "--log-level", level, "world", "list")
    assert code == 0, err
    log = logging.getLogger("topodrake.test")
    log.log(getattr(logging, level.upper()), "seen")
    log.debug("debug line")
    _, err = capsys.readouterr()
    assert f"topodrake {level.upper()} topodrake.test: seen" in err
    assert ("debug line" in err) == (level == "debug")


def test_log_level_refuses_other_levels(capsys):
    with pytest.raises(SystemExit) as e:
        run(capsys, "--log-level", "loud", "world", "list")
    assert e.value.code == 2
    assert "--log-level" in capsys.readouterr().err


def test_log_level_documented(capsys):
    with pytest.raises(SystemExit):
        run(capsys, "--help")
    assert "--log-level" in capsys.readouterr().out
    assert "--log-level" in open("docs/cli.md").read()
