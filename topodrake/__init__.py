"""topodrake: visual topological navigation on Drake.

The plain-Python core. Sub-packages: ``world`` (floor plans, houses, map
loaders, occupancy grid, A*), ``sensing`` (batched camera and lidar rendering,
image overlap). Drake LeafSystems live in ``topodrake.systems``.
"""

from topodrake.errors import TopodrakeError

__all__ = ["TopodrakeError"]
__version__ = "0.1.0"
