"""The named world catalogue and the one loader for every world source.

``load_world(spec)`` takes

* a catalogue name: 96 training houses ``train-00`` .. ``train-95``, 5
  test houses ``test-0`` .. ``test-4`` and 5 calibration houses
  ``calib-0`` .. ``calib-4``, procedural houses with fixed seeds (different
  floor plans, like the paper's training and test scenes). The controllers
  learn in the first 12 training houses (the configs' default
  ``data.train_worlds``; the C_WPs trained at scale in all 96); the others
  give RE labels in houses its controller never saw. No network trains in
  the calibration houses: plan calibrations are fitted there, on outcomes
  of houses as new to the follower as the test houses;
* a ROS map_server map, a path ending ``.yaml`` / ``.yml``;
* a HouseExpo floor plan, a path ending ``.json``.

Catalogue houses are generated on first use and cached in the process (about
0.1-0.4 s each); the cached :class:`World` is shared, so treat it as read-only.
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path

from topodrake.errors import TopodrakeError
from topodrake.world.houses import generate_house
from topodrake.world.world import World

#: name -> seed of :func:`topodrake.world.houses.generate_house`. Fixed: the
#: free areas (m^2) are pinned by ``tests/test_houses.py``; all lie in 200-460.
CATALOGUE: dict[str, int] = {
    **{f"train-{i:02d}": 1000 + i for i in range(96)},
    **{f"test-{i}": 2000 + i for i in range(5)},
    **{f"calib-{i}": 3000 + i for i in range(5)},
}


def catalogue_names() -> list[str]:
    """The catalogue's names: training houses, test houses, then calibration houses."""
    return list(CATALOGUE)


@lru_cache(maxsize=None)
def _catalogue_world(name: str) -> World:
    return generate_house(CATALOGUE[name], name)


def load_world(spec: str) -> World:
    """A world from a catalogue name, a ROS map YAML or a HouseExpo JSON."""
    spec = str(spec)
    if spec in CATALOGUE:
        return _catalogue_world(spec)
    suffix = Path(spec).suffix.lower()
    if suffix in (".yaml", ".yml", ".json"):
        path = Path(spec)
        if not path.is_file():
            raise TopodrakeError(f"map file {spec} does not exist")
        if suffix == ".json":
            from topodrake.world.houseexpo import load_houseexpo
            return load_houseexpo(path)
        from topodrake.world.rosmap import load_ros_map
        return load_ros_map(path)
    raise TopodrakeError(unknown_world_message(spec))


def unknown_world_message(spec: str) -> str:
    """One short line: up to 5 close catalogue names and where the full list is."""
    import difflib

    close = difflib.get_close_matches(spec, CATALOGUE, n=5, cutoff=0.6)
    shown = spec if len(spec) <= 40 else spec[:37] + "..."
    hint = f" (close: {', '.join(close)})" if close else ""
    return (f"unknown world {shown!r}{hint}; 'topodrake world list' names all {len(CATALOGUE)}, "
            f"or give a ROS map .yaml or HouseExpo .json")


def same_world(a, b) -> bool:
    """Whether two world specs name one world (a catalogue name, or one map
    file however its path is written)."""
    if a == b:
        return True
    if a is None or b is None or Path(str(a)).suffix not in (".yaml", ".yml", ".json"):
        return False
    return Path(str(a)).resolve() == Path(str(b)).resolve()


def map_files(text: str) -> list[str]:
    """The ROS map YAMLs ``text`` names: every ``*/map.yaml`` under a folder
    (sorted; a folder without one is refused), or comma-separated specs as
    given."""
    path = Path(text)
    if path.is_dir():
        specs = sorted(str(p) for p in path.glob("*/map.yaml"))
        if not specs:
            raise TopodrakeError(f"{text}: no */map.yaml under that folder")
        return specs
    return [s.strip() for s in text.split(",") if s.strip()]
