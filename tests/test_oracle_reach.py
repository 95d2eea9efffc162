"""The geometric oracle and its calibration against A* oracle rollouts."""

import math

import numpy as np
import pytest

from topodrake.experiments.oracle_reach import calibration_scores, fit_oracle, oracle_reach_pairs
from topodrake.topomap.scorer import (CALIBRATED_ORACLE, OracleConfig, geometric_reach,
                                      pair_geometry, reach_from_geometry)


def test_calibration_scores_on_hand_made_data():
    y = np.array([0, 0, 1, 1])
    perfect = calibration_scores(np.array([0.0, 0.0, 1.0, 1.0]), y)
    assert perfect["auroc"] == 1.0 and perfect["ece"] == 0.0
    flat = calibration_scores(np.full(4, 0.5), y)
    assert flat["auroc"] == 0.5 and flat["ece"] == 0.0 and flat["nll"] == pytest.approx(math.log(2), 1e-3)
    wrong = calibration_scores(np.array([0.9, 0.9, 0.1, 0.1]), y)
    assert wrong["auroc"] == 0.0 and wrong["ece"] == pytest.approx(0.9)


def test_pair_geometry_reads_distance_turn_bearing_overlap_and_sight(box_world):
    a = np.array([[2.0, 2.0, 0.0], [2.0, 2.0, 0.0], [2.0, 2.0, 0.0]])
    b = np.array([[4.0, 2.0, 0.0], [0.5, 2.0, math.pi], [8.0, 2.0, 0.0]])   # ahead, behind, past the wall
    g = pair_geometry(box_world, a, b)
    np.testing.assert_allclose(g["distance"], [2.0, 1.5, 6.0])
    np.testing.assert_allclose(g["turn"], [0.0, math.pi, 0.0], atol=1e-9)
    np.testing.assert_allclose(g["bearing"], [0.0, math.pi, 0.0], atol=1e-9)
    assert g["sight"].tolist() == [True, True, False]
    assert g["overlap"][0] > 0.3 and g["overlap"][1] < 0.05
    p = geometric_reach(box_world, a, b, OracleConfig())
    assert p[0] > 0.98 and p[1] < 0.05 and p[2] < 0.5
    np.testing.assert_allclose(p, reach_from_geometry(g, OracleConfig()), atol=1e-6)


def test_fit_recovers_the_distance_that_decides_the_outcome():
    rng = np.random.default_rng(0)
    n = 600
    d = rng.uniform(0, 8, n)
    g = {"distance": d, "turn": np.zeros(n), "bearing": np.zeros(n), "overlap": np.ones(n),
         "sight": np.ones(n, bool)}
    y = (d < 4.0).astype(float)
    start = OracleConfig(reach_m=2.0, bearing_rad=math.inf, min_overlap=0.0, hidden=0.0)
    fitted, nll = fit_oracle(g, y, start, {"reach_m": [2.0, 3.0, 4.0, 5.0, 6.0]})
    assert fitted.reach_m == 4.0 and nll < 0.1


def test_oracle_pairs_are_seeded_and_labelled_by_rollouts(box_world):
    from topodrake.rollout import ExpertRollout, RolloutConfig

    res = ExpertRollout(box_world, RolloutConfig(t_max_s=60.0)).run(
        np.array([[1.5, 2.0, 0.0], [8.0, 8.0, math.pi]]), np.array([[8.0, 2.0], [1.5, 8.0]]))
    drives = [res.trajectory(i)["poses"] for i in range(2)]
    a = oracle_reach_pairs(box_world, drives, 6, seed=3, noise_std=0.0)
    b = oracle_reach_pairs(box_world, drives, 6, seed=3, noise_std=0.0)
    np.testing.assert_array_equal(a["src"], b["src"])
    np.testing.assert_array_equal(a["label"], b["label"])
    assert a["label"].shape == (6,) and set(a["label"].tolist()) <= {0, 1}
    near = a["same"] & (np.hypot(*(a["tgt"][:, :2] - a["src"][:, :2]).T) < 2.0)
    assert a["label"][near].mean() >= 0.5 if near.any() else True


def test_calibrated_oracle_never_claims_certainty():
    """The calibrated parameters stay below the map's 0.99 where the
    controller is at its best (it fails some of the label protocol there)."""
    g = {"distance": np.array([1.0]), "turn": np.zeros(1), "bearing": np.zeros(1),
         "overlap": np.ones(1), "sight": np.ones(1, bool)}
    assert 0.95 < reach_from_geometry(g, CALIBRATED_ORACLE)[0] < 0.99
    assert reach_from_geometry(g, OracleConfig())[0] > 0.99


def test_the_maps_oracle_rates_short_reverses_as_reachable():
    """A target close behind the car (a turn on the spot, a three-point
    turn's reverse) is rated by distance, overlap and sight alone; one
    farther behind than ``reverse_m`` still counts as hard."""
    g = {"distance": np.array([0.5, 0.5, 3.0]), "turn": np.zeros(3),
         "bearing": np.array([math.pi, 0.0, math.pi]), "overlap": np.ones(3),
         "sight": np.ones(3, bool)}
    p = reach_from_geometry(g, OracleConfig())
    assert p[0] == pytest.approx(p[1], abs=5e-3) and p[0] > 0.99
    assert p[2] < 0.6
    fitted = reach_from_geometry(g, OracleConfig(reverse_m=0.0))
    assert fitted[0] < 0.6 and fitted[2] < 0.6


def test_the_default_scenario_is_the_figures_run():
    from study_run import check_scenarios

    from topodrake.experiments.oracle_reach import OracleReachStudy

    check_scenarios("oracle_reach", OracleReachStudy, ("default",), {"default": ["--json"]})
