"""studies/map_scalability.py with a map config of its own: the config is
used, recorded, and keys the caches, and a bad one is refused in one line."""

import json


def test_a_map_config_is_used_recorded_and_keys_the_caches(tmp_path, capsys, load_study):
    study = load_study("map_scalability")
    cfg = tmp_path / "k3.yaml"
    cfg.write_text("retrieval_k: 3\np_edge: 0.95\n")
    common = ["--modality", "oracle", "--worlds", "test-0", "--trajectories", "2",
              "--hop-samples", "0", "--dense-samples", "1", "--recall-trajectories", "1",
              "--data", str(tmp_path / "data"), "--quiet", "--json"]
    assert study.main(common + ["--config", str(cfg), "--out", str(tmp_path / "a")]) == 0
    out = json.loads((tmp_path / "a" / "map_scalability.json").read_text())
    assert out["map_config"]["retrieval_k"] == 3 and out["map_config"]["p_edge"] == 0.95
    house = out["houses"]["test-0"]
    assert house["retrieval"]["retrieval_k"] == 3 and house["vertices"] > 2
    assert study.main(common + ["--out", str(tmp_path / "b")]) == 0
    default = json.loads((tmp_path / "b" / "map_scalability.json").read_text())
    assert default["map_config"]["retrieval_k"] == 64
    # each config has its own cached map and per-house result
    maps = sorted(p.name for p in (tmp_path / "data" / "maps").glob("*.tdmap"))
    assert len(maps) == 2 and "test-0-oracle-shuffled.tdmap" in maps
    assert len(list((tmp_path / "a" / "map_scalability_runs").glob("*.json"))) == 1
    assert default["order"] == "shuffled"
    capsys.readouterr()
    bad = tmp_path / "bad.yaml"
    bad.write_text("retrieval_k: 0\n")
    assert study.main(common + ["--config", str(bad), "--out", str(tmp_path / "c")]) == 2
    err = capsys.readouterr().err
    assert "bad.yaml" in err and "retrieval_k" in err and "Traceback" not in err


def test_drives_are_added_in_a_seeded_random_order_unless_told(tmp_path, load_study):
    from topodrake.topomap.mapfile import read_map_meta

    study = load_study("map_scalability")
    common = ["--modality", "oracle", "--worlds", "test-0", "--trajectories", "3",
              "--hop-samples", "0", "--dense-samples", "1", "--recall-trajectories", "0",
              "--data", str(tmp_path / "data"), "--out", str(tmp_path / "out"), "--quiet"]
    names = {}
    for order in ("shuffled", "collected"):
        assert study.main(common + ["--order", order]) == 0
        name = "test-0-oracle" + ("-shuffled" if order == "shuffled" else "") + ".tdmap"
        meta = read_map_meta(tmp_path / "data" / "maps" / name)
        names[order] = [t["name"] for t in meta["trajectories"]]
    assert names["collected"] == ["pairs-s0/0", "pairs-s0/1", "pairs-s0/2"]
    assert len(set(names["shuffled"])) == 3 and names["shuffled"] != names["collected"]
    assert study.main(common + ["--order", "shuffled"]) == 0      # the same seed, the same order
    meta = read_map_meta(tmp_path / "data" / "maps" / "test-0-oracle-shuffled.tdmap")
    assert [t["name"] for t in meta["trajectories"]] == names["shuffled"]
