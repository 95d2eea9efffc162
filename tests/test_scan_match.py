"""Scan matching tells look-alike places apart where RE cannot: lidar maps
join drives and link plans only where the scans register onto each other."""

import numpy as np
import pytest

from topodrake.errors import TopodrakeError
from topodrake.se2 import compose
from topodrake.sensing.lidar import Lidar
from topodrake.topomap.build import add_trajectory
from topodrake.topomap.graph import MapConfig, TopoMap
from topodrake.topomap.plan import matched_first
from topodrake.topomap.scan_match import checks_scans, scans_match
from topodrake.world import load_world

from test_topomap import FlatEmbedding, TableScorer


@pytest.fixture(scope="module")
def house():
    return load_world("test-0")


@pytest.fixture(scope="module")
def lidar(house):
    return Lidar(house)


def _apart(house, rng, n, min_m=5.0):
    """``n`` pairs of free poses at least ``min_m`` apart."""
    a, b = [], []
    while len(a) < n:
        p, q = house.sample_free_pose(rng), house.sample_free_pose(rng)
        if np.hypot(*(p[:2] - q[:2])) >= min_m:
            a.append(p)
            b.append(q)
    return np.array(a), np.array(b)


def test_scans_of_one_place_match_and_scans_of_places_apart_do_not(house, lidar):
    rng = np.random.default_rng(0)
    poses = house.sample_free_pose(rng, 60)
    moved = compose(poses, np.column_stack([rng.uniform(-0.15, 0.15, (60, 2)),
                                            rng.uniform(-0.1, 0.1, 60)]))
    near = scans_match(lidar.scan(moved), lidar.scan(poses), 0.8)
    a, b = _apart(house, rng, 60)
    far = scans_match(lidar.scan(a), lidar.scan(b), 0.8)
    assert near.shape == far.shape == (60,)
    assert near.mean() >= 0.85
    assert far.mean() <= 0.05
    # one scan is shared by the batch; a stricter share passes fewer
    one = scans_match(lidar.scan(poses[:1]), lidar.scan(moved[:5]), 0.8)
    assert one.shape == (5,)
    assert scans_match(lidar.scan(moved), lidar.scan(poses), 0.99).sum() <= near.sum()


class ScanScorer(TableScorer):
    """RE from a rule over (drive, frame), read from which drive frame a
    lidar scan is (k = 0): RE that cannot tell look-alike rooms apart,
    over real scans."""

    observation = "lidar"

    def __init__(self, rule, frames: dict):
        super().__init__(rule, "scan-table")
        self.frames = frames

    def features(self, observations):
        obs = np.asarray(observations)
        return {"x": np.array([self.frames[o.tobytes()] for o in obs], np.int64).reshape(-1, 2)}


class FlatLidarEmbedding(FlatEmbedding):
    observation = "lidar"


def _alike(a, b):
    """Drives 0 and 2 are one place, drive 1 a look-alike of it: every frame
    passes for the same frame of another drive, and a drive's own frames reach
    3 ahead."""
    if a[0] == b[0] or {a[0], b[0]} <= {0, 1, 2}:
        return 0.999 if 0 <= b[1] - a[1] <= 3 else 0.1
    return 0.1


@pytest.fixture(scope="module")
def three_drives(house, lidar):
    """Scans of 10 frames 0.1 m apart: drive 0 at one place, drive 2 beside
    it (5 cm to the side), drive 1 at least 5 m away, drive 3 setting off
    where drive 0 ends."""
    rng = np.random.default_rng(3)
    a, b = _apart(house, rng, 1)
    steps = np.column_stack([np.arange(10) * 0.1, np.zeros(10), np.zeros(10)])
    poses = [compose(np.repeat(a, 10, 0), steps), compose(np.repeat(b, 10, 0), steps),
             compose(np.repeat(a, 10, 0), steps + [0.0, 0.05, 0.0])]
    poses.append(compose(np.repeat(poses[0][-1:], 10, 0), steps + [0.0, 0.05, 0.0]))
    scans = [lidar.scan(p) for p in poses]
    frames = {s.tobytes(): (d, f) for d, ss in enumerate(scans) for f, s in enumerate(ss)}
    return scans, poses, frames


def _ends_meet(a, b):
    """Drive 0's last frame and the first of drives 1 and 3 pass for each
    other both ways (drive 1 is a look-alike far away); a drive's own
    frames reach 3 ahead."""
    if a[0] == b[0]:
        return 0.999 if 0 <= b[1] - a[1] <= 3 else 0.1
    return 0.95 if {a, b} in ({(0, 9), (1, 0)}, {(0, 9), (3, 0)}) else 0.1


def _scan_map(frames, rule=_alike, **config):
    return TopoMap(ScanScorer(rule, frames), FlatLidarEmbedding(), MapConfig.from_dict(config),
                   world="test-0")


def _traj(m, v):
    return m.graph.nodes[v]["traj"]


def test_reuse_and_junctions_need_the_scans_to_match(three_drives):
    scans, poses, frames = three_drives
    plain = _scan_map(frames, scan_match=0.0, reuse_pinned=False)
    for s, p in zip(scans[:3], poses[:3]):
        add_trajectory(plain, s, p)
    # RE alone: the look-alike drive 1 stands in drive 0's vertices
    assert any(_traj(plain, v) == 0 for v in plain.trajectories[1].chain)

    m = _scan_map(frames, scan_match=0.8)
    assert checks_scans(m) and not checks_scans(plain)
    for s, p in zip(scans[:3], poses[:3]):
        add_trajectory(m, s, p)
    chains = [t.chain for t in m.trajectories]
    assert all(_traj(m, v) == 1 for v in chains[1])      # the look-alike keeps its own vertices
    assert any(_traj(m, v) == 0 for v in chains[2])      # the drive beside drive 0 still joins it


class CameraTable(TableScorer):
    observation = "camera"


class FlatCameraEmbedding(FlatEmbedding):
    observation = "camera"


def test_a_camera_map_that_keeps_scans_checks_its_joins_by_them(three_drives):
    """Textures repeat where walls do not: a camera map reuses a vertex only
    where the scans taken with the two frames match."""
    from test_topomap import drive

    from topodrake.topomap.scan_match import joins_by_scans

    scans, poses, _ = three_drives

    def build(**config):
        m = TopoMap(CameraTable(_alike), FlatCameraEmbedding(), MapConfig.from_dict(config),
                    world="test-0")
        for d in range(3):
            add_trajectory(m, drive(d, 10), poses[d], scans=scans[d])
        return m

    on, off = build(camera_scans=True), build(camera_scans=False)
    assert joins_by_scans(on) and not joins_by_scans(off) and not checks_scans(on)
    assert any(_traj(off, v) == 0 for v in off.trajectories[1].chain)   # RE alone joins them
    assert all(_traj(on, v) == 1 for v in on.trajectories[1].chain)     # the look-alike apart
    assert any(_traj(on, v) == 0 for v in on.trajectories[2].chain)     # the same place joins
    bare = TopoMap(CameraTable(_alike), FlatCameraEmbedding(), MapConfig(), world="test-0")
    add_trajectory(bare, drive(0, 10), poses[0])
    assert not joins_by_scans(bare)                                     # no scans, no check


def _leaves_drive_0(a, b):
    """Drive 2 runs beside drive 0 and reuses its vertices up to frame 4:
    past it RE trusts drive 2's own frames only."""
    if a[0] != b[0] and ({a[0], b[0]} != {0, 2} or max(a[1], b[1]) >= 5):
        return 0.1
    return 0.999 if 0 <= b[1] - a[1] <= 3 else 0.1


def test_a_camera_map_places_the_vertices_it_reuses_by_the_scans(three_drives):
    """Hops between a drive and the vertices it reused keep the drive's
    odometry, the vertices placed by registering the kept scans."""
    from test_topomap import drive

    from topodrake.se2 import relative

    scans, poses, _ = three_drives

    def build(**config):
        m = TopoMap(CameraTable(_leaves_drive_0), FlatCameraEmbedding(),
                    MapConfig.from_dict({"teach_odometry": "perfect", **config}), world="test-0")
        for d in (0, 2):
            add_trajectory(m, drive(d, 10), poses[d], scans=scans[d])
        return m

    def joins(m):
        return [(u, v, d) for u, v, d in m.graph.edges(data=True) if d["kind"] == "trajectory"
                and {_traj(m, u), _traj(m, v)} == {0, 1}]      # trajectories numbered as added

    placed = joins(build(camera_legs=True))
    assert placed and all("leg" in d for _, _, d in placed)
    m = build(camera_legs=True)
    for u, v, d in joins(m):                       # where the vertices were taken, to 5 cm
        truth = relative(m.pose([u]), m.pose([v]))[0]
        assert np.hypot(*(d["leg"][:2] - truth[:2])) < 0.05
    assert joins(build(camera_legs=False)) and \
        not any("leg" in d for _, _, d in joins(build(camera_legs=False)))


def test_a_lidar_map_reuses_only_vertices_its_scans_place(three_drives, monkeypatch):
    """A reused vertex whose scan does not pin the translation (a corridor
    slides) would leave its hops without the drive's odometry, out of the
    loop check's sight: a lidar map with ``reuse_pinned`` does not reuse it."""
    import topodrake.topomap.build as build_module

    scans, poses, frames = three_drives

    def build(**config):
        m = _scan_map(frames, teach_odometry="perfect", **config)
        for d in (0, 2):
            add_trajectory(m, scans[d], poses[d])
        return m

    def joins(m):
        return [d for u, v, d in m.graph.edges(data=True) if d["kind"] == "trajectory"
                and _traj(m, u) != _traj(m, v)]

    placed = build()
    assert MapConfig().reuse.pinned and joins(placed)         # beside drive 0: pinned, reused
    assert all("leg" in d for d in joins(placed))
    monkeypatch.setattr(build_module, "_pinned_poses",
                        lambda source, target, *settings: [None] * len(source))
    sliding = build()
    assert not joins(sliding)                                 # nothing pins: nothing reused
    assert all(_traj(sliding, v) == 1 for v in sliding.trajectories[1].chain)
    loose = build(reuse_pinned=False)
    assert joins(loose) and not any("leg" in d for d in joins(loose))
    with pytest.raises(TopodrakeError, match="reuse_pinned"):
        MapConfig().updated(reuse_pinned="yes").validate()


def _junctions(m):
    return {(_traj(m, u), _traj(m, v)) for u, v, d in m.graph.edges(data=True)
            if d["kind"] == "junction"}


def test_junctions_need_the_scans_to_match(three_drives):
    scans, poses, frames = three_drives
    built = {}
    for sm in (0.0, 0.8):
        m = _scan_map(frames, _ends_meet, scan_match=sm, reuse=False)
        for d in (0, 1, 3):
            add_trajectory(m, scans[d], poses[d])
        built[sm] = _junctions(m)
    # RE alone joins drive 0's end to the look-alike's start too; the scans only to drive 3's
    assert built[0.0] == {(0, 1), (0, 2)}                # trajectories are numbered as added
    assert built[0.8] == {(0, 2)}


@pytest.fixture(scope="module")
def turned_departure(house, lidar):
    """As :func:`three_drives`' drives 0, 1 and 3, but drive 3 sets off 5 cm
    beside drive 0's end turned 10 deg, where their scans pair 0.72-0.76 of
    their points (a free pose of test-0 found by seed)."""
    end = house.sample_free_pose(np.random.default_rng(54))[None]
    far = _apart(house, np.random.default_rng(3), 1)[1]
    back = np.column_stack([np.arange(-9, 1) * 0.1, np.zeros(10), np.zeros(10)])
    ahead = np.column_stack([np.arange(10) * 0.1, np.zeros(10), np.zeros(10)])
    start = compose(end, np.array([[0.0, 0.05, np.radians(10)]]))
    poses = {0: compose(np.repeat(end, 10, 0), back), 1: compose(np.repeat(far, 10, 0), ahead),
             3: compose(np.repeat(start, 10, 0), ahead)}
    scans = {d: lidar.scan(p) for d, p in poses.items()}
    frames = {s.tobytes(): (d, f) for d, ss in scans.items() for f, s in enumerate(ss)}
    return scans, poses, frames


def test_a_junction_needs_its_own_share_of_matched_points(turned_departure):
    """An arrival and a departure at one place face different ways: their
    scans pair fewer points than a reuse asks, and the junction takes its
    own, lower share, still refusing the look-alike."""
    scans, poses, frames = turned_departure
    shares = scans_match(scans[3][:1], scans[0][-1:], 0.72), scans_match(scans[3][:1],
                                                                           scans[0][-1:], 0.8)
    assert shares[0][0] and not shares[1][0]             # the fixture sits between the two
    built = {}
    for share in (0.8, 0.7):
        m = _scan_map(frames, _ends_meet, scan_match=0.8, junction_scan_match=share,
                      reuse=False)
        for d in (0, 1, 3):
            add_trajectory(m, scans[d], poses[d])
        built[share] = _junctions(m)
    assert built[0.8] == set()
    assert built[0.7] == {(0, 2)}                        # trajectories are numbered as added
    with pytest.raises(TopodrakeError, match="junction_scan_match"):
        MapConfig().updated(junction_scan_match=1.0).validate()


def test_a_camera_map_joins_drives_ends_by_re_alone(three_drives):
    """A camera map checks its junctions by RE alone, not by its kept scans."""
    from test_topomap import drive

    scans, poses, _ = three_drives

    def rule(a, b):             # drive 2 here plays _ends_meet's drive 3
        return _ends_meet(*[(3 if x[0] == 2 else x[0], x[1]) for x in (a, b)])

    m = TopoMap(CameraTable(rule), FlatCameraEmbedding(), MapConfig().updated(reuse=False),
                world="test-0")
    # drive 2 (trajectory 2) sets off where drive 0 ends, but with the scans of drive 1,
    # taken in a room far away: its junction stands on RE alone
    for d, sc in ((0, scans[0]), (1, scans[1]), (2, scans[1])):
        add_trajectory(m, drive(d, 10), poses[d], scans=sc)
    assert _junctions(m) == {(0, 1), (0, 2)}


def test_links_that_match_the_view_come_first(three_drives):
    scans, poses, frames = three_drives
    m = _scan_map(frames, scan_match=0.8)
    for s, p in zip(scans[:2], poses[:2]):
        add_trajectory(m, s, p)
    own, alike = m.trajectories[0].chain[0], m.trajectories[1].chain[0]
    groups = [[(alike, 0.99)], [(own, 0.9)]]          # RE trusts the look-alike more
    assert matched_first(m, groups, scans[0][0]) == [[(own, 0.9)], [(alike, 0.99)]]
    assert matched_first(m, groups, scans[1][0]) == groups
    assert matched_first(m, groups[:1], scans[0][0]) == groups[:1]


def _alike_first(a, b):
    """As :func:`_alike`, but RE trusts the look-alike drive 1 a little more
    than drive 0's own frames."""
    if a[0] != b[0] and {a[0], b[0]} == {0, 1}:
        return 0.9995 if 0 <= b[1] - a[1] <= 3 else 0.1
    return _alike(a, b)


def test_a_camera_map_links_a_plan_where_the_view_s_scan_matches(three_drives):
    """Given the lidar scans taken with the start and goal views, a camera
    map that keeps its drives' scans links the plan at the place itself,
    not at the room that copies its textures; without them RE decides."""
    from test_topomap import drive

    from topodrake.topomap.plan import plan_path

    scans, poses, _ = three_drives
    m = TopoMap(CameraTable(_alike_first), FlatCameraEmbedding(),
                MapConfig().updated(p_edge=0.9999),
                world="test-0")          # no cross edges: two places apart
    for d in range(2):
        add_trajectory(m, drive(d, 10), poses[d], scans=scans[d])
    start, goal = drive(0, 10)[0], drive(0, 10)[9]
    blind = plan_path(m, start, goal)
    seen = plan_path(m, start, goal, view_scans=(scans[0][0], scans[0][9]))
    assert blind.reachable and seen.reachable
    assert {_traj(m, v) for v in blind.vertices} == {1}           # the look-alike
    assert {_traj(m, v) for v in seen.vertices} == {0}            # the place itself
    with pytest.raises(TopodrakeError, match="start's scan"):
        plan_path(m, start, goal, view_scans=(scans[0][0][:5], scans[0][9]))


def test_scan_match_is_checked_and_older_maps_read_it_as_off():
    from topodrake.topomap.graph import same_config

    for bad in (-0.1, 1.0, "high"):
        with pytest.raises(TopodrakeError, match="scan_match"):
            MapConfig().updated(scan_match=bad).validate()
    old = {k: v for k, v in MapConfig().flat().items() if k != "scan_match"}
    assert same_config(old, MapConfig().updated(scan_match=0.0))
    assert not same_config(old, MapConfig().updated(scan_match=0.8))


def test_lidar_map_files_keep_the_scans_as_sensed(three_drives, tmp_path):
    """Scans survive the map file bit for bit (the registration C_WP followed
    maps of millimetre scans worse); files of millimetre scans still read."""
    from topodrake.topomap.mapfile import _decode_observations, load_map, save_map

    scans, poses, frames = three_drives
    m = _scan_map(frames, scan_match=0.8)
    scan = scans[0].copy()
    scan[0, :3] = np.inf                                  # beams that hit nothing
    frames[scan[0].tobytes()] = (0, 0)
    add_trajectory(m, scan, poses[0])
    loaded = load_map(save_map(m, tmp_path / "m.tdmap"), m.scorer, FlatLidarEmbedding())
    assert loaded.bank.observations.dtype == np.float32
    np.testing.assert_array_equal(loaded.bank.observations, m.bank.observations)
    assert np.isinf(loaded.bank.observations[0, :3]).all()
    old = _decode_observations("lidar", np.array([[1234, 65535]], np.uint16))
    np.testing.assert_allclose(old, [[1.234, np.inf]], rtol=1e-6)


def _cross(m, a, b):
    """The cross edges (u, v, data) between drives ``a`` and ``b``."""
    return [(u, v, d) for u, v, d in m.graph.edges(data=True) if d["kind"] == "cross"
            and {_traj(m, u), _traj(m, v)} == {a, b}]


def test_cross_edges_carry_the_pose_their_scans_register_to(three_drives):
    """A cross edge between drives at one place carries the far vertex's pose
    in the near one's frame, from the scans (the follower tracks the car
    across it); one to the look-alike room 5 m away gets none."""
    from topodrake.se2 import relative

    scans, poses, frames = three_drives

    def build(**config):
        m = _scan_map(frames, reuse=False, join_ends=False, **config)
        for d in (0, 1, 2):
            add_trajectory(m, scans[d], poses[d])
        return m

    m = build()
    beside = _cross(m, 0, 2)
    assert MapConfig().cross.legs and beside and all("leg" in d for _, _, d in beside)
    for u, v, d in beside:
        truth = relative(m.pose([u]), m.pose([v]))[0]
        assert np.hypot(*(d["leg"][:2] - truth[:2])) < 0.05
        assert abs(d["leg"][2] - truth[2]) < 0.05
    alike = _cross(m, 0, 1)
    assert alike and not any("leg" in d for _, _, d in alike)  # RE joins them; the scans cannot
    assert not any("leg" in d for _, _, d in _cross(build(cross_legs=False), 0, 2))
    with pytest.raises(TopodrakeError, match="cross_legs"):
        MapConfig().updated(cross_legs=1).validate()


def test_the_hop_into_the_goal_carries_the_goal_scan_s_pose(three_drives):
    """The goal view is no map vertex; its scan registered onto the last
    vertex's places it, so the follower's tracker holds into the goal."""
    from topodrake.se2 import relative
    from topodrake.topomap.plan import plan_path

    scans, poses, frames = three_drives
    m = _scan_map(frames, reuse=False, join_ends=False)
    add_trajectory(m, scans[0], poses[0])
    goal_pose = poses[2][6]                            # 5 cm beside drive 0's frame 6
    plan = plan_path(m, scans[0][0], scans[2][6], goal_pose=goal_pose)
    assert plan.reachable
    last = plan.vertices[-1]
    truth = relative(m.pose([last]), goal_pose[None])[0]
    leg = plan.route.legs[-1]
    assert np.hypot(*(leg[:2] - truth[:2])) < 0.05
    m.config = m.config.updated(goal_leg=False)
    assert np.isnan(plan_path(m, scans[0][0], scans[2][6]).route.legs[-1]).all()


def test_plans_count_hops_without_legs_at_legless_p(three_drives):
    """The follower fails a hop it cannot track across (a join the scans
    could not place) more often: on a map that places joins by scans such a
    hop counts its p times ``legless_p``, in the path's choice and in its
    probability; start and goal links and hops with legs count as RE says."""
    import math
    from topodrake.topomap.plan import _hop_weight, plan_path

    scans, poses, frames = three_drives

    def joined(a, b):          # drive 0's end passes for the start of the look-alike drive 1
        if a[0] == b[0]:
            return 0.999 if 0 <= b[1] - a[1] <= 3 else 0.1
        return 0.995 if (a, b) == ((0, 9), (1, 0)) else 0.1

    m = _scan_map(frames, rule=joined, reuse=False)
    for d in (0, 1):
        add_trajectory(m, scans[d], poses[d])
    alike = _cross(m, 0, 1)
    assert alike and not any("leg" in d for _, _, d in alike)
    m.config = m.config.updated(legless_p=1.0, switch_p=1.0)    # switch_p apart
    plain = plan_path(m, scans[0][0], scans[1][9])
    m.config = m.config.updated(legless_p=0.9)
    counted = plan_path(m, scans[0][0], scans[1][9])
    assert plain.reachable and counted.vertices == plain.vertices
    legless = [i for i in range(len(plain.vertices) - 1)
               if "leg" not in m.graph.edges[plain.vertices[i], plain.vertices[i + 1]]]
    assert legless                                    # the route crosses to the look-alike
    assert math.isclose(counted.probability, plain.probability * 0.9 ** len(legless))
    hop = plain.route.edge_probability
    np.testing.assert_allclose(counted.route.edge_probability[legless], hop[legless] * 0.9)
    weight = _hop_weight(m, {(1, 2)})
    assert weight(1, 2, {"weight": 0.1, "kind": "trajectory"}) is None
    assert weight(0, 1, {"weight": 0.1, "kind": "goal"}) == 0.1
    assert math.isclose(weight(0, 1, {"weight": 0.1, "kind": "cross"}), 0.1 - math.log(0.9))
    assert weight(0, 1, {"weight": 0.1, "kind": "cross", "leg": np.zeros(3)}) == 0.1
    m.config = m.config.updated(teach_odometry="none")       # no hop has a leg: none counts
    assert _hop_weight(m, set())(0, 1, {"weight": 0.1, "kind": "cross"}) == 0.1
    with pytest.raises(TopodrakeError, match="legless_p"):
        MapConfig().updated(legless_p=0.0).validate()


def test_plans_start_at_the_anchor_the_start_s_scan_places_near(house, lidar):
    """RE trusts anchors metres along a drive as readily as the one the car
    stands by; where the start's scan registers onto an anchor within
    ``start_near_m`` the plan starts there, not at one metres on."""
    from topodrake.topomap.plan import near_start_links, plan_path

    steps = np.column_stack([np.arange(17) * 0.25, np.zeros(17), np.zeros(17)])
    rng = np.random.default_rng(5)
    while True:          # a straight 4 m of free floor
        pose = house.sample_free_pose(rng)
        poses = compose(np.repeat(pose[None], 17, 0), steps)
        if house.grid.is_free(poses[:, :2]).all():
            break
    scans = lidar.scan(poses)
    frames = {s.tobytes(): (0, f) for f, s in enumerate(scans)}

    def far_reaching(a, b):       # every frame ahead passes; the far ones a little more
        return 0.99 + 0.0005 * min(b[1] - a[1], 16) / 16 if b[1] >= a[1] else 0.1

    m = _scan_map(frames, rule=far_reaching, reuse=False, join_ends=False, start_near_m=0.0)
    add_trajectory(m, scans, poses)
    vertices = m.trajectories[0].chain
    links = [(int(v), 0.99) for v in vertices]
    assert near_start_links(m, links, scans[0]) == links                # off
    m.config = m.config.updated(start_near_m=2.0)
    near = near_start_links(m, links, scans[0])
    offsets = np.hypot(*(m.pose([v for v, _ in near])[:, :2] - poses[0][:2]).T)
    assert near and (offsets <= 2.0 + 0.1).all() and len(near) < len(links)
    assert near_start_links(m, links[:1], scans[0]) == links[:1]         # one link: kept

    m.config = m.config.updated(start_near_m=0.0)
    blind = plan_path(m, scans[0], scans[-1])
    m.config = m.config.updated(start_near_m=2.0)
    placed = plan_path(m, scans[0], scans[-1])
    first = lambda plan: np.hypot(*(m.pose(plan.vertices[:1])[0, :2] - poses[0][:2]))
    assert blind.reachable and placed.reachable
    assert first(blind) > 2.0 >= first(placed)
    with pytest.raises(TopodrakeError, match="start_near_m"):
        MapConfig().updated(start_near_m=-1.0).validate()


def test_a_near_start_vertex_faces_the_car_s_way_and_lies_not_far_behind():
    """_near_start reads the car's pose in the vertex's frame: within
    links.near_m, its heading within links.near_deg, the vertex at most
    links.near_behind_m behind the car."""
    from topodrake.topomap.plan import _near_start

    cfg = MapConfig().updated(start_near_m=2.0, start_near_deg=60.0,
                              start_near_behind_m=0.3).links
    assert _near_start(np.array([-1.0, 0.2, 0.3]), cfg)          # 1 m short of it, same way
    assert not _near_start(np.array([-1.0, 0.2, 1.4]), cfg)      # turned 80 deg
    assert not _near_start(np.array([1.0, 0.0, 0.0]), cfg)       # it lies 1 m behind the car
    assert _near_start(np.array([0.2, 0.0, 0.0]), cfg)           # 0.2 m behind: near
    assert not _near_start(np.array([-2.5, 0.0, 0.0]), cfg)      # beyond start_near_m
    with pytest.raises(TopodrakeError, match="start_near_deg"):
        MapConfig().updated(start_near_deg=-1.0).validate()
