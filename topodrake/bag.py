"""ROS 2 bags in MCAP: the map as markers and a drive's sensor messages.

Written through ``mcap-ros2-support``'s ROS 2 writer (CDR encoding, the
message definitions below in ROS 2's concatenated ``.msg`` form), so that
Foxglove and ``ros2 bag`` open the files. Times are sim time (a drive) or 0
(the map), in nanoseconds. Frames: ``map`` (the world), ``base_link`` (the
car) and ``lidar`` (the lidar, ``forward_m`` ahead of the car's reference
point).

Topics of a map (:func:`map_mcap_bytes`): ``/topodrake/map``
(``visualization_msgs/msg/MarkerArray``: namespace ``vertices``, one
``SPHERE_LIST`` of every vertex whose pose is known; namespace ``edges``,
one ``LINE_LIST`` per edge kind, two points per edge between known poses)
and ``/topodrake/map/table`` (``std_msgs/msg/String``: JSON of every vertex
id and every edge as [source, target, kind, p]).

Topics of a drive (:func:`drive_mcap_bytes`), one message per control
period: ``/scan`` (``sensor_msgs/msg/LaserScan``), ``/odom``
(``nav_msgs/msg/Odometry``: the pose the follower reads, true or drifting
odometry, and the car's speed and turn rate), ``/camera/image``
(``sensor_msgs/msg/Image``, ``rgb8``), ``/follower/mode``
(``std_msgs/msg/String``: ``search``, ``follow``, ...) and ``/tf``
(``tf2_msgs/msg/TFMessage``: ``map`` -> ``base_link`` at the true pose,
``base_link`` -> ``lidar``).
"""

from __future__ import annotations

import io
import json
import math

import numpy as np
from mcap_ros2.writer import Writer

from topodrake.fileio import atomic_write_bytes

_SEP = "=" * 80 + "\n"
_DEFS = {
    "builtin_interfaces/Time": "int32 sec\nuint32 nanosec\n",
    "builtin_interfaces/Duration": "int32 sec\nuint32 nanosec\n",
    "std_msgs/Header": "builtin_interfaces/Time stamp\nstring frame_id\n",
    "std_msgs/ColorRGBA": "float32 r\nfloat32 g\nfloat32 b\nfloat32 a\n",
    "std_msgs/String": "string data\n",
    "geometry_msgs/Point": "float64 x\nfloat64 y\nfloat64 z\n",
    "geometry_msgs/Vector3": "float64 x\nfloat64 y\nfloat64 z\n",
    "geometry_msgs/Quaternion": "float64 x\nfloat64 y\nfloat64 z\nfloat64 w\n",
    "geometry_msgs/Pose": "geometry_msgs/Point position\ngeometry_msgs/Quaternion orientation\n",
    "geometry_msgs/Twist": "geometry_msgs/Vector3 linear\ngeometry_msgs/Vector3 angular\n",
    "geometry_msgs/PoseWithCovariance": "geometry_msgs/Pose pose\nfloat64[36] covariance\n",
    "geometry_msgs/TwistWithCovariance": "geometry_msgs/Twist twist\nfloat64[36] covariance\n",
    "geometry_msgs/Transform": "geometry_msgs/Vector3 translation\n"
                               "geometry_msgs/Quaternion rotation\n",
    "geometry_msgs/TransformStamped": "std_msgs/Header header\nstring child_frame_id\n"
                                      "geometry_msgs/Transform transform\n",
    "tf2_msgs/TFMessage": "geometry_msgs/TransformStamped[] transforms\n",
    "visualization_msgs/Marker": (
        "int32 SPHERE_LIST=7\nint32 LINE_LIST=5\nint32 ADD=0\n"
        "std_msgs/Header header\nstring ns\nint32 id\nint32 type\nint32 action\n"
        "geometry_msgs/Pose pose\ngeometry_msgs/Vector3 scale\nstd_msgs/ColorRGBA color\n"
        "builtin_interfaces/Duration lifetime\nbool frame_locked\n"
        "geometry_msgs/Point[] points\nstd_msgs/ColorRGBA[] colors\nstring text\n"
        "string mesh_resource\nbool mesh_use_embedded_materials\n"),
    "visualization_msgs/MarkerArray": "visualization_msgs/Marker[] markers\n",
    "sensor_msgs/LaserScan": (
        "std_msgs/Header header\nfloat32 angle_min\nfloat32 angle_max\n"
        "float32 angle_increment\nfloat32 time_increment\nfloat32 scan_time\n"
        "float32 range_min\nfloat32 range_max\nfloat32[] ranges\nfloat32[] intensities\n"),
    "sensor_msgs/Image": ("std_msgs/Header header\nuint32 height\nuint32 width\n"
                          "string encoding\nuint8 is_bigendian\nuint32 step\nuint8[] data\n"),
    "nav_msgs/Odometry": ("std_msgs/Header header\nstring child_frame_id\n"
                          "geometry_msgs/PoseWithCovariance pose\n"
                          "geometry_msgs/TwistWithCovariance twist\n"),
}

#: the map's topic; a drive's topics by what they carry
MAP_TOPIC = "/topodrake/map"
#: the map's vertices and edges with their p, as JSON (a ``String``)
MAP_TABLE_TOPIC = "/topodrake/map/table"
DRIVE_TOPICS = {"scan": "/scan", "odometry": "/odom", "image": "/camera/image",
                "mode": "/follower/mode", "tf": "/tf"}
#: edge kind -> RGBA of its line list
EDGE_COLORS = {"trajectory": (0.12, 0.47, 0.71, 1.0), "cross": (1.0, 0.5, 0.05, 1.0),
               "junction": (0.17, 0.63, 0.17, 1.0)}


def _deps(name: str, seen: list) -> None:
    for line in _DEFS[name].splitlines():
        kind = line.split()[0].split("[")[0]
        if "/" in kind and kind not in seen:
            seen.append(kind)
            _deps(kind, seen)


def msgdef(name: str) -> str:
    """The ROS 2 definition of ``pkg/Name`` with its dependencies appended."""
    deps: list = []
    _deps(name, deps)
    return _DEFS[name] + "".join(f"{_SEP}MSG: {d}\n{_DEFS[d]}" for d in deps)


def _ros_name(name: str) -> str:
    pkg, msg = name.split("/")
    return f"{pkg}/msg/{msg}"


class _Bag:
    """A ROS 2 MCAP writer into memory, registering each schema once."""

    def __init__(self):
        self.buffer = io.BytesIO()
        self.writer = Writer(self.buffer)
        self.schemas = {}
        self.counts = {}

    def write(self, topic: str, kind: str, message: dict, t_ns: int) -> None:
        if kind not in self.schemas:
            self.schemas[kind] = self.writer.register_msgdef(_ros_name(kind), msgdef(kind))
        self.writer.write_message(topic=topic, schema=self.schemas[kind], message=message,
                                  log_time=int(t_ns), publish_time=int(t_ns),
                                  sequence=self.counts.get(topic, 0))
        self.counts[topic] = self.counts.get(topic, 0) + 1

    def finish(self) -> bytes:
        self.writer.finish()
        return self.buffer.getvalue()


def stamp(t_ns: int) -> dict:
    return {"sec": int(t_ns // 1_000_000_000), "nanosec": int(t_ns % 1_000_000_000)}


def header(t_ns: int, frame: str) -> dict:
    return {"stamp": stamp(t_ns), "frame_id": frame}


def quaternion(yaw: float) -> dict:
    """The rotation by ``yaw`` about z."""
    return {"x": 0.0, "y": 0.0, "z": math.sin(0.5 * yaw), "w": math.cos(0.5 * yaw)}


def _point(x, y, z=0.0) -> dict:
    return {"x": float(x), "y": float(y), "z": float(z)}


def _color(rgba) -> dict:
    return dict(zip("rgba", map(float, rgba)))


def marker(ns: str, ident: int, kind: int, points, rgba, scale: float, frame: str = "map",
           t_ns: int = 0) -> dict:
    """A ``visualization_msgs/Marker`` (``kind``: 5 line list, 7 sphere list)."""
    return {"header": header(t_ns, frame), "ns": ns, "id": int(ident), "type": int(kind),
            "action": 0, "pose": {"position": _point(0, 0), "orientation": quaternion(0.0)},
            "scale": _point(scale, scale, scale), "color": _color(rgba),
            "lifetime": stamp(0), "frame_locked": False,
            "points": [_point(*p) for p in points], "colors": [], "text": "",
            "mesh_resource": "", "mesh_use_embedded_materials": False}


SPHERE_LIST, LINE_LIST = 7, 5


def map_markers(vertex_xy: np.ndarray, edges, kinds=tuple(EDGE_COLORS)) -> list[dict]:
    """The markers of a map: ``vertex_xy`` (V, 2) of the vertices whose pose
    is known; ``edges``: (kind, (x0, y0), (x1, y1)) of each edge between two
    of them. One sphere list of the vertices, one line list per edge kind
    (those without edges too, empty)."""
    out = [marker("vertices", 0, SPHERE_LIST, [(x, y, 0.05) for x, y in vertex_xy],
                  (0.0, 0.0, 0.5, 1.0), 0.15)]
    for i, kind in enumerate(kinds):
        points = [q for k, a, b in edges if k == kind for q in ((*a, 0.05), (*b, 0.05))]
        out.append(marker(f"edges/{kind}", i, LINE_LIST, points,
                          EDGE_COLORS.get(kind, (0.5, 0.5, 0.5, 1.0)), 0.03))
    return out


def map_mcap_bytes(vertex_xy, edges, kinds=tuple(EDGE_COLORS), table: dict | None = None) -> bytes:
    """The map's markers (:func:`map_markers`) as one ``MarkerArray`` at t = 0;
    with ``table`` (every vertex id, and every edge as [source, target, kind,
    p]) also that table as JSON in a ``String`` on :data:`MAP_TABLE_TOPIC`."""
    bag = _Bag()
    bag.write(MAP_TOPIC, "visualization_msgs/MarkerArray",
              {"markers": map_markers(np.asarray(vertex_xy).reshape(-1, 2), edges, kinds)}, 0)
    if table is not None:
        bag.write(MAP_TABLE_TOPIC, "std_msgs/String", {"data": json.dumps(table)}, 0)
    return bag.finish()


def _transform(t_ns, parent, child, x, y, yaw) -> dict:
    return {"header": header(t_ns, parent), "child_frame_id": child,
            "transform": {"translation": _point(x, y), "rotation": quaternion(yaw)}}


def drive_messages(frames: dict, lidar, camera=None, modes=()):
    """(topic, kind, message, t_ns) of each period of a drive. ``frames``:
    ``t`` (K,) s, ``state`` (K, 5) true x, y, yaw, v, omega, ``odometry``
    (K, 3) the pose the follower read, ``ranges`` (K, beams) m (inf: no
    hit), ``image`` (K, H, W, 3) uint8 or None, ``mode`` (K,) ints naming
    ``modes``; ``lidar``: its :class:`~topodrake.sensing.config.LidarConfig`."""
    angles = lidar.beam_angles()
    step = float(angles[1] - angles[0]) if len(angles) > 1 else 0.0
    period = float(np.median(np.diff(frames["t"]))) if len(frames["t"]) > 1 else 0.0
    images = frames.get("image")
    for k, t in enumerate(frames["t"]):
        t_ns = int(round(float(t) * 1e9))
        x, y, yaw, v, omega = map(float, frames["state"][k])
        yield DRIVE_TOPICS["tf"], "tf2_msgs/TFMessage", {"transforms": [
            _transform(t_ns, "map", "base_link", x, y, yaw),
            _transform(t_ns, "base_link", "lidar", float(lidar.forward_m), 0.0, 0.0)]}, t_ns
        yield DRIVE_TOPICS["scan"], "sensor_msgs/LaserScan", {
            "header": header(t_ns, "lidar"), "angle_min": float(angles[0]),
            "angle_max": float(angles[-1]), "angle_increment": step, "time_increment": 0.0,
            "scan_time": period, "range_min": 0.0, "range_max": float(lidar.range_m),
            "ranges": np.asarray(frames["ranges"][k], np.float32).tolist(),
            "intensities": []}, t_ns
        ox, oy, oyaw = map(float, frames["odometry"][k][:3])
        yield DRIVE_TOPICS["odometry"], "nav_msgs/Odometry", {
            "header": header(t_ns, "map"), "child_frame_id": "base_link",
            "pose": {"pose": {"position": _point(ox, oy), "orientation": quaternion(oyaw)},
                     "covariance": [0.0] * 36},
            "twist": {"twist": {"linear": _point(v, 0.0), "angular": _point(0.0, 0.0, omega)},
                      "covariance": [0.0] * 36}}, t_ns
        if images is not None:
            image = np.ascontiguousarray(images[k], np.uint8)
            h, w = image.shape[:2]
            yield DRIVE_TOPICS["image"], "sensor_msgs/Image", {
                "header": header(t_ns, "camera"), "height": h, "width": w, "encoding": "rgb8",
                "is_bigendian": 0, "step": 3 * w, "data": image.tobytes()}, t_ns
        m = int(frames["mode"][k])
        yield DRIVE_TOPICS["mode"], "std_msgs/String", {
            "data": modes[m] if 0 <= m < len(modes) else str(m)}, t_ns


def drive_mcap_bytes(frames: dict, lidar, camera=None, modes=()) -> bytes:
    """A drive's messages (:func:`drive_messages`) as a ROS 2 MCAP bag."""
    bag = _Bag()
    for topic, kind, message, t_ns in drive_messages(frames, lidar, camera, modes):
        bag.write(topic, kind, message, t_ns)
    return bag.finish()


def write_drive_mcap(path, frames: dict, lidar, camera=None, modes=()):
    """Write a drive's bag to ``path``, atomically; returns the path."""
    return atomic_write_bytes(path, drive_mcap_bytes(frames, lidar, camera, modes))
