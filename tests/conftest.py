"""Shared fixtures: a small hand-made world with known geometry."""

import importlib.util
from pathlib import Path

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
def load_study():
    """A script of studies/ imported as a module: ``load_study("planning")``."""
    def load(name: str):
        path = Path(__file__).resolve().parents[1] / "studies" / f"{name}.py"
        spec = importlib.util.spec_from_file_location(f"study_{name}", path)
        mod = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mod)
        return mod
    return load
