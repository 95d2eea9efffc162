"""Topological maps: sparsified trajectories, graph building, planning, map files."""

from topodrake.learning.reachability.sparsify import sparsify

__all__ = ["sparsify"]
