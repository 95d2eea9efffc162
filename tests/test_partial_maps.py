"""The partial-maps study: its place subsets, its figures, its scenario."""

import pytest

from topodrake.errors import TopodrakeError
from topodrake.experiments.partial_maps import (
    PartialMapsStudy,
    all_pairs,
    coverage_figures,
    place_subset,
)


def _rec(planned, success, covered, false_kind="", uncovered=None, p=0.9):
    r = {"planned": planned, "success": success, "covered_in_truth": covered,
         "plan_probability": p if planned else 0.0, "success_probability": None,
         "false_link_m": (3.0 if false_kind else 0.0) if planned else None}
    if false_kind:
        r["false_link_kind"] = false_kind
    if uncovered:
        r["uncovered"] = uncovered
    return r


def test_place_subsets_are_seeded_sorted_and_apart_per_map():
    a = place_subset(10, 4, 7, 0)
    assert a == sorted(a) and len(set(a)) == 4 and a == place_subset(10, 4, 7, 0)
    assert place_subset(10, 4, 7, 1) != a or place_subset(10, 4, 8, 0) != a
    with pytest.raises(TopodrakeError, match="2..10"):
        place_subset(10, 11, 0, 0)


def test_every_ordered_pair_once():
    pairs = all_pairs(4)
    assert len(pairs) == 12 and len({tuple(p) for p in pairs}) == 12
    assert all(a != b for a, b in pairs)


def test_figures_separate_wrong_plans_refusals_and_misses():
    records = [_rec(True, True, True), _rec(True, False, True, false_kind="goal"),
               _rec(True, True, True, false_kind="cross"),        # not a coverage mistake
               _rec(False, False, False, uncovered="goal"),       # rightly refused
               _rec(False, False, True, uncovered="start"),       # wrongly refused
               _rec(False, False, False)]                         # unplanned, another reason
    f = coverage_figures(records)
    assert f["queries"] == 6 and f["planned"] == 0.5
    assert f["covered_link_false"] == round(1 / 3, 4)
    assert f["false_link_plans"] == round(2 / 3, 4)
    assert f["refused"] == round(2 / 6, 4)
    assert f["uncovered_refused"] == 1.0            # both queries outside got no plan
    assert f["covered_refused"] == 0.25             # one of four covered in truth refused
    assert f["success"] == round(2 / 6, 4) and f["success_planned"] == round(2 / 3, 4)
    assert f["ece"] == pytest.approx(abs(0.9 - 2 / 3), abs=1e-4)


def test_the_study_refuses_bad_settings_by_name():
    with pytest.raises(TopodrakeError, match="sptm"):
        PartialMapsStudy(methods=["sptm"]).validate()
    with pytest.raises(TopodrakeError, match="counts >= 2"):
        PartialMapsStudy(places=[1]).validate()
    with pytest.raises(TopodrakeError, match="links.cover|link_cover"):
        PartialMapsStudy(map={"link_cover": 2.0}).validate()
    assert PartialMapsStudy().validate().places == [4, 5, 6, 7]


def test_two_runs_compare_query_by_query(tmp_path):
    import json

    from topodrake.experiments.partial_maps import paired_runs

    def run(name, refuse):
        trials = [{"method": "m", "house": "h", "map_places": [1, 2], "trial": t,
                   "success": t == 0, "planned": not (refuse and t == 1),
                   **({"uncovered": "goal"} if refuse and t == 1 else
                      {"false_link_kind": "goal"} if t == 1 else {})} for t in range(3)]
        path = tmp_path / name
        path.write_text(json.dumps({"trials": trials}))
        return path

    doc = paired_runs(run("a.json", False), run("b.json", True))["m"]
    assert doc["queries"] == 3
    assert doc["covered_link_false"]["before"] == round(1 / 3, 4)
    assert doc["covered_link_false"]["after"] == 0.0 and doc["refused"]["after"] == round(1 / 3, 4)
    assert doc["success"]["difference"]["mean"] == 0.0
    (tmp_path / "bad.json").write_text("{}")
    with pytest.raises(TopodrakeError, match="not a partial-maps result"):
        paired_runs(tmp_path / "bad.json", tmp_path / "a.json")
