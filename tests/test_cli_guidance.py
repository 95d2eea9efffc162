"""Finding one's way: the workflow without arguments, negative values, one
vocabulary, messages that name the real problem, the scenario format in
the docs."""

import argparse
import re
from pathlib import Path

import pytest

from topodrake.apps.argtypes import Parser
from cli_run import one_line, run
from topodrake.apps.cli import build_parser, main

ROOT = Path(__file__).resolve().parents[1]


def test_bare_topodrake_shows_the_workflow(capsys):
    code, out, err = run(capsys)
    assert code == 0 and err == ""
    assert "topodrake demo" in out and "required" not in out
    order = [out.index(step) for step in ("topodrake demo", "topodrake collect",
                                          "topodrake map build", "topodrake map plan",
                                          "topodrake navigate")]
    assert order == sorted(order)


@pytest.mark.parametrize("argv, commands", [
    (["map"], "build, info, plot, plan"),
    (["world"], "list, info, plot"),
    (["bench"], "sensors"),
    (["train"], "waypoint"),
])
def test_a_command_without_its_subcommand_names_them(capsys, argv, commands):
    one_line(*run(capsys, *argv)[::2], commands, "--help")


def test_negative_numbers_are_values(capsys, tmp_path):
    p = Parser(prog="t")
    p.add_argument("--start")
    p.add_argument("--noise", type=float)
    args = p.parse_args(["--start", "-1,-1,0", "--noise", "-1e-3"])
    assert args.start == "-1,-1,0" and args.noise == -1e-3
    with pytest.raises(SystemExit):
        p.parse_args(["--start", "-x"])                 # an option still reads as one
    capsys.readouterr()
    one_line(*run(capsys, "map", "plan", tmp_path / "m.tdmap", "--start", "-1,-1,0",
                  "--goal", "-2.5,3,-0.1")[::2], "m.tdmap does not exist")


def test_navigate_names_an_unknown_controller(capsys):
    code, _, err = run(capsys, "navigate", "t1.tdmap", "--controller", "bogus",
                       "--start", "1,1,0", "--goal", "2,2,0")
    one_line(code, err, "controller bogus is unknown", "registration",
             "checkpoints/camera_k5/checkpoint.pt")
    assert "built for" not in err


def test_map_build_names_a_missing_re(capsys, tmp_path):
    code, _, err = run(capsys, "map", "build", "test-0", "--reach", "nothere.pt",
                       "--out", tmp_path / "m.tdmap")
    one_line(code, err, "RE checkpoint nothere.pt does not exist")
    code, _, err = run(capsys, "map", "build", "test-0", "--controller", "registration",
                       "--out", tmp_path / "m.tdmap", "--places", "4,9")
    one_line(code, err, "--controller needs --reach")


def test_map_build_takes_the_controller_from_the_re():
    from topodrake.topomap.sources import ROOT as INSTALL, reach_controller

    assert reach_controller("checkpoints/reach_lidar_reg/checkpoint.pt") == "registration"
    assert Path(reach_controller("checkpoints/reach_camera_k5/checkpoint.pt")).resolve() == \
        INSTALL / "checkpoints/camera_k5/checkpoint.pt"


def test_map_info_of_a_folder(capsys):
    one_line(*run(capsys, "map", "info", "/proc")[::2], "/proc is a folder, not a map file")


def test_one_name_for_the_controller_and_the_re():
    """Wherever a command takes a C_WP or an RE, --controller and --reach name it."""
    def walk(parser, path="topodrake"):
        yield path, parser
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                for name, sub in action.choices.items():
                    yield from walk(sub, f"{path} {name}")

    for path, parser in walk(build_parser()):
        names = {s for a in parser._actions for s in a.option_strings}
        if names & {"--cwp", "--re"}:
            assert {"--controller", "--reach"} <= names, path


def test_the_documented_scenario_loads(tmp_path):
    from topodrake.systems.scenario import load_scenario

    text = (ROOT / "docs" / "cli.md").read_text()
    block = re.search(r"## The scenario of `topodrake drive`.*?```yaml\n(.*?)```", text, re.S)
    (tmp_path / "s.yaml").write_text(block.group(1))
    scenario = load_scenario(tmp_path / "s.yaml")
    assert scenario.world == "test-0" and scenario.goal_place == 5 and scenario.seed == 7
    assert not scenario.camera_enabled and scenario.lidar.beams == 64


def test_the_drive_help_points_to_the_docs(capsys):
    with pytest.raises(SystemExit):
        main(["drive", "--help"])
    assert "docs/cli.md" in capsys.readouterr().out


def test_a_recording_starts_no_listening_line(caplog):
    import logging

    from topodrake.apps.drive import make_recorder

    with caplog.at_level(logging.INFO, logger="drake"):
        make_recorder()
    assert "listening" not in caplog.text
