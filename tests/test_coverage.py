"""Coverage: a plan refuses a start or goal the map's drives never passed."""

import json

import numpy as np
import pytest
from cli_run import run

from topodrake.errors import TopodrakeError
from topodrake.topomap.graph import MapConfig
from topodrake.topomap.plan import plan_path
from topodrake.topomap.sources import drive_observations, open_map


@pytest.fixture(scope="module")
def lidar_49(small_map):
    """test-0's lidar map of the drives between places 4 and 9, and the
    observations at every place."""
    loaded = open_map(small_map("lidar"))
    obs = drive_observations(loaded.world, loaded.topomap.scorer, loaded.world.places)
    return loaded, obs


def test_a_goal_the_drives_never_passed_is_refused_as_not_covered(lidar_49):
    """RE links place 8's view to a vertex of the 4 <-> 9 drives; its scan
    registers onto none of them: no plan, with that reason. The same query
    without the check plans there, confidently."""
    loaded, obs = lidar_49
    m = loaded.topomap
    refused = plan_path(m, obs[4], obs[8])
    assert not refused.reachable and refused.uncovered == "goal"
    assert "goal is not covered by the map" in refused.reason and refused.goal_links > 0
    assert refused.summary()["uncovered"] == "goal"
    config = m.config
    try:
        m.config = config.updated(link_cover=0.0)
        blind = plan_path(m, obs[4], obs[8])
    finally:
        m.config = config
    assert blind.reachable and blind.probability > 0.3


def test_places_the_drives_joined_still_plan(lidar_49):
    loaded, obs = lidar_49
    for a, b in ((4, 9), (9, 4)):
        result = plan_path(loaded.topomap, obs[a], obs[b])
        assert result.reachable and not result.uncovered and result.probability > 0.5


def test_a_start_the_drives_never_passed_is_refused_too(lidar_49):
    loaded, obs = lidar_49
    refused = plan_path(loaded.topomap, obs[0], obs[9])
    assert not refused.reachable and refused.uncovered == "start"
    assert "start is not covered" in refused.reason


def test_map_plan_exits_1_for_an_uncovered_goal_and_says_why(capsys, small_map):
    code, out, err = run(capsys, "map", "plan", small_map("lidar"), "--start-place", "4",
                         "--goal-place", "8", "--json")
    assert code == 1
    assert "not covered by the map" in err
    assert json.loads(out)["reachable"] is False


def test_bench_map_counts_uncovered_places_unreachable(capsys, small_map):
    code, out, _ = run(capsys, "bench", "map", small_map("lidar"), "--json", "--quiet")
    summary = json.loads(out)
    assert code == 0 and summary["reachable"] < summary["queries"]
    why = summary["unreachable_why"]
    assert any("not covered" in reason for reason in why), why


def test_the_cover_share_is_checked_like_every_map_setting():
    with pytest.raises(TopodrakeError, match="links.cover"):
        MapConfig.from_dict({"links": {"cover": 1.5}}).validate()
    assert MapConfig.from_dict({"link_cover": 0.0}).links.cover == 0.0


def test_registration_shares_rate_a_place_against_itself_above_a_look_alike(lidar_49):
    from topodrake.topomap.coverage import registration_shares

    loaded, obs = lidar_49
    m = loaded.topomap
    poses = m.pose(sorted(m.graph.nodes)).reshape(-1, 3)
    near9 = int(np.argmin(np.hypot(*(poses[:, :2] - loaded.world.places[9][:2]).T)))
    shares = registration_shares(m, [sorted(m.graph.nodes)[near9]], obs[9])
    assert shares[0] >= m.config.links.cover
    assert registration_shares(m, [sorted(m.graph.nodes)[near9]], obs[8])[0] < 0.5
