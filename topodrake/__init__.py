"""topodrake: visual topological navigation on Drake.

The plain-Python core. Sub-packages: ``world`` (floor plans, houses, map
loaders, occupancy grid, A*), ``sensing`` (batched camera and lidar rendering,
image overlap). Drake LeafSystems live in ``topodrake.systems``.
"""

import os as _os

# Numba's default OpenMP threading layer shares libgomp with torch: a numba
# parallel region (the batched renderer, the expert) resets the OpenMP thread
# count that torch.set_num_threads chose, so a one-thread training or
# inference process ends up running torch on every core. The workqueue layer
# leaves OpenMP alone. Set NUMBA_THREADING_LAYER to choose another.
if "NUMBA_THREADING_LAYER" not in _os.environ:
    import numba as _numba

    _numba.config.THREADING_LAYER = "workqueue"

# Compiled kernels are cached between processes in a directory keyed by their
# sources (see topodrake.jitcache); this must precede every kernel module.
from topodrake import jitcache as _jitcache  # noqa: E402

_jitcache.configure()

from topodrake.errors import TopodrakeError  # noqa: E402

__all__ = ["TopodrakeError"]
__version__ = "0.1.0"
