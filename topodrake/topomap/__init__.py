"""Topological maps: graph building, planning, map files."""
