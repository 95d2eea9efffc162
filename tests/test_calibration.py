"""Calibration metrics against hand-computed and simulated cases."""

import numpy as np
import pytest

from topodrake.errors import TopodrakeError
from topodrake.learning.reachability.calibration import (auroc, brier, calibration_summary, ece,
                                                         fit_temperature, reliability)


def test_reliability_and_ece_by_hand():
    p = np.array([0.05, 0.05, 0.95, 0.95, 0.55, 0.55])
    y = np.array([0, 0, 1, 0, 1, 1])
    r = reliability(p, y, bins=10)
    assert r.count.tolist() == [2, 0, 0, 0, 0, 2, 0, 0, 0, 2]
    assert r.rate[0] == 0 and r.rate[5] == 1 and r.rate[9] == 0.5
    assert np.isnan(r.rate[1])
    # |0 - .05| * 2 + |1 - .55| * 2 + |.5 - .95| * 2, over 6
    assert ece(p, y) == pytest.approx((0.1 + 0.9 + 0.9) / 6)
    assert brier(p, y) == pytest.approx(np.mean((p - y) ** 2))
    # p = 1.0 falls into the last bin, not past it
    assert reliability([1.0, 0.0], [1, 0]).count.sum() == 2


def test_calibrated_predictions_have_small_ece_and_overconfident_ones_do_not():
    rng = np.random.default_rng(0)
    p = rng.random(20000)
    y = (rng.random(20000) < p).astype(int)
    assert ece(p, y) < 0.02
    sharp = np.clip(0.5 + 1.8 * (p - 0.5), 0, 1)          # over-confident
    assert ece(sharp, y) > 0.1


def test_auroc_cases():
    assert auroc([0.1, 0.2, 0.8, 0.9], [0, 0, 1, 1]) == 1.0
    assert auroc([0.9, 0.8, 0.2, 0.1], [0, 0, 1, 1]) == 0.0
    assert auroc([0.5, 0.5, 0.5, 0.5], [0, 1, 0, 1]) == 0.5      # ties count half
    # one inversion among 2 x 2 pairs
    assert auroc([0.1, 0.6, 0.5, 0.9], [0, 0, 1, 1]) == pytest.approx(0.75)
    with pytest.raises(TopodrakeError, match="both"):
        auroc([0.2, 0.3], [1, 1])
    assert calibration_summary([0.2, 0.3], [1, 1])["auroc"] is None


def test_temperature_scaling_recovers_the_true_temperature():
    rng = np.random.default_rng(1)
    z_true = rng.normal(0, 2, 20000)
    y = (rng.random(z_true.size) < 1 / (1 + np.exp(-z_true))).astype(int)
    assert fit_temperature(3.0 * z_true, y) == pytest.approx(3.0, rel=0.08)
    assert fit_temperature(z_true, y) == pytest.approx(1.0, rel=0.08)


def test_bad_input_is_refused():
    with pytest.raises(TopodrakeError, match="probabilities"):
        ece([1.5], [1])
    with pytest.raises(TopodrakeError, match="0 or 1"):
        brier([0.5], [2])
    with pytest.raises(TopodrakeError, match="outcomes"):
        brier([0.5, 0.2], [1])
    with pytest.raises(TopodrakeError, match="no predictions"):
        ece([], [])


def test_platt_scaling_recovers_slope_and_bias():
    from topodrake.learning.reachability.calibration import fit_platt

    rng = np.random.default_rng(0)
    z = rng.normal(0.0, 3.0, 20000)
    y = (rng.random(z.size) < 1 / (1 + np.exp(-(0.5 * z + 1.5)))).astype(int)
    a, b = fit_platt(z, y)
    assert a == pytest.approx(0.5, abs=0.05) and b == pytest.approx(1.5, abs=0.1)
    with pytest.raises(TopodrakeError, match="0 or 1"):
        fit_platt(z[:3], [0, 1, 2])
