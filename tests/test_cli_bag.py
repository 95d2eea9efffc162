"""``topodrake navigate --record-mcap``: a drive as a ROS 2 bag in MCAP, read
back with the MCAP reader: scans, odometry, camera images and the follower's
mode, one each per control period, in sim time."""

import json
from collections import Counter

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from cli_run import one_line, run
from topodrake.navigation.follower import MODES
from topodrake.sensing.config import CameraConfig, LidarConfig

START, GOAL = "16.42,14.88,2.95", "8.22,14.08,-0.2"


def _messages(path):
    with open(path, "rb") as f:
        return [(channel.topic, schema.name, message.log_time, msg) for schema, channel, message, msg
                in make_reader(f, decoder_factories=[DecoderFactory()]).iter_decoded_messages()]


@pytest.fixture(scope="module")
def drive(tmp_path_factory):
    """A 2 s drive of the learned camera follower recorded to a bag."""
    import contextlib
    import io

    from topodrake.apps.cli import main

    out = tmp_path_factory.mktemp("bag") / "run.mcap"
    stdout = io.StringIO()
    with contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(io.StringIO()):
        code = main(["navigate", "test-0", "--start", START, "--goal", GOAL, "--t-max", "2",
                     "--json", "--record-mcap", str(out)])
    assert code == 3                        # 2 s: a drive that times out
    return out, json.loads(stdout.getvalue().strip().splitlines()[-1])


def test_bag_holds_the_drives_scan_odometry_image_and_mode(drive):
    out, summary = drive
    assert out.read_bytes().startswith(b"\x89MCAP0\r\n")
    msgs = _messages(out)
    counts = Counter(topic for topic, *_ in msgs)
    schemas = {topic: name for topic, name, *_ in msgs}
    assert schemas == {"/scan": "sensor_msgs/msg/LaserScan", "/odom": "nav_msgs/msg/Odometry",
                       "/camera/image": "sensor_msgs/msg/Image",
                       "/follower/mode": "std_msgs/msg/String", "/tf": "tf2_msgs/msg/TFMessage"}
    # one of each per control period (0.1 s) of the drive
    k = counts["/scan"]
    assert set(counts.values()) == {k}
    assert abs(k - summary["time_s"] / 0.1) <= 2 and k >= 15
    lidar, camera = LidarConfig(), CameraConfig()
    by_topic = {}
    for topic, _, t_ns, msg in msgs:
        by_topic.setdefault(topic, []).append((t_ns, msg))
    times = [t for t, _ in by_topic["/scan"]]
    assert times == sorted(times) and times[0] >= 0 and times[-1] <= 2.05e9
    for t_ns, scan in by_topic["/scan"]:
        assert len(scan.ranges) == lidar.beams and scan.header.frame_id == "lidar"
        assert scan.header.stamp.sec * 10 ** 9 + scan.header.stamp.nanosec == t_ns
        assert scan.range_max == pytest.approx(lidar.range_m)
        r = np.array(scan.ranges)
        assert np.all((r > 0) | ~np.isfinite(r)) and np.isfinite(r).any()
    start = np.array([float(v) for v in START.split(",")])
    first = by_topic["/odom"][0][1].pose.pose.position
    assert np.hypot(first.x - start[0], first.y - start[1]) < 0.3
    last = by_topic["/odom"][-1][1].pose.pose.position
    assert np.hypot(last.x - first.x, last.y - first.y) > 0.05       # the car moved
    for _, image in by_topic["/camera/image"]:
        assert (image.width, image.height, image.encoding) == (camera.width, camera.height,
                                                               "rgb8")
        assert image.step == 3 * image.width and len(image.data) == 3 * camera.width * \
            camera.height
    assert len({bytes(im.data) for _, im in by_topic["/camera/image"]}) > 1
    assert {m.data for _, m in by_topic["/follower/mode"]} <= set(MODES)


def test_bag_is_refused_over_an_existing_file_without_force(capsys, tmp_path, drive):
    out = tmp_path / "run.mcap"
    out.write_bytes(drive[0].read_bytes())
    code, _, err = run(capsys, "navigate", "test-0", "--start", START, "--goal", GOAL,
                       "--t-max", "2", "--record-mcap", out)
    one_line(code, err, "--record-mcap", str(out), "--force")
    other = tmp_path / "run.txt"
    code, _, err = run(capsys, "navigate", "test-0", "--start", START, "--goal", GOAL,
                       "--t-max", "2", "--record-mcap", other)
    one_line(code, err, "--record-mcap", ".mcap")
    assert not other.exists()
