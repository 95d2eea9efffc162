"""Shared fixtures: a small hand-made world with known geometry, two expert drives of test-0."""

import numpy as np
import pytest

from topodrake.world import WallSet, world_from_walls


@pytest.fixture(scope="session")
def box_world():
    """A 10 x 10 m room (inner faces at 0.2 and 9.8) with a partition
    x in [4.9, 5.1], y in [0, 6] that leaves a 3.8 m gap at the top."""
    boxes = np.array([[0, 0, 10, 0.2], [0, 9.8, 10, 10], [0, 0, 0.2, 10],
                      [9.8, 0, 10, 10], [4.9, 0, 5.1, 6]], dtype=float)
    return world_from_walls("box", WallSet.from_boxes(boxes, np.arange(5)))


@pytest.fixture(scope="session")
def test0_drives():
    """Two expert drives of test-0 (5-9 m, seeded) as a TrajectorySet, and the world."""
    from topodrake.learning.samples import TrajectorySet
    from topodrake.rollout import ExpertRollout, RolloutConfig
    from topodrake.world import load_world

    world = load_world("test-0")
    rng = np.random.default_rng(3)
    got = []
    while len(got) < 2:
        s, g = world.sample_free_pose(rng), world.sample_free_pose(rng)
        path = world.astar(s, g)
        if not 5.0 < np.hypot(*np.diff(path, axis=0).T).sum() < 9.0:
            continue
        d = path[min(10, len(path) - 1)] - path[0]
        s[2] = np.arctan2(d[1], d[0])
        res = ExpertRollout(world, RolloutConfig(t_max_s=60.0)).run(s[None], g[None, :2])
        if res.success[0]:
            t = res.trajectory(0)
            got.append((0, t["poses"], t["controls"]))
    return world, TrajectorySet.from_drives(["test-0"], got)


@pytest.fixture(scope="session")
def small_map(tmp_path_factory):
    """``small_map(modality)``: a map file of test-0's drives between places
    4 and 9, built once per session (read it, never write it)."""
    import contextlib
    import io

    from topodrake.apps.cli import main

    built = {}

    def get(modality: str):
        if modality not in built:
            path = tmp_path_factory.mktemp(f"small-{modality}") / f"{modality}.tdmap"
            with contextlib.redirect_stdout(io.StringIO()), \
                    contextlib.redirect_stderr(io.StringIO()):  # not into a test's capsys
                code = main(["map", "build", "test-0", "--modality", modality, "--places",
                             "4,9", "--out", str(path), "--quiet"])
            assert code == 0
            built[modality] = path
        return built[modality]
    return get


@pytest.fixture
def patch_everywhere(monkeypatch):
    """``patch_everywhere("topodrake.module.name", value)``: monkeypatch a
    function in its module and in every loaded topodrake module that imported
    it by name (imports sit at module top, so a caller holds its own binding)."""
    import importlib
    import sys

    def patch(target: str, value):
        modname, attr = target.rsplit(".", 1)
        module = importlib.import_module(modname)
        original = getattr(module, attr)
        monkeypatch.setattr(module, attr, value)
        for other in list(sys.modules.values()):
            name = getattr(other, "__name__", "") or ""
            if other is not module and name.startswith("topodrake") and \
                    getattr(other, "__dict__", {}).get(attr) is original:
                monkeypatch.setattr(other, attr, value)
    return patch
