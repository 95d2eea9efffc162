"""``topodrake map export``: the map as networkx's GraphML, read back with
networkx, and as a ROS 2 bag in MCAP, read back with the MCAP reader; both
checked against the map file's own arrays."""

import json
import math
from collections import Counter

import networkx as nx
import numpy as np
import pytest

from cli_run import one_line, run
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
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
    code, _, err = run(capsys, "map", "export", oracle_map, "--format", "graphml",
                       "--out", tmp_path / "m.mcap")
    one_line(code, err, "m.mcap", ".graphml")
    code, _, err = run(capsys, "map", "export", oracle_map, "--format", "mcap",
                       "--out", tmp_path / "m.graphml")
    one_line(code, err, "m.graphml", ".mcap")
    with pytest.raises(SystemExit) as e:
        run(capsys, "map", "export", oracle_map, "--format", "bag", "--out", tmp_path / "m.mcap")
    err = capsys.readouterr().err
    assert e.value.code == 2 and len(err.strip().splitlines()) == 1 and "mcap" in err
    assert not (tmp_path / "m.mcap").exists() and not (tmp_path / "m.graphml").exists()


def test_export_of_a_missing_map_is_one_line(capsys, tmp_path):
    out = tmp_path / "m.graphml"
    code, _, err = run(capsys, "map", "export", tmp_path / "none.tdmap", "--out", out)
    one_line(code, err, "none.tdmap")
    assert not out.exists()


def test_export_help_names_the_formats(capsys):
    with pytest.raises(SystemExit):
        run(capsys, "map", "export", "--help")
    out = capsys.readouterr().out
    assert "formats accepted: graphml, mcap" in " ".join(out.split())


def _messages(path):
    with open(path, "rb") as f:
        msgs = list(make_reader(f, decoder_factories=[DecoderFactory()]).iter_decoded_messages())
    assert [channel.topic for _, channel, _, _ in msgs] == ["/topodrake/map",
                                                            "/topodrake/map/table"]
    assert all(channel.message_encoding == "cdr" for _, channel, _, _ in msgs)
    return msgs


def _markers(path):
    schema, _, _, array = _messages(path)[0]
    assert schema.name == "visualization_msgs/msg/MarkerArray"
    return array.markers


def _table(path):
    schema, _, _, text = _messages(path)[1]
    assert schema.name == "std_msgs/msg/String"
    return json.loads(text.data)


def test_export_mcap_reads_back_with_the_maps_counts(capsys, tmp_path, oracle_map):
    out = tmp_path / "t0.mcap"
    code, stdout, err = run(capsys, "map", "export", oracle_map, "--format", "mcap",
                            "--out", out, "--json")
    assert code == 0, err
    assert json.loads(stdout)["format"] == "mcap"
    assert out.read_bytes().startswith(b"\x89MCAP0\r\n")
    _, z = read_map_arrays(oracle_map)
    poses = z["poses"][z["vertex_center"]]
    known = np.all(np.isfinite(poses[:, :2]), axis=1)
    assert known.sum() > 2
    markers = _markers(out)
    vertices = [m for m in markers if m.ns == "vertices"]
    assert len(vertices) == 1 and vertices[0].type == 7 and vertices[0].header.frame_id == "map"
    got = np.array([[p.x, p.y] for p in vertices[0].points])
    assert len(got) == known.sum()
    assert np.allclose(np.sort(got, axis=0), np.sort(poses[known, :2], axis=0), atol=1e-9)
    # one line list per edge kind, two points per edge between known poses
    ids = {int(v): k for v, k in zip(z["vertex_id"], known)}
    want = Counter(EDGE_KINDS[int(k)] for u, v, k in zip(z["edge_src"], z["edge_dst"],
                                                         z["edge_kind"])
                   if ids[int(u)] and ids[int(v)])
    lines = {m.ns: m for m in markers if m.ns.startswith("edges/")}
    assert set(lines) == {f"edges/{k}" for k in EDGE_KINDS}
    assert all(m.type == 5 for m in lines.values())
    assert {k: len(lines[f"edges/{k}"].points) // 2 for k in EDGE_KINDS} == \
        {k: want.get(k, 0) for k in EDGE_KINDS}
    assert sum(want.values()) == len(z["edge_src"])     # the small map's poses are all known
    # the table: every vertex and edge, with p to 1e-6
    table = _table(out)
    assert sorted(table["vertices"]) == sorted(int(v) for v in z["vertex_id"])
    got_p = {(u, v, k): p for u, v, k, p in table["edges"]}
    assert len(got_p) == len(table["edges"]) == len(z["edge_src"])
    for u, v, k, p in zip(z["edge_src"], z["edge_dst"], z["edge_kind"], z["edge_p"]):
        assert got_p[(int(u), int(v), EDGE_KINDS[int(k)])] == pytest.approx(float(p), abs=1e-6)


def test_export_mcap_format_from_the_ending_and_refused_without_force(capsys, tmp_path,
                                                                      oracle_map):
    out = tmp_path / "m.mcap"
    assert run(capsys, "map", "export", oracle_map, "--out", out)[0] == 0
    before = out.read_bytes()
    assert before.startswith(b"\x89MCAP0\r\n")
    code, _, err = run(capsys, "map", "export", oracle_map, "--out", out)
    one_line(code, err, str(out), "exists", "--force")
    other = tmp_path / "o.mcap"
    other.write_text("not a bag")
    code, _, err = run(capsys, "map", "export", oracle_map, "--out", other)
    one_line(code, err, "o.mcap", "--force")
    assert other.read_text() == "not a bag"
    assert run(capsys, "map", "export", oracle_map, "--out", out, "--force")[0] == 0
    assert len(_markers(out)) == 1 + len(EDGE_KINDS)
