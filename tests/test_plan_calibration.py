"""Plan calibration: a plan's chance of success fitted on training-house trials."""

import json
import shutil

import numpy as np
import pytest

from cli_run import one_line, run
from topodrake.errors import TopodrakeError
from topodrake.topomap.plan_calibration import calibration
from topodrake.topomap.plan_calibration import (FILENAME, PlanCalibration, calibration_beside,
                                                fit_from_records, fit_plan_calibration)


def _synthetic(n, seed, truth=(3.0, -0.5, 2.0)):
    """Plans whose success follows a known logistic law of log p and anchors / 10."""
    rng = np.random.default_rng(seed)
    p = rng.uniform(0.5, 1.0, n)
    anchors = rng.integers(5, 60, n)
    z = truth[0] * np.log(p) + truth[1] * anchors / 10 + truth[2]
    success = rng.random(n) < 1.0 / (1.0 + np.exp(-z))
    return p, anchors, success


def test_fit_recovers_a_known_law_and_calibrates_held_out_plans():
    p, n, y = _synthetic(6000, 0)
    cal = fit_plan_calibration("lidar", p, n, y)
    assert cal.coef[0] == pytest.approx(3.0, abs=0.6)
    assert cal.coef[1] == pytest.approx(-0.5, abs=0.15)
    assert cal.intercept == pytest.approx(2.0, abs=0.4)
    p2, n2, y2 = _synthetic(3000, 1)
    assert calibration(cal.predict(p2, n2), y2)[1] < 0.03


def test_an_overconfident_plan_probability_is_brought_to_the_success_rate():
    rng = np.random.default_rng(3)
    p = rng.uniform(0.85, 0.97, 800)
    n = rng.integers(10, 30, 800)
    y = rng.random(800) < 0.3
    raw_ece = calibration(p, y)[1]
    cal = fit_plan_calibration("lidar", p, n, y)
    assert raw_ece > 0.5
    assert calibration(cal.predict(p, n), y)[1] < 0.05
    assert cal.fitted_on["trials"] == 800 and cal.fitted_on["success_rate"] == pytest.approx(
        y.mean(), abs=1e-4)


def test_fit_refuses_what_it_cannot_fit():
    p, n, y = _synthetic(100, 2)
    with pytest.raises(TopodrakeError, match="at least 20"):
        fit_plan_calibration("lidar", p[:10], n[:10], y[:10])
    with pytest.raises(TopodrakeError, match="both successes and failures"):
        fit_plan_calibration("lidar", p, n, np.ones(100, bool))
    with pytest.raises(TopodrakeError, match="100 plans for 99 outcomes"):
        fit_plan_calibration("lidar", p, n, y[:99])
    with pytest.raises(TopodrakeError, match="finite"):
        fit_plan_calibration("lidar", np.r_[p[:-1], np.nan], n, y)


def test_a_calibration_file_round_trips_and_bad_files_are_refused(tmp_path):
    p, n, y = _synthetic(500, 4)
    cal = fit_plan_calibration("camera", p, n, y, {"houses": ["train-60"]})
    path = cal.save(tmp_path / FILENAME)
    back = PlanCalibration.load(path)
    assert back.method == "camera" and back.fitted_on["houses"] == ["train-60"]
    assert np.allclose(back.predict(p, n), cal.predict(p, n))
    assert calibration_beside(tmp_path / "checkpoint.pt").coef == cal.coef
    assert calibration_beside(tmp_path / "elsewhere" / "checkpoint.pt") is None
    good = json.loads(path.read_text())
    bad = {"not JSON": "{", "not a plan calibration": json.dumps({"format": "x"}),
           "version 9": json.dumps({**good, "version": 9}),
           "finite coefficients": json.dumps({**good, "coef": [1.0, float("nan")]}),
           "malformed": json.dumps({k: v for k, v in good.items() if k != "intercept"}),
           "features": json.dumps({**good, "features": ["log_probability"]})}
    for words, text in bad.items():
        f = tmp_path / "bad.json"
        f.write_text(text)
        with pytest.raises(TopodrakeError, match=words.split()[0]):
            PlanCalibration.load(f)
    with pytest.raises(TopodrakeError, match="does not exist"):
        PlanCalibration.load(tmp_path / "nothere.json")


def _records(houses, method="lidar", n=60, seed=5):
    rng = np.random.default_rng(seed)
    out = []
    for h in houses:
        for t in range(n):
            planned = t % 10 != 0
            out.append({"house": h, "method": method, "trial": t, "planned": planned,
                        "plan_probability": round(float(rng.uniform(0.7, 1.0)), 4) if planned
                        else 0.0, "plan_anchors": int(rng.integers(5, 40)) if planned else 0,
                        "success": bool(planned and rng.random() < 0.4)})
    return out


def test_fitting_from_records_takes_planned_trials_of_training_houses_only():
    recs = _records(["train-60", "train-61"]) + _records(["train-60"], method="lidar_reg")
    cal = fit_from_records(recs, "lidar", source="x.json")
    assert cal.fitted_on["trials"] == 108 and cal.fitted_on["houses"] == ["train-60", "train-61"]
    assert cal.fitted_on["ece_fitted"] <= cal.fitted_on["ece_raw"]
    with pytest.raises(TopodrakeError, match="calibration houses"):
        fit_from_records(recs + _records(["test-2"]), "lidar")
    with pytest.raises(TopodrakeError, match="lidar, lidar_reg"):
        fit_from_records(recs, "ours")


def test_map_calibrate_cli_writes_the_file_and_refuses_test_houses(capsys, tmp_path):
    study = tmp_path / "planning.json"
    study.write_text(json.dumps({"command": "python studies/planning.py --houses train-60",
                                 "trials": _records(["train-60", "train-61"])}))
    out = tmp_path / "cal.json"
    code, text, _ = run(capsys, "map", "calibrate", study, "--method", "lidar", "--out", out,
                        "--json")
    fit = json.loads(text)
    assert code == 0 and fit["trials"] == 108 and fit["houses"] == ["train-60", "train-61"]
    assert PlanCalibration.load(out).fitted_on["command"].startswith("python studies/planning")
    other = tmp_path / "more.json"
    other.write_text(json.dumps({"command": "c2", "trials": _records(["train-62"], seed=6)}))
    code, text, _ = run(capsys, "map", "calibrate", study, other, "--method", "lidar", "--out",
                        out, "--json", "--force")
    assert code == 0 and json.loads(text)["houses"] == ["train-60", "train-61", "train-62"]
    code, _, err = run(capsys, "map", "calibrate", study, study, "--method", "lidar", "--out",
                       out, "--force")
    one_line(code, err, "recorded twice")
    study.write_text(json.dumps({"trials": _records(["test-0"])}))
    code, _, err = run(capsys, "map", "calibrate", study, "--method", "lidar", "--out",
                       tmp_path / "c2.json")
    one_line(code, err, "calibration houses")
    assert not (tmp_path / "c2.json").exists()
    study.write_text(json.dumps({"houses": {}}))
    code, _, err = run(capsys, "map", "calibrate", study, "--method", "lidar", "--out",
                       tmp_path / "c3.json")
    one_line(code, err, "no per-trial records")


@pytest.fixture
def reg_map(small_map):
    return small_map("lidar_reg")


def test_a_plan_on_a_map_reports_the_chance_of_the_calibration_beside_its_re(capsys, tmp_path,
                                                                               reg_map):
    from topodrake.topomap.sources import ROOT
    from topodrake.world import load_world

    reach = tmp_path / "re" / "checkpoint.pt"
    reach.parent.mkdir()
    shutil.copy(ROOT / "checkpoints" / "reach_lidar_reg" / "checkpoint.pt", reach)
    p = load_world("test-0").places
    start, goal = (",".join(f"{v:.4f}" for v in p[i]) for i in (4, 9))
    capsys.readouterr()
    code, text, _ = run(capsys, "map", "plan", reg_map, "--start", start, "--goal", goal,
                        "--reach", reach, "--json")
    plain = json.loads(text)
    assert code == 0 and "success_probability" not in plain
    cal = PlanCalibration("lidar_reg", coef=[1.0, -1.0], intercept=0.5)
    cal.save(reach.parent / FILENAME)
    code, text, _ = run(capsys, "map", "plan", reg_map, "--start", start, "--goal", goal,
                        "--reach", reach, "--json")
    plan = json.loads(text)
    want = float(cal.predict(plan["probability"], plan["anchors"])[0])
    assert plan["success_probability"] == pytest.approx(want, abs=1e-4)


def test_the_planning_study_reports_the_calibrated_ece_where_every_plan_has_a_chance():
    from topodrake.experiments import plan_methods as planning

    recs = [{"method": "lidar", "planned": True, "plan_probability": 0.9,
             "success_probability": 0.5, "success": t % 2 == 0} for t in range(40)]
    recs += [{"method": "ours", "planned": True, "plan_probability": 0.9,
              "success_probability": None, "success": True} for _ in range(10)]
    cal = planning.calibration_table(["lidar", "ours", "sptm"], recs)
    assert set(cal) == {"lidar", "ours"}
    assert cal["lidar"]["calibrated"] and cal["lidar"]["ece"] == 0.0
    assert cal["lidar"]["ece_raw"] == pytest.approx(0.4)
    assert not cal["ours"]["calibrated"] and cal["ours"]["ece"] == pytest.approx(0.1)


def test_each_learned_method_has_one_place_for_its_plan_calibration():
    from topodrake.experiments.plan_methods import plan_calibration_path
    from topodrake.topomap.sources import ROOT

    ck = ROOT / "checkpoints"
    assert plan_calibration_path("lidar") == ck / "reach_lidar_k5" / FILENAME
    assert plan_calibration_path("ours_replan") == ck / "reach_camera_k5" / FILENAME
    # the C_WP at scale follows the lidar map with another C_WP than the map's own
    assert plan_calibration_path("lidar_scale") == ck / "lidar_k5_scale" / FILENAME
    assert plan_calibration_path("oracle_full") is None
    with pytest.raises(ValueError, match="unknown method"):
        plan_calibration_path("lidar_k9")


def test_map_calibrate_fits_the_method_named_and_not_another(capsys, tmp_path):
    recs = _records(["train-60"])
    scale = [dict(r, method="lidar_scale", success=r["planned"] and r["trial"] % 3 == 0)
             for r in recs]
    planned = [r for r in scale if r["planned"]]
    study = tmp_path / "planning.json"
    study.write_text(json.dumps({"command": "c", "trials": recs + scale}))
    out = tmp_path / "scale.json"
    code, text, _ = run(capsys, "map", "calibrate", study, "--method", "lidar_scale", "--out",
                        out, "--json")
    assert code == 0 and json.loads(text)["method"] == "lidar_scale"
    cal = PlanCalibration.load(out)
    assert cal.fitted_on["trials"] == len(planned)
    assert cal.fitted_on["success_rate"] == pytest.approx(
        np.mean([r["success"] for r in planned]), abs=0.01)
