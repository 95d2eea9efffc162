"""Topological maps: sparsified trajectories, graph building, planning, map files."""

from topodrake.topomap.sparsify import sparsify

__all__ = ["sparsify"]
