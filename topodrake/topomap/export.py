"""A map for other tools: networkx's GraphML, or a ROS 2 bag in MCAP.

:func:`map_graph` turns a :class:`~topodrake.topomap.graph.TopoMap` into a
plain ``networkx.DiGraph`` whose attributes are scalars (as GraphML holds
them), and :func:`write_graphml` writes it atomically. Read it back with
``networkx.read_graphml(path)`` (node ids are strings there; pass
``node_type=int`` for integers).

Graph attributes: ``world``, ``modality``, ``k``, ``vertices``, ``edges``,
``trajectories``, ``raw_frames``, ``edge_kinds`` (the kinds, comma-separated)
and ``source`` (the map file, where given).

Per vertex: ``traj`` (the drive that created it), ``frame`` (its frame in
that drive), ``pos`` (its place in the drive's chain) and, where the pose
it was taken at is known, ``x``, ``y`` (m) and ``yaw`` (rad).

Per edge: ``p`` (the probability that the controller drives it),
``neg_log_p`` (``-log p``, Dijkstra's weight), ``kind`` (``trajectory``,
``cross`` or ``junction``: every kind a map holds) and, where the edge
carries them, ``leg_dx``, ``leg_dy``, ``leg_dyaw`` (the end's pose in the
start's frame: the drive's odometry or a junction's registration),
``passed``, ``failed`` and ``p_re`` (cars that drove it, and RE's own
rating).

:func:`write_mcap` writes the map as ``visualization_msgs/msg/MarkerArray``
markers on ``/topodrake/map`` (see :mod:`topodrake.bag`): the vertices whose
pose is known as one sphere list, the edges between them as one line list
per kind.
"""

from __future__ import annotations

import io
import math

import networkx as nx
import numpy as np

from topodrake.bag import map_mcap_bytes
from topodrake.fileio import atomic_write_bytes
from topodrake.topomap.graph import EDGE_KINDS

#: the formats ``map export`` writes
FORMATS = ("graphml", "mcap")


def map_graph(topomap, source: str = "") -> nx.DiGraph:
    """The map's vertices and edges with scalar attributes (see the module)."""
    g = nx.DiGraph()
    g.graph.update(world=str(topomap.world), modality=str(topomap.modality), k=int(topomap.k),
                   vertices=len(topomap), edges=int(topomap.n_edges),
                   trajectories=len(topomap.trajectories), raw_frames=int(topomap.raw_frames),
                   edge_kinds=",".join(EDGE_KINDS))
    if source:
        g.graph["source"] = str(source)
    vertices = sorted(topomap.graph.nodes)
    poses = topomap.pose(vertices) if vertices else np.zeros((0, 3))
    for v, pose in zip(vertices, poses):
        node = topomap.graph.nodes[v]
        attrs = {"traj": int(node["traj"]), "frame": int(node["frame"]), "pos": int(node["pos"])}
        if np.all(np.isfinite(pose)):
            attrs.update(x=float(pose[0]), y=float(pose[1]), yaw=float(pose[2]))
        g.add_node(int(v), **attrs)
    for u, v, d in topomap.graph.edges(data=True):
        p = float(d["p"])
        attrs = {"p": p, "neg_log_p": -math.log(p) if p > 0 else math.inf, "kind": str(d["kind"])}
        leg = d.get("leg")
        if leg is not None and np.all(np.isfinite(leg)):
            attrs.update(leg_dx=float(leg[0]), leg_dy=float(leg[1]), leg_dyaw=float(leg[2]))
        for key in ("passed", "failed"):
            if key in d:
                attrs[key] = int(d[key])
        if "p_re" in d and np.isfinite(d["p_re"]):
            attrs["p_re"] = float(d["p_re"])
        g.add_edge(int(u), int(v), **attrs)
    return g


def graphml_bytes(topomap, source: str = "") -> bytes:
    """The map as GraphML (UTF-8)."""
    buf = io.BytesIO()
    nx.write_graphml(map_graph(topomap, source), buf, encoding="utf-8", prettyprint=True)
    return buf.getvalue()


def write_graphml(topomap, path, source: str = ""):
    """Write the map as GraphML to ``path``, atomically; returns the path."""
    return atomic_write_bytes(path, graphml_bytes(topomap, source))


def mcap_bytes(topomap) -> bytes:
    """The map's markers as a ROS 2 MCAP bag (see the module)."""
    vertices = sorted(topomap.graph.nodes)
    poses = topomap.pose(vertices) if vertices else np.zeros((0, 3))
    known = {int(v): (float(p[0]), float(p[1])) for v, p in zip(vertices, poses)
             if np.all(np.isfinite(p[:2]))}
    edges = [(str(d["kind"]), known[int(u)], known[int(v)])
             for u, v, d in topomap.graph.edges(data=True) if int(u) in known and int(v) in known]
    table = {"vertices": [int(v) for v in vertices],
             "edges": [[int(u), int(v), str(d["kind"]), float(d["p"])]
                       for u, v, d in topomap.graph.edges(data=True)]}
    return map_mcap_bytes(np.array(list(known.values())).reshape(-1, 2), edges, EDGE_KINDS, table)


def write_mcap(topomap, path):
    """Write the map as a ROS 2 MCAP bag to ``path``, atomically; returns the path."""
    return atomic_write_bytes(path, mcap_bytes(topomap))


#: format -> writer(topomap, path, source)
WRITERS = {"graphml": write_graphml,
           "mcap": lambda topomap, path, source="": write_mcap(topomap, path)}
