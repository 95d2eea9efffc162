"""Every option that writes is checked before the work: one line, exit 2,
nothing written and nothing run; a write that fails after the work keeps
the result elsewhere."""

import json

import pytest

from cli_run import one_line, run
from topodrake.apps.cli import main
from topodrake.errors import TopodrakeError
from topodrake.apps.outputs import check_output, sniff, write_kept

POSE = ["--start", "16.42,14.88,2.95", "--goal", "8.22,14.08,-0.2"]
PNG = b"\x89PNG\r\n\x1a\n" + b"\0" * 32


#: (command line with {OUT} where the target goes, the target's kind)
WRITERS = [
    (["world", "plot", "test-0", "--out", "{OUT}"], "image"),
    (["map", "plot", "nothere.tdmap", "--out", "{OUT}"], "image"),
    (["map", "plan", "nothere.tdmap", *POSE, "--plot", "{OUT}"], "image"),
    (["navigate", "test-0", *POSE, "--plot", "{OUT}"], "image"),
    (["navigate", "test-0", *POSE, "--meshcat", "{OUT}"], "html"),
    (["sparsify", "test-0", "--reach", "r.pt", "--controller", "c.pt", "--plot", "{OUT}"], "image"),
    (["map", "build", "test-0", "--modality", "oracle", "--out", "{OUT}"], "map"),
    (["train", "pack-trajectories", "--out", "{OUT}"], "npz"),
]
SUFFIX = {"image": ".png", "html": ".html", "map": ".tdmap", "npz": ".npz"}
IDS = [" ".join(argv[:2]) + f" {argv[-2]}" for argv, _ in WRITERS]


def _argv(argv, target):
    return [str(target) if a == "{OUT}" else a for a in argv]


@pytest.mark.parametrize("argv, kind", WRITERS, ids=IDS)
def test_an_unwritable_folder_is_refused_first(capsys, argv, kind):
    code, _, err = run(capsys, *_argv(argv, f"/proc/x{SUFFIX[kind]}"))
    one_line(code, err, "cannot write in /proc")


@pytest.mark.parametrize("argv, kind", WRITERS, ids=IDS)
def test_an_unknown_format_is_refused(capsys, tmp_path, argv, kind):
    target = tmp_path / "x.jpgg"
    code, _, err = run(capsys, *_argv(argv, target))
    one_line(code, err, "unknown format '.jpgg'", SUFFIX[kind])
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("argv, kind", WRITERS, ids=IDS)
def test_a_file_where_a_folder_goes_is_refused(capsys, tmp_path, argv, kind):
    blocker = tmp_path / "plan.png"
    blocker.write_bytes(PNG)
    code, _, err = run(capsys, *_argv(argv, blocker / f"x{SUFFIX[kind]}"))
    one_line(code, err, "plan.png is a file, not a folder")
    assert blocker.read_bytes() == PNG


@pytest.mark.parametrize("argv, kind", WRITERS, ids=IDS)
def test_a_folder_where_a_file_goes_is_refused(capsys, tmp_path, argv, kind):
    folder = tmp_path / f"d{SUFFIX[kind]}"
    folder.mkdir()
    code, _, err = run(capsys, *_argv(argv, folder))
    one_line(code, err, "is a folder")


def test_a_map_is_not_written_over_a_png(capsys, tmp_path):
    victim = tmp_path / "victim.tdmap"
    victim.write_bytes(PNG)
    code, _, err = run(capsys, "map", "build", "test-0", "--modality", "oracle", "--out", victim)
    one_line(code, err, "holds a PNG image", "--force")
    assert victim.read_bytes() == PNG
    code, _, err = run(capsys, "map", "build", "test-0", "--modality", "oracle",
                       "--out", tmp_path / "victim.png")
    one_line(code, err, "unknown format '.png'", ".tdmap")


def test_force_overwrites_a_file_of_another_kind(capsys, tmp_path):
    target = tmp_path / "plan.png"
    target.write_text('{"a": 1}')
    code, _, err = run(capsys, "world", "plot", "test-0", "--out", target)
    one_line(code, err, "holds JSON", "--force")
    assert target.read_text() == '{"a": 1}'
    assert run(capsys, "world", "plot", "test-0", "--out", target, "--force")[0] == 0
    assert sniff(target) == "png"


def test_a_png_is_replaced_only_with_force(capsys, tmp_path):
    target = tmp_path / "plan.png"
    target.write_bytes(PNG)
    code, _, err = run(capsys, "world", "plot", "test-0", "--out", target)
    one_line(code, err, "plan.png exists", "--force")
    assert target.read_bytes() == PNG
    assert run(capsys, "world", "plot", "test-0", "--out", target, "--force")[0] == 0
    assert target.stat().st_size > len(PNG)


def test_collect_refuses_an_unrelated_folder(capsys, tmp_path):
    (tmp_path / "notes.txt").write_text("mine")
    code, _, err = run(capsys, "collect", "test-1", "--out", tmp_path)
    one_line(code, err, "holds other files", "--force")
    assert [p.name for p in tmp_path.iterdir()] == ["notes.txt"]
    code, _, err = run(capsys, "collect", "test-1", "--out", tmp_path / "notes.txt")
    one_line(code, err, "is a file, not a folder")
    code, _, err = run(capsys, "collect", "test-1", "--out", "/proc/demos")
    one_line(code, err, "cannot write in /proc")


@pytest.mark.parametrize("out", ["/proc/demo", "{FILE}"])
def test_demo_checks_its_folder_first(capsys, tmp_path, out):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    code, _, err = run(capsys, "demo", "--out", str(blocker) if out == "{FILE}" else out)
    one_line(code, err, "/proc" if out != "{FILE}" else "is a file, not a folder")


def test_demo_refuses_to_overwrite_another_kind_in_its_folder(capsys, tmp_path):
    (tmp_path / "plan.png").write_text("my notes")
    code, _, err = run(capsys, "demo", "--out", tmp_path)
    one_line(code, err, "plan.png", "--force")
    assert (tmp_path / "plan.png").read_text() == "my notes"


@pytest.mark.parametrize("argv", [
    ["train", "waypoint", "--config", "c.yaml", "--out", "/proc/run"],
    ["train", "reachability", "--config", "c.yaml", "--out", "/proc/run"],
    ["train", "dagger", "--config", "c.yaml", "--out", "/proc/run"],
    ["train", "scale", "--config", "c.yaml", "--out", "/proc/run"],
    ["train", "place", "c.yaml", "--out", "/proc/run"],
    ["train", "waypoint", "--config", "c.yaml", "--out", "o", "--data", "/proc/data"],
])
def test_training_folders_are_checked_first(capsys, argv):
    code, _, err = run(capsys, *argv)
    one_line(code, err, "/proc")


def test_map_build_says_where_it_collects(capsys, tmp_path, monkeypatch, patch_everywhere):
    """Without --demos the demonstrations go under ./data, said on stderr;
    a ./data that cannot hold them is refused before anything is made."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "data").write_text("not a folder")
    code, _, err = run(capsys, "map", "build", "test-0", "--modality", "oracle", "--out", "m.tdmap")
    one_line(code, err, "data is a file, not a folder")
    (tmp_path / "data").unlink()

    def stop(*args, **kwargs):
        raise TopodrakeError("collection stopped here")

    patch_everywhere("topodrake.demonstrations.collect", stop)
    code, _, err = run(capsys, "map", "build", "test-0", "--modality", "oracle", "--out", "m.tdmap",
                       "--quiet")
    assert code == 2 and "collecting them into data/demos/pairs-s0/test-0" in err
    assert not (tmp_path / "m.tdmap").exists()
    code, _, err = run(capsys, "map", "build", "test-0", "--demos", "nothere", "--out", "m.tdmap")
    one_line(code, err, "no demonstrations in nothere")
    assert not (tmp_path / "data").exists()


def test_write_kept_keeps_the_result_and_says_where(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    written = []

    def write(path):
        if "gone" in str(path):
            raise PermissionError(13, "Permission denied", str(path))
        path.write_text("result")
        written.append(path)

    with pytest.raises(TopodrakeError) as e:
        write_kept(tmp_path / "gone" / "m.tdmap", write, "the map")
    message = str(e.value)
    assert "could not write" in message and "Permission denied" in message
    assert "kept the map in" in message and written and written[0].read_text() == "result"
    assert str(written[0]) in message and written[0].suffix == ".tdmap"
    assert write_kept(tmp_path / "ok.tdmap", write) == tmp_path / "ok.tdmap"


@pytest.fixture(scope="module")
def demos():
    """test-0's demonstrations (collected into ./data once, as map build does)."""
    from topodrake.topomap.sources import demo_drives

    return demo_drives("test-0", progress=False)[0].resolve()


def test_a_failed_write_after_the_work_is_one_line(capsys, tmp_path, monkeypatch, demos, patch_everywhere):
    """The map is built, its file cannot be written: one line naming the
    failure and the place the map was kept."""
    monkeypatch.chdir(tmp_path)

    def refuse(topomap, path):
        if "kept" not in str(path):
            raise OSError(28, "No space left on device", str(path))
        path.write_bytes(b"PK\x03\x04map")

    patch_everywhere("topodrake.topomap.mapfile.save_map", refuse)
    code, out, err = run(capsys, "map", "build", "test-0", "--modality", "oracle", "--places", "4,9",
                         "--demos", demos, "--out", tmp_path / "m.tdmap", "--quiet")
    line = one_line(code, err, "No space left on device", "kept the map in")
    kept = line.split("kept the map in ")[1]
    assert (tmp_path / kept).read_bytes().startswith(b"PK") and out == ""


def test_check_output_passes_none_and_new_files(tmp_path):
    assert check_output(None, "image") is None
    assert check_output(tmp_path / "new" / "deeper" / "x.svg", "image").name == "x.svg"
    assert not (tmp_path / "new").exists()          # checked, not made


def test_json_of_map_build_names_its_demonstrations(capsys, tmp_path):
    code, out, _ = run(capsys, "map", "build", "test-0", "--modality", "oracle", "--places", "4,9",
                       "--out", tmp_path / "m.tdmap", "--quiet", "--json")
    summary = json.loads(out)
    assert code == 0 and summary["demos"].endswith("pairs-s0/test-0")
    assert len(summary["drive_s"]) == summary["added"] == 2
    assert summary["drive_s_first10"] > 0 and summary["drive_s_last10"] > 0
    assert not list(tmp_path.glob(".*partial"))
