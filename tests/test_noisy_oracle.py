"""The A* oracle C_WP with a controlled error: its spec, its kinds of error, its determinism."""

import numpy as np
import pytest

from topodrake.errors import TopodrakeError
from topodrake.learning.waypoint.noisy_oracle import NoisyOracle, OracleError, parse_oracle_spec
from topodrake.learning.waypoint.policy import AStarOracle, WaypointPrediction


@pytest.mark.parametrize("spec,says", [
    ("oracle:anchor", "'anchor' in 'oracle:anchor' is not KEY=VALUE"),
    ("oracle:", "'' in 'oracle:' is not KEY=VALUE"),
    ("oracle:bias=0.3", "unknown key 'bias'"),
    ("oracle:anchor=big", "anchor='big' is not a number"),
    ("oracle:anchor=-0.1", "anchor=-0.1 must be finite and >= 0"),
    ("oracle:fresh=nan", "fresh=nan must be finite"),
    ("oracle:tail=1.5", "tail=1.5 must be a probability"),
    ("oracle:seed=1.5", "seed='1.5' is not an integer"),
    ("oracle:anchor=0.1:anchor=0.2", "key 'anchor' given twice"),
    ("oracles:anchor=0.1", "is not an oracle spec"),
])
def test_a_bad_spec_is_one_line_naming_the_key(spec, says):
    with pytest.raises(TopodrakeError) as got:
        parse_oracle_spec(spec)
    assert says in str(got.value) and "\n" not in str(got.value)


def test_a_spec_reads_its_keys_and_writes_them_back():
    e = parse_oracle_spec("oracle:tail=0.08:anchor=0.3:seed=4")
    assert e == OracleError(anchor=0.3, tail=0.08, seed=4)
    assert e.text == "oracle:anchor=0.3:tail=0.08:seed=4"
    assert parse_oracle_spec("oracle") == OracleError() and OracleError().text == "oracle"


class _Flat:
    """An oracle that always answers waypoint (1, 0) (no A*)."""

    def predict(self, observation, target):
        n = max(len(np.reshape(observation, (-1, 3))), len(target))
        return WaypointPrediction(np.tile([1.0, 0.0], (n, 1)), np.zeros(n), np.ones((n, 2)))

    def encode_target(self, context):
        return np.asarray(context, np.float64)[:, 0]


def _noisy(box_world, spec):
    policy = NoisyOracle(box_world, spec)
    policy.oracle = _Flat()
    return policy


def test_the_anchor_error_is_fixed_per_target_and_differs_between_targets(box_world):
    targets = np.array([[3.0, 3.0, 0.0], [7.0, 8.0, 1.0]])
    car = np.array([[2.0, 2.0, 0.3]])
    a = _noisy(box_world, "oracle:anchor=0.3")
    first = a.predict(np.repeat(car, 2, 0), a.encode_target(targets[:, None])).waypoint
    for _ in range(3):                                    # every period, and as bare poses
        np.testing.assert_array_equal(a.predict(car, a.encode_target(targets[:1, None])).waypoint,
                                      first[:1])
        np.testing.assert_array_equal(a.predict(car, targets[1]).waypoint, first[1:])
    assert np.abs(first[0] - first[1]).max() > 1e-3
    # another oracle of the same spec, in another order: the same errors
    b = _noisy(box_world, "oracle:anchor=0.3")
    np.testing.assert_array_equal(b.predict(car, targets[1]).waypoint, first[1:])
    other = _noisy(box_world, "oracle:anchor=0.3:seed=1").predict(car, targets[1]).waypoint
    assert np.abs(other - first[1:]).max() > 1e-3
    # a world-frame displacement: its size does not depend on the car's heading
    turned = a.predict(np.array([[2.0, 2.0, 2.0]]), targets[1]).waypoint
    assert np.hypot(*(turned[0] - [1, 0])) == pytest.approx(np.hypot(*(first[1] - [1, 0])))
    errs = a.anchor_error(np.random.default_rng(0).uniform(0, 10, (2000, 3)))
    assert 0.27 < errs.std() < 0.33 and abs(errs.mean()) < 0.03


def test_the_fresh_error_changes_per_call_and_repeats_with_the_seed(box_world):
    car, tgt = np.array([[2.0, 2.0, 0.3]]), np.array([[3.0, 3.0, 0.0]])
    a, b = _noisy(box_world, "oracle:fresh=0.2"), _noisy(box_world, "oracle:fresh=0.2")
    got = np.array([a.predict(car, tgt).waypoint[0] for _ in range(500)])
    assert len(np.unique(got[:, 0])) == 500
    assert 0.17 < (got - [1, 0]).std() < 0.23
    again = np.array([b.predict(car, tgt).waypoint[0] for _ in range(500)])
    np.testing.assert_array_equal(got, again)


def test_the_tail_rotates_its_share_by_45_to_180_degrees(box_world):
    a = _noisy(box_world, "oracle:tail=0.1")
    n = 2000
    wp = a.perturb(np.tile([2.0, 0.0], (n, 1)), np.zeros(n), np.zeros((n, 2)))
    angle = np.degrees(np.abs(np.arctan2(wp[:, 1], wp[:, 0])))
    turned = angle > 1e-6
    assert 0.08 < turned.mean() < 0.12
    assert angle[turned].min() >= 45.0 - 1e-6 and angle[turned].max() <= 180.0 + 1e-6
    assert 0.3 < (wp[turned, 1] > 0).mean() < 0.7             # both sides
    np.testing.assert_allclose(np.hypot(*wp.T), 2.0)           # a rotation, not a new length
    np.testing.assert_array_equal(_noisy(box_world, "oracle").perturb(wp, np.zeros(n),
                                                                      np.zeros((n, 2))), wp)


def test_without_error_it_is_the_a_star_oracle_exactly(box_world):
    rng = np.random.default_rng(0)
    cars = np.column_stack([rng.uniform(1, 4, 6), rng.uniform(1, 8, 6), rng.uniform(-3, 3, 6)])
    targets = np.column_stack([rng.uniform(6, 9, 6), rng.uniform(1, 8, 6), rng.uniform(-3, 3, 6)])
    exact = AStarOracle(box_world, k=2)
    noisy = NoisyOracle(box_world, "oracle", k=2)
    ctx = np.repeat(targets[:, None], 5, axis=1)
    want = exact.predict(cars, exact.encode_target(ctx))
    for spec in ("oracle", "oracle:anchor=0:fresh=0:tail=0:seed=3"):
        noisy = NoisyOracle(box_world, spec, k=2)
        got = noisy.predict(cars, noisy.encode_target(ctx))
        np.testing.assert_array_equal(got.waypoint, want.waypoint)
        np.testing.assert_array_equal(got.heading_diff, want.heading_diff)
        np.testing.assert_array_equal(got.overlap, want.overlap)
    # with an error: only the waypoint moves
    got = NoisyOracle(box_world, "oracle:anchor=0.3:fresh=0.1", k=2).predict(cars, targets)
    np.testing.assert_array_equal(got.heading_diff, want.heading_diff)
    np.testing.assert_array_equal(got.overlap, want.overlap)
    assert np.abs(got.waypoint - want.waypoint).min() > 0


def test_the_spec_names_a_c_wp_wherever_a_checkpoint_does(box_world):
    from topodrake.experiments.bench_onpolicy import CONTROLLERS, parse_controllers
    from topodrake.learning.reachability.controllers import controller_policy

    got = parse_controllers("lidar_k5", ["lidar_k5=oracle:anchor=0.3"], must_exist=True)
    assert got == {"lidar_k5": ("oracle:anchor=0.3", *CONTROLLERS["lidar_k5"][1:])}
    # an RE override belongs to the controller's own C_WP, not to the oracle
    got = parse_controllers("lidar_k5", ["lidar_k5=oracle"], ["lidar_k5=r.pt"])
    assert got == {"lidar_k5": ("oracle", "r.pt", CONTROLLERS["lidar_k5"][0])}
    with pytest.raises(TopodrakeError, match="unknown key 'bias'"):
        parse_controllers("lidar_k5", ["lidar_k5=oracle:bias=1"], must_exist=True)
    policy = controller_policy("oracle:fresh=0.1", box_world)
    assert isinstance(policy, NoisyOracle) and policy.error == OracleError(fresh=0.1)
    with pytest.raises(TopodrakeError, match="A\\* oracle of a world"):
        controller_policy("oracle:fresh=0.1")
