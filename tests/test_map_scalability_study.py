"""studies/map_scalability.py with a map config of its own: the config is
used, recorded, and keys the caches, and a bad one is refused in one line."""

import json

from study_run import run_study


def test_a_map_config_is_used_recorded_and_keys_the_caches(tmp_path):
    cfg = tmp_path / "k3.yaml"
    cfg.write_text("retrieval_k: 3\np_edge: 0.95\n")
    common = ["--modality", "oracle", "--worlds", "test-0", "--trajectories", "2",
              "--hop-samples", "0", "--dense-samples", "1", "--recall-trajectories", "1",
              "--data", str(tmp_path / "data"), "--quiet", "--json"]
    code, _, err = run_study("map_scalability", *common, "--config", cfg, "--out", tmp_path / "a")
    assert code == 0, err
    out = json.loads((tmp_path / "a" / "map_scalability.json").read_text())
    assert out["map_config"]["retrieval_k"] == 3 and out["map_config"]["p_edge"] == 0.95
    house = out["houses"]["test-0"]
    assert house["retrieval"]["retrieval_k"] == 3 and house["vertices"] > 2
    code, _, err = run_study("map_scalability", *common, "--out", tmp_path / "b")
    assert code == 0, err
    default = json.loads((tmp_path / "b" / "map_scalability.json").read_text())
    assert default["map_config"]["retrieval_k"] == 64
    # each config has its own cached map and per-house result
    maps = sorted(p.name for p in (tmp_path / "data" / "maps").glob("*.tdmap"))
    assert len(maps) == 2 and "test-0-oracle-shuffled.tdmap" in maps
    assert len(list((tmp_path / "a" / "map_scalability_runs").glob("*.json"))) == 1
    assert default["order"] == "shuffled"
    bad = tmp_path / "bad.yaml"
    bad.write_text("retrieval_k: 0\n")
    code, _, err = run_study("map_scalability", *common, "--config", bad, "--out", tmp_path / "c")
    assert code == 2
    assert "bad.yaml" in err and "retrieval_k" in err and "Traceback" not in err


def test_drives_are_added_in_a_seeded_random_order_unless_told(tmp_path):
    from topodrake.topomap.mapfile import read_map_meta

    common = ["--modality", "oracle", "--worlds", "test-0", "--trajectories", "3",
              "--hop-samples", "0", "--dense-samples", "1", "--recall-trajectories", "0",
              "--data", str(tmp_path / "data"), "--out", str(tmp_path / "out"), "--quiet"]
    names = {}
    for order in ("shuffled", "collected"):
        code, _, err = run_study("map_scalability", *common, "--order", order)
        assert code == 0, err
        name = "test-0-oracle" + ("-shuffled" if order == "shuffled" else "") + ".tdmap"
        meta = read_map_meta(tmp_path / "data" / "maps" / name)
        names[order] = [t["name"] for t in meta["trajectories"]]
    assert names["collected"] == ["pairs-s0/0", "pairs-s0/1", "pairs-s0/2"]
    assert len(set(names["shuffled"])) == 3 and names["shuffled"] != names["collected"]
    code, _, err = run_study("map_scalability", *common, "--order", "shuffled")
    assert code == 0, err                                         # the same seed, the same order
    meta = read_map_meta(tmp_path / "data" / "maps" / "test-0-oracle-shuffled.tdmap")
    assert [t["name"] for t in meta["trajectories"]] == names["shuffled"]


def test_the_default_scenario_is_the_figures_run_and_every_named_scenario_loads():
    from study_run import check_scenarios

    from topodrake.experiments.map_scalability import ScalabilityStudy

    check_scenarios("map_scalability", ScalabilityStudy, ("default", "collected_order"),
                    {"default": ["--json"], "collected_order": ["--order", "collected"]})
