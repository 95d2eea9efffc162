"""The world: walls, occupancy, rooms with floor textures, named places.

A :class:`World` is what every other part of topodrake sees, whatever its
source (a procedural house, a ROS map, a HouseExpo plan). Walls are the truth
for rendering; the occupancy grid is the truth for collision, c-space and A*.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from topodrake.errors import TopodrakeError
from topodrake.world.astar import AStarConfig, astar, cell_costs
from topodrake.world.grid import OccupancyGrid, rasterize_walls
from topodrake.world.walls import Faces, WallSet

WALL_HEIGHT = 2.5


@dataclass
class World:
    """A floor plan ready for sensing and planning.

    ``regions`` is an int raster on the grid giving each cell's room index
    (-1 outside every room); ``floor_texture`` and ``ceiling_texture`` give a
    texture id per room. ``places`` is (P, 3) of ``x, y, heading``;
    ``place_names`` names them where the world has names (empty: none).
    """

    name: str
    walls: WallSet
    grid: OccupancyGrid
    regions: np.ndarray
    floor_texture: np.ndarray
    ceiling_texture: np.ndarray
    places: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    wall_height: float = WALL_HEIGHT
    source: str = ""
    faces_override: Faces | None = None
    place_names: tuple = ()

    def __post_init__(self) -> None:
        self.regions = np.asarray(self.regions, dtype=np.int32)
        if self.regions.shape != self.grid.shape:
            raise TopodrakeError(
                f"world {self.name!r}: region raster {self.regions.shape} does not "
                f"match the occupancy grid {self.grid.shape}")
        self.floor_texture = np.asarray(self.floor_texture, dtype=np.int32)
        self.ceiling_texture = np.asarray(self.ceiling_texture, dtype=np.int32)
        self.places = np.asarray(self.places, dtype=np.float64).reshape(-1, 3)
        self.place_names = tuple(str(n) for n in self.place_names)
        if not self.grid.reachable.any():
            raise TopodrakeError(f"world {self.name!r} has no free space for the car")

    # -- geometry ---------------------------------------------------------
    @cached_property
    def faces(self) -> Faces:
        """The faces the renderer draws."""
        return self.faces_override if self.faces_override is not None else Faces.from_walls(self.walls)

    @property
    def bbox(self) -> np.ndarray:
        return self.grid.bbox()

    @property
    def free_area_m2(self) -> float:
        """Floor area (m^2) of the connected free region the car drives in."""
        from topodrake.world.grid import largest_component
        free = largest_component(~self.grid.occupied)
        return float(free.sum() * self.grid.resolution ** 2)

    def check_pose(self, pose, what: str = "pose", free: bool = True) -> np.ndarray:
        """Validate one ``(x, y[, heading])``; raise a one-line error if it is
        outside the map or (with ``free``) outside the free configuration
        space."""
        pose = np.asarray(pose, dtype=np.float64).reshape(-1)
        if pose.size not in (2, 3) or not np.all(np.isfinite(pose)):
            raise TopodrakeError(f"{what} must be finite (x, y[, heading]), got {pose.tolist()}")
        rc = self.grid.to_cell(pose[:2])
        if not self.grid.in_bounds(rc):
            (x0, y0), (x1, y1) = self.bbox
            raise TopodrakeError(
                f"{what} ({pose[0]:.2f}, {pose[1]:.2f}) is outside the map of "
                f"{self.name!r} [{x0:.1f}, {x1:.1f}] x [{y0:.1f}, {y1:.1f}]")
        if free and not self.grid.free_space[rc[0], rc[1]]:
            raise TopodrakeError(
                f"{what} ({pose[0]:.2f}, {pose[1]:.2f}) is in collision in {self.name!r}")
        return pose

    def place_pose(self, index: int, what: str = "place") -> np.ndarray:
        """A copy of place ``index``'s pose (x, y, heading); an index the
        world does not have is refused in one line naming the world and how
        many places it has (``what`` names the option, e.g. ``--goal-place``)."""
        n = len(self.places)
        if not 0 <= int(index) < n:
            have = "no places" if n == 0 else ("1 place (0)" if n == 1 else
                                               f"{n} places (0..{n - 1})")
            raise TopodrakeError(f"{what} {index} is not a place of {self.name!r}: it has {have}")
        return self.places[int(index)].copy()

    def place_list(self) -> list[dict]:
        """Each place as ``{"index", "x", "y", "yaw"}`` (rounded to the mm),
        with its ``"name"`` where the world names its places."""
        out = []
        for i, (x, y, yaw) in enumerate(np.round(self.places, 3).tolist()):
            row = {"index": i, "x": x, "y": y, "yaw": yaw}
            if i < len(self.place_names) and self.place_names[i]:
                row["name"] = self.place_names[i]
            out.append(row)
        return out

    # -- sampling and planning ------------------------------------------------
    def sample_free_pose(self, rng: np.random.Generator, n: int | None = None) -> np.ndarray:
        """Uniform collision-free pose(s) in the reachable region: (3,) or (n, 3)."""
        cells = self._reachable_cells
        k = 1 if n is None else n
        idx = rng.integers(0, len(cells), size=k)
        xy = self.grid.to_world(cells[idx])
        xy += rng.uniform(-0.5, 0.5, size=(k, 2)) * self.grid.resolution * 0.5
        heading = rng.uniform(-np.pi, np.pi, size=k)
        poses = np.column_stack([xy, heading])
        return poses[0] if n is None else poses

    @cached_property
    def _reachable_cells(self) -> np.ndarray:
        return np.argwhere(self.grid.reachable)

    @cached_property
    def _astar_costs(self) -> np.ndarray:
        return cell_costs(self.grid, AStarConfig())

    def astar(self, start, goal, config: AStarConfig | None = None) -> np.ndarray:
        """A* path (K, 2) in metres between two points; see :func:`astar`."""
        start = self.check_pose(start, "start")
        goal = self.check_pose(goal, "goal")
        costs = None if config is not None else self._astar_costs
        return astar(self.grid, start, goal, config or AStarConfig(), costs)

    # -- summary ----------------------------------------------------------------
    def info(self) -> dict:
        return {
            "name": self.name,
            "source": self.source,
            "free_area_m2": round(self.free_area_m2, 2),
            "bbox_m": np.round(self.bbox, 3).tolist(),
            "walls": int(len(self.walls)),
            "faces": int(len(self.faces)),
            "rooms": int(len(self.floor_texture)),
            "resolution_m": self.grid.resolution,
            "places": np.round(self.places, 3).tolist(),
            **({"place_names": list(self.place_names)} if self.place_names else {}),
        }


def world_from_walls(name: str, walls: WallSet, *, room_boxes: np.ndarray | None = None,
                     floor_texture=None, ceiling_texture=None, resolution: float = 0.05,
                     margin: float = 0.5, source: str = "", wall_height: float = WALL_HEIGHT,
                     places: np.ndarray | None = None) -> World:
    """Rasterise walls into a world.

    ``room_boxes`` (R, 4) ``xmin, ymin, xmax, ymax`` give the rooms; cells in
    no room are treated as outside the building (occupied). Without rooms the
    whole bounding box is one room.
    """
    bbox = walls.bbox()
    origin = np.floor((bbox[0] - margin) / resolution) * resolution
    top = bbox[1] + margin
    shape = (int(np.ceil((top[1] - origin[1]) / resolution)),
             int(np.ceil((top[0] - origin[0]) / resolution)))
    occ = rasterize_walls(walls, origin, shape, resolution)
    regions = np.full(shape, -1, np.int32)
    if room_boxes is None:
        regions[:] = 0
        n_rooms = 1
    else:
        room_boxes = np.asarray(room_boxes, dtype=np.float64).reshape(-1, 4)
        n_rooms = len(room_boxes)
        xs = origin[0] + (np.arange(shape[1]) + 0.5) * resolution
        ys = origin[1] + (np.arange(shape[0]) + 0.5) * resolution
        for i, (x0, y0, x1, y1) in enumerate(room_boxes):
            c0, c1 = np.searchsorted(xs, [x0, x1])
            r0, r1 = np.searchsorted(ys, [y0, y1])
            regions[r0:r1, c0:c1] = i
        occ |= regions < 0
    floor_texture = np.zeros(n_rooms, np.int32) if floor_texture is None else floor_texture
    ceiling_texture = np.zeros(n_rooms, np.int32) if ceiling_texture is None else ceiling_texture
    grid = OccupancyGrid(occ, origin, resolution)
    world = World(name, walls, grid, regions, floor_texture, ceiling_texture,
                  wall_height=wall_height, source=source)
    if places is not None:
        world.places = np.asarray(places, dtype=np.float64)
    return world
