"""The link audit: plans judged in truth, pooled over buildings."""

import pytest

from topodrake.errors import TopodrakeError
from topodrake.experiments import link_audit as la


def test_the_audit_pools_plans_over_buildings(monkeypatch):
    rows = {"a": {"trials": 10, "drives": 9, "vertices": 50, "planned": 1.0,
                  "false_link_plans": 0.1, "false_link_kinds": {"start": 1}, "uncovered": 0.0,
                  "wall_s": 1.0},
            "b": {"trials": 10, "drives": 9, "vertices": 50, "planned": 0.5,
                  "false_link_plans": 0.4, "false_link_kinds": {"cross": 1, "goal": 1},
                  "uncovered": 0.5, "wall_s": 1.0}}
    monkeypatch.setattr(la, "audit_building", lambda study, spec, method, progress: rows[spec])
    monkeypatch.setattr(la, "house_key", lambda spec: spec)
    doc = la.link_audit(la.LinkAuditStudy(houses=["a", "b"]), "cmd", quiet=True)
    pooled = doc["summary"]["pooled"]["lidar_reg"]
    assert pooled["plans"] == 15 and pooled["false_link_plans"] == round(3 / 15, 4)
    assert pooled["worst_building"] == 0.4 and pooled["uncovered"] == 0.25
    assert doc["summary"]["by_building"]["b"]["lidar_reg"] is rows["b"]


def test_the_audit_refuses_what_it_cannot_plan():
    with pytest.raises(TopodrakeError, match="not sptm"):
        la.LinkAuditStudy(methods=["sptm"]).validate()
    with pytest.raises(TopodrakeError, match="trials"):
        la.LinkAuditStudy(trials=0).validate()
