"""``topodrake map export``: the map as networkx's GraphML, read back with
networkx and checked against the map file's own arrays."""

import json
import math
from collections import Counter

import networkx as nx
import numpy as np
import pytest

from cli_run import one_line, run
from topodrake.topomap.graph import EDGE_KINDS
from topodrake.topomap.mapfile import read_map_arrays


@pytest.fixture
def oracle_map(small_map):
    """A small oracle map of test-0 (the drives between places 4 and 9)."""
    return small_map("oracle")


def test_export_graphml_reads_back_with_the_maps_counts_and_p(capsys, tmp_path, oracle_map):
    out = tmp_path / "t0.graphml"
    code, stdout, err = run(capsys, "map", "export", oracle_map, "--format", "graphml",
                            "--out", out, "--json")
    assert code == 0, err
    summary = json.loads(stdout)
    _, z = read_map_arrays(oracle_map)
    n_v, n_e = len(z["vertex_id"]), len(z["edge_src"])
    assert n_v > 2 and n_e > 2
    assert summary["vertices"] == n_v and summary["edges"] == n_e

    g = nx.read_graphml(out, node_type=int)
    assert g.is_directed()
    assert g.number_of_nodes() == n_v and g.number_of_edges() == n_e
    assert set(g.nodes) == {int(v) for v in z["vertex_id"]}
    for u, v, p, kind in zip(z["edge_src"], z["edge_dst"], z["edge_p"], z["edge_kind"]):
        d = g.edges[int(u), int(v)]
        assert abs(d["p"] - p) <= 1e-6
        assert abs(d["neg_log_p"] + math.log(p)) <= 1e-6
        assert d["kind"] == EDGE_KINDS[int(kind)]
    # every edge kind the map holds, counted as the map counts them
    have = Counter(d["kind"] for _, _, d in g.edges(data=True))
    want = Counter(EDGE_KINDS[int(k)] for k in z["edge_kind"])
    assert have == want and {f"{k}_edges" for k in EDGE_KINDS} <= set(summary)
    assert g.graph["world"] == "test-0" and g.graph["vertices"] == n_v
    # vertex poses: where each vertex's centre frame was taken
    poses = z["poses"][z["vertex_center"]]
    for v, pose in zip(z["vertex_id"], poses):
        node = g.nodes[int(v)]
        if np.all(np.isfinite(pose)):
            assert [node["x"], node["y"], node["yaw"]] == pytest.approx(pose, abs=1e-9)
        else:
            assert "x" not in node


def test_export_refuses_an_existing_file_without_force(capsys, tmp_path, oracle_map):
    out = tmp_path / "m.graphml"
    assert run(capsys, "map", "export", oracle_map, "--out", out)[0] == 0
    out.write_text(out.read_text().replace("test-0", "test-9"))     # someone's edited export
    before = out.read_bytes()
    code, _, err = run(capsys, "map", "export", oracle_map, "--out", out)
    one_line(code, err, str(out), "exists", "--force")
    assert out.read_bytes() == before
    code, _, err = run(capsys, "map", "export", oracle_map, "--out", out, "--force")
    assert code == 0, err
    assert nx.read_graphml(out).graph["world"] == "test-0"


def test_export_refuses_another_kind_of_file_and_format(capsys, tmp_path, oracle_map):
    code, _, err = run(capsys, "map", "export", oracle_map, "--out", tmp_path / "m.xml")
    one_line(code, err, "m.xml", ".graphml")
    with pytest.raises(SystemExit) as e:
        run(capsys, "map", "export", oracle_map, "--format", "mcap", "--out", tmp_path / "m.mcap")
    err = capsys.readouterr().err
    assert e.value.code == 2 and len(err.strip().splitlines()) == 1 and "graphml" in err
    assert not (tmp_path / "m.mcap").exists()


def test_export_of_a_missing_map_is_one_line(capsys, tmp_path):
    out = tmp_path / "m.graphml"
    code, _, err = run(capsys, "map", "export", tmp_path / "none.tdmap", "--out", out)
    one_line(code, err, "none.tdmap")
    assert not out.exists()


def test_export_help_names_the_formats(capsys):
    with pytest.raises(SystemExit):
        run(capsys, "map", "export", "--help")
    out = capsys.readouterr().out
    assert "formats accepted: graphml" in " ".join(out.split())
