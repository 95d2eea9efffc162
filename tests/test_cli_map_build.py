"""``map build``: an interrupted build resumes to the same map file, and
the JSON holds each drive's time."""

import json

from topodrake.apps.cli import main

BUILD = ["map", "build", "test-0", "--modality", "oracle", "--places", "4,5,9", "--quiet", "--json"]


def interrupt_at(monkeypatch, n: int):
    """Makes the build's n-th drive raise KeyboardInterrupt (progress saved at
    every drive); returns the real ``add_trajectory`` to put back."""
    import topodrake.topomap.build as build
    from topodrake.topomap.resumable import MapBuild

    add, calls = build.add_trajectory, []

    def interrupted(*args, **kwargs):
        calls.append(1)
        if len(calls) == n:
            raise KeyboardInterrupt
        return add(*args, **kwargs)

    monkeypatch.setattr(build, "add_trajectory", interrupted)
    monkeypatch.setattr(MapBuild, "save_every_s", 0.0)
    return add


def test_an_interrupted_build_resumes_to_the_same_file(capsys, tmp_path, monkeypatch):
    import topodrake.topomap.build as build

    assert main([*BUILD, "--out", str(tmp_path / "ref.tdmap")]) == 0
    whole = json.loads(capsys.readouterr().out)
    assert whole["added"] == len(whole["drive_s"]) == 6 and whole["resumed"] == 0

    add = interrupt_at(monkeypatch, 4)
    out = tmp_path / "m.tdmap"
    assert main([*BUILD, "--out", str(out)]) == 130
    capsys.readouterr()
    (partial,) = tmp_path.glob(".m.tdmap.*partial")
    assert partial.name.startswith(".m.tdmap.places-4-5-9.") and not out.exists()

    monkeypatch.setattr(build, "add_trajectory", add)
    assert main([*BUILD, "--out", str(out)]) == 0
    resumed = json.loads(capsys.readouterr().out)
    assert resumed["resumed"] == 3 and len(resumed["drive_s"]) == 3 and resumed["added"] == 6
    assert out.read_bytes() == (tmp_path / "ref.tdmap").read_bytes()
    assert not partial.exists()


def test_an_interrupted_build_of_other_drives_is_not_resumed(capsys, tmp_path, monkeypatch):
    import topodrake.topomap.build as build

    add = interrupt_at(monkeypatch, 2)
    out = tmp_path / "m.tdmap"
    assert main([*BUILD, "--out", str(out)]) == 130
    monkeypatch.setattr(build, "add_trajectory", add)
    other = [a if a != "4,5,9" else "4,9" for a in BUILD]
    assert main([*other, "--out", str(out)]) == 0
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert summary["trajectories"] == 2       # none of the other build's drives
