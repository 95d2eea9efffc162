"""Meshcat recordings open on the whole floor plan: the camera pose that
frames a world, and the static HTML of a diagram built with a Meshcat."""

from __future__ import annotations

import base64
import re
import struct

import numpy as np
import pytest

from topodrake.sensing.scenegraph import MESHCAT_FOV_DEG, framing_camera_pose, view_angles


@pytest.mark.parametrize("world_name", ["test-0", "train-07"])
def test_framing_sees_every_corner(world_name):
    from topodrake.world import load_world

    world = load_world(world_name)
    camera, target = framing_camera_pose(world)
    (x0, y0), (x1, y1) = world.bbox
    assert np.allclose(target[:2], [(x0 + x1) / 2, (y0 + y1) / 2]) and target[2] == 0
    assert camera[2] > world.wall_height
    h = world.wall_height
    corners = np.array([[x, y, z] for x in (x0, x1) for y in (y0, y1) for z in (0.0, h)])
    angles = view_angles(camera, target, corners)
    # every corner inside the view (vertical field of view; windows are at least as wide)
    assert np.all(angles < MESHCAT_FOV_DEG / 2)
    # and the plan fills it: not framed from needlessly far away
    assert np.nanmax(angles) > 0.8 * MESHCAT_FOV_DEG / 2
    # a point straight ahead is on the axis; one behind the camera is NaN
    assert np.allclose(view_angles(camera, target, target[None]), 0)
    assert np.isnan(view_angles(camera, target, (2 * camera - target)[None])).all()


def _messages(html: str) -> list[bytes]:
    return [base64.b64decode(m) for m in
            re.findall(r"data:application/octet-binary;base64,([A-Za-z0-9+/=]+)", html)]


def _xyz_after(msg: bytes, key: bytes) -> np.ndarray:
    """The 3 float64 values msgpack-encoded right after ``key`` (a fixarray of
    0xcb doubles)."""
    i = msg.index(key) + len(key)
    assert msg[i] == 0x93
    return np.array([struct.unpack(">d", msg[i + 2 + 9 * k:i + 10 + 9 * k])[0] for k in range(3)])


def test_diagram_recording_opens_framed():
    from pydrake.geometry import Meshcat

    from topodrake.systems.diagram import build_expert_diagram
    from topodrake.systems.scenario import Scenario
    from topodrake.world import load_world

    try:
        meshcat = Meshcat()
    except RuntimeError as e:  # no free port
        pytest.skip(f"Meshcat unavailable: {e}")
    world = load_world("test-0")
    build_expert_diagram(Scenario(world="test-0", camera_enabled=False), world=world,
                         meshcat=meshcat)
    camera, target = framing_camera_pose(world)
    msgs = _messages(meshcat.StaticHtml())
    targets = [m for m in msgs if b"set_target" in m]
    positions = [m for m in msgs if b"/Cameras/default/rotated/<object>" in m and b"position" in m]
    assert targets and positions
    # Drake's z-up target becomes three.js's y-up (x, z, -y).
    assert np.allclose(_xyz_after(targets[-1], b"\xa5value"), [target[0], target[2], -target[1]])
    # The camera position is set relative to the target's frame; its height is the pose's.
    assert _xyz_after(positions[-1], b"\xa5value")[1] == pytest.approx(camera[2] - target[2])
