"""Queries by place: ``--start-place``/``--goal-place`` on ``map plan``,
``navigate`` and ``demo``, either form of an end but not both, a place the
world lacks refused in one line, and ``world info`` listing the places."""

import dataclasses
import json

import pytest

from cli_run import one_line, run
from topodrake.world import load_world


@pytest.fixture
def oracle_map(small_map):
    """A small oracle map of test-0 (the drives between places 4 and 9)."""
    return small_map("oracle")


def _pose_text(world, i):
    return ",".join(repr(float(v)) for v in world.places[i])


def test_map_plan_by_place_is_the_plan_by_its_pose(capsys, oracle_map):
    world = load_world("test-0")
    code, out, err = run(capsys, "map", "plan", oracle_map, "--start-place", 4, "--goal-place", 9,
                         "--json")
    assert code == 0, err
    by_place = json.loads(out)
    code, out, _ = run(capsys, "map", "plan", oracle_map, "--start", _pose_text(world, 4),
                       "--goal", _pose_text(world, 9), "--json")
    assert code == 0
    by_pose = json.loads(out)
    assert by_place["reachable"] and by_place["path"] == by_pose["path"]
    assert by_place["probability"] == by_pose["probability"]
    # the forms mix: a pose for one end, a place for the other
    code, out, _ = run(capsys, "map", "plan", oracle_map, "--start", _pose_text(world, 4),
                       "--goal-place", 9, "--json")
    assert code == 0 and json.loads(out)["path"] == by_place["path"]


@pytest.mark.parametrize("argv, words", [
    (["--start", "1,2,0", "--start-place", "1", "--goal-place", "4"],
     ["--start X,Y,YAW", "--start-place N", "not both"]),
    (["--start-place", "1", "--goal", "1,2,0", "--goal-place", "4"], ["--goal-place N", "not both"]),
    (["--start-place", "1"], ["goal is missing", "--goal-place N"]),
    ([], ["start is missing"]),
    (["--start", "1,2", "--goal-place", "4"], ["--start must be X,Y,YAW"]),
])
@pytest.mark.parametrize("command", [["map", "plan", "nowhere.tdmap"],
                                     ["navigate", "nowhere.tdmap"]])
def test_both_or_neither_form_is_one_line(capsys, command, argv, words):
    code, _, err = run(capsys, *command, *argv)
    one_line(code, err, *words)


def test_a_place_the_map_world_lacks_names_the_world(capsys, oracle_map):
    code, _, err = run(capsys, "map", "plan", oracle_map, "--start-place", 1, "--goal-place", 10)
    one_line(code, err, "--goal-place 10", "'test-0'", "10 places", "0..9")


def test_navigate_refuses_a_missing_place_before_driving(capsys, tmp_path):
    plot = tmp_path / "nav.png"
    code, _, err = run(capsys, "navigate", "test-0", "--start-place", 11, "--goal-place", 4,
                       "--plot", plot)
    one_line(code, err, "--start-place 11", "'test-0'", "10 places")
    assert not plot.exists()


def test_a_negative_place_is_refused_by_the_parser(capsys):
    with pytest.raises(SystemExit) as e:
        run(capsys, "navigate", "test-0", "--start-place", -1, "--goal-place", 4)
    err = capsys.readouterr().err
    assert e.value.code == 2 and len(err.strip().splitlines()) == 1
    assert "--start-place" in err and ">= 0" in err


@pytest.mark.parametrize("extra", [[], ["--expert"]])
def test_demo_refuses_a_missing_place_before_any_work(capsys, tmp_path, extra):
    out = tmp_path / "demo"
    code, _, err = run(capsys, "demo", "--goal-place", 10, "--out", out, *extra)
    one_line(code, err, "--goal-place 10", "'test-0'", "10 places")
    assert not (out / "plan.png").exists()


@pytest.mark.parametrize("option", ["--goal-place", "--start-place"])
def test_trials_with_a_missing_place_is_one_line_not_a_traceback(capsys, option):
    code, _, err = run(capsys, "trials", option, 11, "--trials", 1, "--workers", 1)
    one_line(code, err, f"{option} 11", "'test-0'", "10 places")
    assert "Traceback" not in err


def test_world_info_lists_each_place_with_its_index(capsys):
    world = load_world("test-0")
    code, out, _ = run(capsys, "world", "info", "test-0")
    assert code == 0
    lines = out.splitlines()
    head = next(i for i, line in enumerate(lines) if line.startswith("places"))
    assert lines[head].split()[1] == "10"
    rows = lines[head + 1:head + 11]
    for i, row in enumerate(rows):
        index, x, y, yaw = row.split()
        assert index == f"{i}:"
        assert [float(x), float(y), float(yaw)] == pytest.approx(world.places[i], abs=1e-3)


def test_world_info_shows_place_names_where_the_world_has_them(capsys, patch_everywhere):
    base = load_world("test-0")
    names = tuple(f"room-{i}" for i in range(len(base.places)))
    named = dataclasses.replace(base, place_names=names)
    patch_everywhere("topodrake.world.load_world", lambda spec: named)
    code, out, _ = run(capsys, "world", "info", "test-0")
    assert code == 0
    assert any(line.split()[0] == "3:" and line.split()[-1] == "room-3" for line in out.splitlines()
               if line.strip())
    code, out, _ = run(capsys, "world", "info", "test-0", "--json")
    info = json.loads(out)
    assert info["place_names"] == list(names) and len(info["places"]) == len(names)
    assert named.place_list()[2]["name"] == "room-2"
    assert "name" not in base.place_list()[2]


def test_help_names_the_place_options(capsys):
    for command in (["map", "plan"], ["navigate"], ["demo"]):
        with pytest.raises(SystemExit):
            run(capsys, *command, "--help")
        out = capsys.readouterr().out
        assert "--start-place" in out and "--goal-place" in out
