"""Floor plans: walls, occupancy grid, c-space, A*, houses and map loaders.

``load_world(spec)`` is the one entry point: ``spec`` is a catalogue name
(``train-00`` .. ``train-95``, ``test-0`` .. ``test-4``), a ROS map_server
YAML, or a HouseExpo JSON file.
"""

from topodrake.world.astar import AStarConfig, astar, path_length
from topodrake.world.grid import OccupancyGrid
from topodrake.world.walls import Faces, Wall, WallSet
from topodrake.world.world import World, world_from_walls

__all__ = ["AStarConfig", "astar", "path_length", "OccupancyGrid", "Faces", "Wall",
           "WallSet", "World", "world_from_walls", "load_world"]


def load_world(spec: str) -> World:
    from topodrake.world.catalogue import load_world as _load
    return _load(spec)
