"""Nothing lost: writers lock their outputs, never replace a map, plot or
recording without --force (or --add), and keep the interrupted builds of
other places beside the map."""

import json
import subprocess
import sys
from pathlib import Path

import pytest
from filelock import FileLock

from cli_run import one_line, run
from test_cli_map_build import BUILD, interrupt_at
from topodrake.apps.outputs import lock_path

POSE = ["--start", "16.42,14.88,2.95", "--goal", "8.22,14.08,-0.2"]
PNG = b"\x89PNG\r\n\x1a\n" + b"\0" * 32
HTML = b"<!DOCTYPE html><html>my notes</html>"


def _argv(argv, target):
    return [str(target) if a == "{OUT}" else a for a in argv]


#: (command line with {OUT} where the locked output goes, the output's name)
WRITERS = [
    (["map", "build", "test-0", "--modality", "oracle", "--places", "4,9", "--out", "{OUT}",
      "--force", "--quiet"], "m.tdmap"),
    (["map", "build", "test-0", "--modality", "oracle", "--places", "4,9", "--out", "{OUT}",
      "--add", "--quiet"], "m.tdmap"),
    (["world", "plot", "test-0", "--out", "{OUT}", "--force"], "w.png"),
    (["map", "plot", "nothere.tdmap", "--out", "{OUT}", "--force"], "p.png"),
    (["map", "plan", "nothere.tdmap", *POSE, "--plot", "{OUT}", "--force"], "p.png"),
    (["navigate", "test-0", *POSE, "--plot", "{OUT}", "--force"], "n.png"),
    (["navigate", "test-0", *POSE, "--meshcat", "{OUT}", "--force"], "n.html"),
    (["demo", "--out", "{OUT}", "--force"], "demo"),
]
IDS = [" ".join(argv[:2]) + (" --add" if "--add" in argv else "") for argv, _ in WRITERS]


@pytest.mark.parametrize("argv, name", WRITERS, ids=IDS)
def test_lock_a_locked_output_is_refused_and_left_as_it_is(capsys, tmp_path, argv, name):
    """Another process holds the output's lock: one line, exit 2, the output untouched."""
    target = tmp_path / name
    if name == "demo":
        target.mkdir()
        (target / "plan.png").write_bytes(PNG)
        before = PNG
    else:
        before = PNG if name.endswith(".png") else HTML if name.endswith(".html") \
            else b"PK\x03\x04 a map"
        target.write_bytes(before)
    with FileLock(lock_path(target)):
        code, out, err = run(capsys, *_argv(argv, target))
    one_line(code, err, str(target), "is being written by another process")
    assert (target / "plan.png" if name == "demo" else target).read_bytes() == before
    assert out == ""


def test_lock_a_second_map_build_is_refused_while_the_first_runs(tmp_path):
    """Two processes: the first holds the map's lock (as a running build
    does); ``topodrake map build`` onto the same --out exits 2 in one line."""
    out = tmp_path / "m.tdmap"
    holder = subprocess.Popen([sys.executable, "-c", (
        "import sys, time\nfrom filelock import FileLock\n"
        f"with FileLock({str(lock_path(out))!r}):\n"
        "    print('held', flush=True)\n    sys.stdin.read()\n")],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "held"
        second = subprocess.run([sys.executable, "-m", "topodrake.apps.cli", "map", "build",
                                 "test-0", "--modality", "oracle", "--places", "4,9", "--out",
                                 str(out), "--quiet"], capture_output=True, text=True,
                                timeout=300)
    finally:
        holder.communicate("", timeout=30)
    lines = second.stderr.strip().splitlines()
    assert second.returncode == 2 and len(lines) == 1, second.stderr
    assert "is being written by another process" in lines[0] and str(out) in lines[0]
    assert not out.exists()


def test_lock_map_build_does_not_replace_a_map_without_add_or_force(capsys, tmp_path, small_map):
    out = tmp_path / "m.tdmap"
    out.write_bytes(small_map("oracle").read_bytes())
    capsys.readouterr()             # building the fixture's map on first use may have spoken
    before = out.read_bytes()
    code, _, err = run(capsys, "map", "build", "test-0", "--modality", "oracle", "--places", "4,9",
                       "--out", out, "--quiet")
    one_line(code, err, str(out), "exists", "--add", "--force")
    assert out.read_bytes() == before


@pytest.mark.parametrize("name, data", [("plan.png", PNG), ("meshcat.html", HTML)])
def test_lock_demo_does_not_replace_a_user_s_file_without_force(capsys, tmp_path, name, data):
    (tmp_path / name).write_bytes(data)
    code, _, err = run(capsys, "demo", "--out", tmp_path)
    one_line(code, err, name, "--force")
    assert (tmp_path / name).read_bytes() == data


def test_lock_demo_replaces_its_own_earlier_outputs(capsys, tmp_path):
    """Files the demo recorded as its own, unchanged since, pass the check (the
    demo then stops at its bad place, after the check); a changed one does not."""
    from topodrake.apps.demo import OWN_OUTPUTS, record_outputs

    for name, data in (("plan.png", PNG), ("meshcat.html", HTML)):
        (tmp_path / name).write_bytes(data)
    record_outputs(tmp_path, [tmp_path / "plan.png", tmp_path / "meshcat.html"])
    assert set(json.loads((tmp_path / OWN_OUTPUTS).read_text())["files"]) == \
        {"plan.png", "meshcat.html"}
    code, _, err = run(capsys, "demo", "--out", tmp_path, "--start-place", "42")
    one_line(code, err, "--start-place")
    (tmp_path / "plan.png").write_bytes(PNG + b"mine now")
    code, _, err = run(capsys, "demo", "--out", tmp_path, "--start-place", "42")
    one_line(code, err, "plan.png exists", "--force")
    assert (tmp_path / "plan.png").read_bytes() == PNG + b"mine now"


def test_lock_demo_help_names_its_own_outputs(capsys):
    from topodrake.apps.demo import OWN_OUTPUTS

    with pytest.raises(SystemExit):
        run(capsys, "demo", "--help")
    text = " ".join(capsys.readouterr().out.split())
    assert OWN_OUTPUTS in text and "--force" in text


def test_lock_the_partial_build_of_other_places_is_kept(capsys, tmp_path, monkeypatch):
    """An interrupted build of places 4,5,9, then a whole build of places 4,9
    onto the same map: the first one's progress stays beside, untouched, and
    resumes when its build runs again."""
    import topodrake.topomap.build as build

    out = tmp_path / "m.tdmap"
    add = interrupt_at(monkeypatch, 4)
    assert run(capsys, *BUILD, "--out", out)[0] == 130
    (first,) = tmp_path.glob(".m.tdmap.*partial")
    kept = first.read_bytes()
    monkeypatch.setattr(build, "add_trajectory", add)
    other = [a if a != "4,5,9" else "4,9" for a in BUILD]
    code, text, err = run(capsys, *[a for a in other if a != "--quiet"], "--out", out)
    assert code == 0 and json.loads(text.strip().splitlines()[-1])["trajectories"] == 2
    assert first.name in err and "kept" in err
    assert list(tmp_path.glob(".m.tdmap.*partial")) == [first] and first.read_bytes() == kept
    out.unlink()
    code, text, _ = run(capsys, *BUILD, "--out", out)
    resumed = json.loads(text)
    assert code == 0 and resumed["resumed"] == 3 and resumed["added"] == 6
    assert not list(tmp_path.glob(".m.tdmap.*partial"))
