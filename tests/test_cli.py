"""The command line: outputs, and one-line errors with exit status 2."""

import json
import shutil

import numpy as np
import pytest

from topodrake.apps.cli import main
from topodrake.world import load_world

MAPS = __import__("pathlib").Path(__file__).parent / "data" / "maps"


def run(capsys, *argv):
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def assert_one_line_error(code, err, *words):
    assert code == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("topodrake: error:")
    for w in words:
        assert w in lines[0]


def test_world_list(capsys):
    code, out, _ = run(capsys, "world", "list", "--json")
    names = json.loads(out)
    assert code == 0 and len(names) == 106 and names[-1] == "calib-4"
    assert names[:2] == ["train-00", "train-01"] and "test-4" in names


def test_world_list_adds_the_maps_of_a_folder(capsys, tmp_path):
    for name in ("lab", "attic"):
        (tmp_path / name).mkdir()
        (tmp_path / name / "map.yaml").write_text("image: map.pgm\n")
    (tmp_path / "notes").mkdir()
    code, out, _ = run(capsys, "world", "list", "--maps", str(tmp_path), "--json")
    names = json.loads(out)
    assert code == 0 and len(names) == 108 and names[-2:] == [
        str(tmp_path / "attic" / "map.yaml"), str(tmp_path / "lab" / "map.yaml")]
    code, _, err = run(capsys, "world", "list", "--maps", str(tmp_path / "notes"))
    assert code == 2 and "no */map.yaml" in err
    code, _, err = run(capsys, "world", "list", "--maps", str(tmp_path / "gone"))
    assert code == 2 and "no such folder" in err


def test_world_info_json(capsys):
    code, out, _ = run(capsys, "world", "info", "test-1", "--json")
    info = json.loads(out)
    assert code == 0
    assert 200 <= info["free_area_m2"] <= 460
    (x0, y0), (x1, y1) = info["bbox_m"]
    assert x1 > x0 and y1 > y0
    assert info["walls"] > 20 and len(info["places"]) == 10
    for x, y, _ in info["places"]:
        assert x0 <= x <= x1 and y0 <= y <= y1


def test_world_info_of_a_real_map(capsys):
    code, out, _ = run(capsys, "world", "info", str(MAPS / "yujin_rnd_extended" / "map.yaml"), "--json")
    assert code == 0 and json.loads(out)["free_area_m2"] > 50


def test_world_plot_writes_png(capsys, tmp_path):
    out_png = tmp_path / "plan.png"
    code, out, _ = run(capsys, "world", "plot", "test-0", "--out", str(out_png), "--astar", "0", "3")
    assert code == 0 and out_png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_unknown_world(capsys):
    assert_one_line_error(*run(capsys, "world", "info", "castle-9")[::2], "castle-9")


def test_bad_place_index(capsys, tmp_path):
    code, _, err = run(capsys, "world", "plot", "test-0", "--out", str(tmp_path / "x.png"),
                       "--astar", "0", "99")
    assert_one_line_error(code, err, "99")


@pytest.mark.parametrize("text, words", [
    ("image: [unclosed\n", ["map.yaml"]),
    ("image: missing.pgm\nresolution: 0.05\norigin: [0, 0, 0]\n", ["missing.pgm"]),
])
def test_malformed_map_files(capsys, tmp_path, text, words):
    (tmp_path / "map.yaml").write_text(text)
    code, _, err = run(capsys, "world", "info", str(tmp_path / "map.yaml"))
    assert_one_line_error(code, err, *words)


def test_truncated_map_image(capsys, tmp_path):
    src = MAPS / "yujin_rnd_extended"
    shutil.copy(src / "map.yaml", tmp_path / "map.yaml")
    data = (src / "yujin_rnd_extended.png").read_bytes()
    (tmp_path / "yujin_rnd_extended.png").write_bytes(data[: len(data) // 2])
    code, _, err = run(capsys, "world", "info", str(tmp_path / "map.yaml"))
    assert_one_line_error(code, err, "yujin_rnd_extended.png")


def test_map_without_free_space(capsys, tmp_path):
    from PIL import Image

    Image.fromarray(np.zeros((40, 40), np.uint8)).save(tmp_path / "black.png")
    (tmp_path / "map.yaml").write_text(
        "image: black.png\nresolution: 0.05\norigin: [0, 0, 0]\nnegate: 0\n"
        "occupied_thresh: 0.65\nfree_thresh: 0.196\n")
    code, _, err = run(capsys, "world", "info", str(tmp_path / "map.yaml"))
    assert_one_line_error(code, err, "free")


def test_drive_scenario_yaml(capsys, tmp_path):
    sc = tmp_path / "s.yaml"
    sc.write_text("world: test-0\nstart_place: 0\ngoal_place: 5\nnoise_std: 0.33\n"
                  "seed: 3\ncamera_enabled: false\n")
    code, out, _ = run(capsys, "drive", str(sc))
    summary = json.loads(out)
    assert code == 0 and summary["outcome"] == "reached"
    assert summary["distance_to_goal_m"] < 0.27
    # the driven length, as navigate and the learned demo print it
    start, goal = (np.array(load_world("test-0").places[i][:2]) for i in (0, 5))
    assert summary["distance_m"] >= np.hypot(*(goal - start)) - 0.6


@pytest.mark.parametrize("text, words", [
    ("world: test-0\nstart_plaec: 1\n", ["start_plaec"]),          # unknown key
    ("world: test-0\nseed: [1, 2\n", ["s.yaml"]),                   # broken YAML
    ("world: test-0\nstart: [5.1, 0.0, 0.0]\n", ["start", "collision"]),  # start in a wall
    ("world: test-0\ngoal: [500.0, 3.0]\n", ["goal", "outside"]),   # goal off the map
    ("world: no-such-house\n", ["no-such-house"]),
])
def test_bad_scenarios(capsys, tmp_path, text, words):
    (tmp_path / "s.yaml").write_text(text)
    code, _, err = run(capsys, "drive", str(tmp_path / "s.yaml"))
    assert_one_line_error(code, err, *words)


def test_missing_scenario_file(capsys, tmp_path):
    code, _, err = run(capsys, "drive", str(tmp_path / "nope.yaml"))
    assert_one_line_error(code, err, "nope.yaml")


def test_demo_writes_plan_camera_strip_and_meshcat_recording(capsys, tmp_path):
    code, out, _ = run(capsys, "demo", "--expert", "--start-place", "0", "--goal-place", "5",
                       "--out", str(tmp_path), "--meshcat")
    assert code == 0
    summary = json.loads(out.strip().splitlines()[-1])
    assert summary["outcome"] == "reached" and summary["distance_to_goal_m"] < 0.27
    assert summary["distance_m"] > 1.0
    for name in ("plan.png", "camera.png"):
        assert (tmp_path / name).read_bytes()[:4] == b"\x89PNG"
    html = (tmp_path / "meshcat.html").read_text()
    assert "<html" in html.lower() and len(html) > 10_000


def test_demo_with_people_reports_the_changes_and_records_the_walker(capsys, tmp_path,
                                                                   monkeypatch):
    """The learned demo in a changed house (cut to 5 s of driving)."""
    import base64
    import re

    import topodrake.apps.demo as demo

    drive = demo.drive_route

    def short(scenario, *args, **kwargs):
        scenario.t_max_s = 5.0
        return drive(scenario, *args, **kwargs)

    monkeypatch.setattr(demo, "drive_route", short)
    code, out, _ = run(capsys, "demo", "--people", "1", "--json", "--out", str(tmp_path))
    summary = json.loads(out)
    assert summary["changes"] == "people=1"
    assert summary["placed"] == {"boxes": None, "block": None}
    assert summary["outcome"] == "timeout" and code == 3
    html = (tmp_path / "meshcat.html").read_text()
    blobs = b"".join(base64.b64decode(b) for b in
                     re.findall(r"octet-binary;base64,([A-Za-z0-9+/=]+)", html))
    assert b"/topodrake/changes/walkers/0" in blobs


@pytest.mark.parametrize("argv, words", [
    (["--people", "-1"], ["--people", ">= 0", "-1"]),
    (["--boxes", "two"], ["--boxes", "two"]),
    (["--expert", "--people", "1"], ["--people", "--expert"])])
def test_demo_refuses_bad_changes_in_one_line(capsys, tmp_path, argv, words):
    try:
        code = main(["demo", "--out", str(tmp_path), *argv])
    except SystemExit as e:        # an option's type: argparse's own exit
        code = e.code
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1 and "error:" in lines[0]
    for w in words:
        assert w in lines[0]


def test_trials_on_a_local_pool(capsys):
    code, out, _ = run(capsys, "trials", "--trials", "2", "--workers", "2", "--json",
                       "--start-place", "2", "--goal-place", "8")
    summary = json.loads(out.strip().splitlines()[-1])
    assert code == 0 and summary["trials"] == 2 and summary["reached_rate"] == 1.0
    assert 0 <= summary["mean_distance_to_goal_m"] < 0.54
