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
    assert len(maps) == 2 and "test-0-oracle.tdmap" in maps
    assert len(list((tmp_path / "a" / "map_scalability_runs").glob("*.json"))) == 1
    capsys.readouterr()
    bad = tmp_path / "bad.yaml"
    bad.write_text("retrieval_k: 0\n")
    assert study.main(common + ["--config", str(bad), "--out", str(tmp_path / "c")]) == 2
    err = capsys.readouterr().err
    assert "bad.yaml" in err and "retrieval_k" in err and "Traceback" not in err
