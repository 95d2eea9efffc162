"""No import cycles inside the package: a small AST walk over topodrake/ and
systems/ (installed as topodrake.systems), counting imports inside functions
too, since a deferred import only hides a cycle."""

from __future__ import annotations

import ast
from pathlib import Path

import networkx as nx

ROOT = Path(__file__).resolve().parent.parent


def _module_name(path: Path) -> str:
    rel = path.relative_to(ROOT).with_suffix("")
    parts = list(rel.parts)
    if parts[0] == "systems":
        parts = ["topodrake", *parts]
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def import_graph(top_level_only: bool = False) -> nx.DiGraph:
    """Edges module -> topodrake module it imports (a ``from a import b``
    counts as importing ``a`` and, when it is a module, ``a.b``)."""
    files = {_module_name(p): p for folder in ("topodrake", "systems")
             for p in (ROOT / folder).rglob("*.py")}
    graph = nx.DiGraph()
    graph.add_nodes_from(files)
    for name, path in files.items():
        tree = ast.parse(path.read_text(encoding="utf-8"), str(path))
        nodes = tree.body if top_level_only else ast.walk(tree)
        for node in nodes:
            if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                targets = [node.module, *(f"{node.module}.{a.name}" for a in node.names)]
            elif isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            else:
                continue
            graph.add_edges_from((name, t) for t in targets if t in files and t != name)
    return graph


def _cycles(graph: nx.DiGraph) -> list[list[str]]:
    return [sorted(c) for c in nx.strongly_connected_components(graph) if len(c) > 1]


def test_graph_sees_known_edges():
    g = import_graph()
    assert g.has_edge("topodrake.apps.cli", "topodrake.errors")
    assert g.has_edge("topodrake.systems.run", "topodrake.vehicle")
    # a deferred import inside a function counts
    assert g.has_edge("topodrake.apps.cli", "topodrake.world.plot")


def test_no_import_cycles_at_module_level():
    assert _cycles(import_graph(top_level_only=True)) == []


def test_no_import_cycles_even_through_deferred_imports():
    assert _cycles(import_graph()) == []
