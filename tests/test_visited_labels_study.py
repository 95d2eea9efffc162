"""studies/visited_labels.py: cold and tracked labels at the follower's visited states."""

import json

import numpy as np


def test_cold_and_tracked_labels_of_the_same_states(tmp_path, capsys):
    import importlib.util

    spec = importlib.util.spec_from_file_location("visited_labels", "studies/visited_labels.py")
    study = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(study)
    assert study.main(["--houses", "train-84", "--drives", "1", "--states", "6",
                       "--data", str(tmp_path / "data"), "--out", str(tmp_path), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert set(summary) == {"active_anchor", "next_anchor"}
    for row in summary.values():
        assert row["states"] == 6
        for key in ("success_cold", "success_tracked", "re_below_0.85_tracked_reached"):
            assert np.isclose(row[key] * 6, round(row[key] * 6), atol=1e-3)   # shares of 6
        assert 0.0 < row["mean_re_p"] < 1.0
    stored = json.loads((tmp_path / "visited_labels.json").read_text())
    assert stored["summary"] == summary and stored["command"].startswith("python studies/")
