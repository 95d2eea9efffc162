"""Plots read at a glance: directed edges, a slim colour bar, legends under
the floor plan, follower modes in colours the map does not use."""

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.quiver import Quiver

from topodrake.apps.drive import MODE_COLORS
from topodrake.topomap.plot import VERTEX_COLOR, draw_map
from topodrake.world import load_world
from topodrake.world.plot import legend_below

def test_map_edges_are_arrows_and_the_colour_bar_is_slim():
    world = load_world("test-0")
    poses = np.array([[2.0, 2.0, 0.0], [4.0, 2.0, 0.0], [4.0, 4.0, 1.57]])
    edges = np.array([[0, 1], [1, 2]])
    fig, ax = plt.subplots(figsize=(10, 9))
    draw_map(ax, world, poses, edges, np.array([0.95, 0.99]))
    arrows = [c for c in ax.collections if isinstance(c, Quiver) and len(c.U) == 2]
    assert len(arrows) == 1
    assert np.allclose(arrows[0].U, [2.0, 0.0]) and np.allclose(arrows[0].V, [0.0, 2.0])
    bar = [a for a in fig.axes if a is not ax]
    assert len(bar) == 1 and bar[0].get_position().width < 0.05
    plt.close(fig)


def test_the_legend_is_under_the_floor_plan():
    fig, ax = plt.subplots()
    ax.plot([0, 1], [0, 1], label="a")
    legend_below(ax)
    fig.canvas.draw()
    legend = ax.get_legend().get_window_extent()
    assert legend.y1 <= ax.get_window_extent().y0
    plt.close(fig)


def test_follower_modes_do_not_take_the_maps_colours():
    taken = {VERTEX_COLOR, "tab:purple", "tab:red"}       # map vertices, the plan, the goal
    assert not taken & set(MODE_COLORS.values())
    assert len(set(MODE_COLORS.values())) == len(MODE_COLORS)
