"""Integrity: a damaged checkpoint or map is refused in one line naming the
file and "damaged", never loaded; a hand-edited map that does not hold
together is refused in one line; the shipped cards record their files'
SHA-256."""

import io
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch

from cli_run import one_line, run
from topodrake.errors import TopodrakeError
from topodrake.fileio import file_sha256
from topodrake.learning.checkpoint import load_checkpoint, save_checkpoint
from topodrake.topomap.mapfile import CHECKSUM, payload_sha256

ROOT = Path(__file__).resolve().parents[1]
SHIPPED = ROOT / "checkpoints"
REACH = SHIPPED / "reach_lidar_k5" / "checkpoint.pt"     # the RE of the lidar C_WP below
CWP = SHIPPED / "lidar_k5" / "checkpoint.pt"
DEMO_MAP = SHIPPED / "demo_map" / "map.tdmap"
POSE = ["--start", "16.42,14.88,2.95", "--goal", "8.22,14.08,-0.2"]


def flipped(data: bytes, n: int = 200, seed: int = 0) -> bytes:
    """``data`` with ``n`` bytes in its middle third inverted."""
    out = bytearray(data)
    third = len(out) // 3
    for i in np.random.default_rng(seed).choice(np.arange(third, 2 * third), n, replace=False):
        out[i] ^= 0xFF
    return bytes(out)


def copy_of(src: Path, folder: Path, *, damage: bool, card: bool) -> Path:
    """``src`` (and its card) copied into ``folder``, 200 bytes flipped if ``damage``."""
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / src.name
    path.write_bytes(flipped(src.read_bytes()) if damage else src.read_bytes())
    if card:
        shutil.copy(src.parent / "card.json", folder / "card.json")
    return path


# ---------------------------------------------------------------- checkpoints

@pytest.mark.parametrize("card", [True, False], ids=["with its card", "alone"])
def test_integrity_a_damaged_checkpoint_is_refused_by_the_loader(tmp_path, card):
    bad = copy_of(REACH, tmp_path / "bad", damage=True, card=card)
    with pytest.raises(TopodrakeError) as e:
        load_checkpoint(bad)
    message = str(e.value)
    assert "damaged" in message and str(bad) in message and "\n" not in message
    good = copy_of(REACH, tmp_path / "good", damage=False, card=card)
    loaded, shipped = load_checkpoint(good), load_checkpoint(REACH)
    for (name, a), (_, b) in zip(loaded.model.state_dict().items(),
                                 shipped.model.state_dict().items()):
        assert torch.equal(a, b), name


@pytest.mark.parametrize("option", ["--reach", "--controller"])
def test_integrity_navigate_refuses_a_damaged_checkpoint(capsys, tmp_path, option):
    bad = copy_of(REACH if option == "--reach" else CWP, tmp_path, damage=True, card=False)
    given = ["--reach", bad, "--controller", CWP] if option == "--reach" else \
        ["--controller", bad, "--reach", REACH]
    code, out, err = run(capsys, "navigate", "test-0", *POSE, *given, "--t-max", "2")
    one_line(code, err, str(bad), "damaged")
    assert out == ""


def test_integrity_demo_refuses_a_damaged_controller(capsys, tmp_path):
    bad = copy_of(CWP, tmp_path / "ck", damage=True, card=False)
    code, _, err = run(capsys, "demo", "--controller", bad, "--out", tmp_path / "demo")
    one_line(code, err, str(bad), "damaged")
    assert not (tmp_path / "demo" / "plan.png").exists()


@pytest.mark.parametrize("option", ["--reach", "--controller"])
def test_integrity_map_build_refuses_a_damaged_checkpoint(capsys, tmp_path, option):
    bad = copy_of(REACH if option == "--reach" else CWP, tmp_path / "ck", damage=True,
                  card=True)
    given = ["--reach", bad] if option == "--reach" else ["--reach", REACH, "--controller", bad]
    out = tmp_path / "m.tdmap"
    code, _, err = run(capsys, "map", "build", "test-0", "--modality", "lidar", *given,
                       "--places", "4,9", "--out", out, "--quiet")
    one_line(code, err, str(bad), "damaged")
    assert not out.exists()


def test_integrity_a_checkpoint_carries_the_checksum_of_its_payload(tmp_path):
    """A checkpoint written now holds the SHA-256 of its payload: weights
    changed and saved again by torch (every archive CRC-32 right) are refused."""
    shipped = load_checkpoint(REACH)
    path = save_checkpoint(tmp_path / "checkpoint.pt", shipped.model, shipped.sensor,
                           revision="test", extra=shipped.meta.get("extra"))
    load_checkpoint(path)
    blob = torch.load(path, weights_only=True)
    assert len(blob["payload_sha256"]) == 64
    name = next(iter(blob["model"]))
    blob["model"][name] = blob["model"][name] + 1e-3
    buf = io.BytesIO()
    torch.save(blob, buf)
    path.write_bytes(buf.getvalue())
    with pytest.raises(TopodrakeError, match="damaged") as e:
        load_checkpoint(path)
    assert str(path) in str(e.value)


def test_integrity_place_embeddings_are_checked_too(tmp_path):
    from topodrake.topomap.embedding import PlaceEmbedding, save_place_checkpoint

    src = SHIPPED / "place_lidar" / "checkpoint.pt"
    with pytest.raises(TopodrakeError, match="damaged"):
        PlaceEmbedding.from_checkpoint(copy_of(src, tmp_path / "a", damage=True, card=False))
    shipped = PlaceEmbedding.from_checkpoint(src)
    path = save_place_checkpoint(tmp_path / "b" / "checkpoint.pt", shipped.model, shipped.sensor)
    blob = torch.load(path, weights_only=True)
    blob["sensor"]["range_m"] = 1.0
    buf = io.BytesIO()
    torch.save(blob, buf)
    path.write_bytes(buf.getvalue())
    with pytest.raises(TopodrakeError, match="damaged"):
        PlaceEmbedding.from_checkpoint(path)


def test_integrity_shipped_cards_carry_the_sha256_of_their_files():
    folders = sorted(p for p in SHIPPED.iterdir() if p.is_dir())
    assert len(folders) >= 24
    for folder in folders:
        card = json.loads((folder / "card.json").read_text())
        name = Path(card.get("checkpoint") or card["file"]).name
        assert card.get("sha256") == file_sha256(folder / name), folder.name


def test_integrity_writing_a_checkpoint_drops_the_checksum_its_card_held(tmp_path):
    """The card no longer describes the new bytes: its sha256 goes (the
    trainer writes the card anew with the new one), and the file loads."""
    folder = tmp_path / "run"
    path = copy_of(REACH, folder, damage=False, card=True)
    assert "sha256" in json.loads((folder / "card.json").read_text())
    ck = load_checkpoint(path)
    save_checkpoint(path, ck.model, ck.sensor, revision="test", extra=ck.meta.get("extra"))
    assert "sha256" not in json.loads((folder / "card.json").read_text())
    load_checkpoint(path)


# ---------------------------------------------------------------- maps

def map_arrays(path) -> dict:
    with np.load(path) as z:
        return {name: z[name] for name in z.files}


def write_map(arrays: dict, path: Path, *, version: int | None = None, reseal: bool = True) -> Path:
    """A map file of ``arrays`` (meta's version set to ``version``; version 5
    files resealed with a checksum of their new payload unless not ``reseal``)."""
    arrays = dict(arrays)
    meta = json.loads(bytes(arrays["meta"]).decode())
    if version is not None:
        meta["version"] = version
        arrays["meta"] = np.frombuffer(json.dumps(meta).encode(), np.uint8)
    arrays.pop(CHECKSUM, None)
    if meta["version"] >= 5:
        arrays[CHECKSUM] = np.array(payload_sha256(arrays) if reseal else "0" * 64)
    with open(path, "wb") as f:
        np.savez_compressed(f, **arrays)
    return path


def test_integrity_maps_carry_the_checksum_of_their_payload(small_map):
    path = small_map("oracle")
    arrays = map_arrays(path)
    meta = json.loads(bytes(arrays["meta"]).decode())
    assert meta["version"] == 5 and str(arrays[CHECKSUM]) == payload_sha256(arrays)


def test_integrity_a_damaged_map_is_refused(capsys, tmp_path, small_map):
    from topodrake.topomap.mapfile import load_map
    from topodrake.topomap.sources import make_scorer

    src = small_map("oracle")
    bad = tmp_path / "bad.tdmap"
    bad.write_bytes(flipped(src.read_bytes()))
    code, _, err = run(capsys, "map", "info", bad)
    one_line(code, err, str(bad), "damaged")
    # a payload changed and written again whole (every CRC-32 right): its checksum tells
    arrays = map_arrays(src)
    arrays["edge_p"] = np.clip(arrays["edge_p"] * 0.5, 0, 1)
    edited = write_map(arrays, tmp_path / "edited.tdmap", reseal=False)
    for argv in (["map", "info", edited], ["map", "plot", edited, "--out", tmp_path / "p.png"]):
        code, _, err = run(capsys, *argv)
        one_line(code, err, str(edited), "damaged")
    from topodrake.world import load_world

    with pytest.raises(TopodrakeError, match="damaged"):
        load_map(edited, make_scorer("oracle", load_world("test-0")))


def test_integrity_the_demo_map_is_checked_against_its_card(capsys, tmp_path):
    """The shipped map (version 4, no checksum inside) is checked by the
    SHA-256 its card records; copied alone it is checked for consistency."""
    folder = tmp_path / "demo_map"
    bad = copy_of(DEMO_MAP, folder, damage=False, card=True)
    assert run(capsys, "map", "info", bad, "--json")[0] == 0
    arrays = map_arrays(DEMO_MAP)
    arrays["edge_p"] = arrays["edge_p"] * 0.99         # consistent, but not the shipped bytes
    write_map(arrays, bad)
    code, _, err = run(capsys, "map", "info", bad)
    one_line(code, err, str(bad), "damaged", "card.json")


def _unequal_edges(a):
    a["edge_p"] = a["edge_p"][:-1]
    return "edge_p has"


def _vertex_id(a):
    a["vertex_id"] = a["vertex_id"].copy()
    a["vertex_id"][0] = 100000
    return "vertex"


def _edge_p(value):
    def edit(a):
        a["edge_p"] = a["edge_p"].copy()
        a["edge_p"][3] = value
        return f"probability {value}"
    return edit


def _pose(a):
    a["poses"] = a["poses"].copy()
    a["poses"][5, 1] = np.inf
    return "pose"


def _edge_to_nowhere(a):
    a["edge_dst"] = a["edge_dst"].copy()
    a["edge_dst"][2] = 100000
    return "vertex 100000"


EDITS = {"edge arrays of unequal length": _unequal_edges, "a vertex id 100000": _vertex_id,
         "an edge p NaN": _edge_p(np.nan), "an edge p 7.0": _edge_p(7.0),
         "an edge p -0.5": _edge_p(-0.5), "an infinite pose": _pose,
         "an edge to vertex 100000": _edge_to_nowhere}


@pytest.mark.parametrize("version", [4, 5])
@pytest.mark.parametrize("edit", list(EDITS), ids=list(EDITS))
def test_integrity_a_hand_edited_map_is_refused_in_one_line(capsys, tmp_path, edit, version):
    """Each defect, in a version 4 file (no checksum) and in a version 5 file
    resealed by hand: ``map info`` and ``map plot`` refuse it in one line
    (exit 2, no traceback); nothing is planned on it."""
    arrays = map_arrays(DEMO_MAP)                   # version 4, its card not copied
    words = EDITS[edit](arrays)
    path = write_map(arrays, tmp_path / "edited.tdmap", version=version)
    code, _, err = run(capsys, "map", "info", path)
    one_line(code, err, str(path), "inconsistent map file", words)
    code, _, err = run(capsys, "map", "plot", path, "--out", tmp_path / "p.png")
    one_line(code, err, str(path), words)
    assert not (tmp_path / "p.png").exists()
    code, out, err = run(capsys, "map", "plan", path, *POSE)
    one_line(code, err, str(path), words)
    assert out == ""


def test_integrity_an_intact_version_4_map_loads_as_before(tmp_path):
    """The shipped version 4 map, copied without its card, passes the checks."""
    from topodrake.topomap.mapfile import read_map_arrays

    copy = write_map(map_arrays(DEMO_MAP), tmp_path / "v4.tdmap")
    meta, arrays = read_map_arrays(copy)
    assert meta["version"] == 4 and len(arrays["vertex_id"]) == 991
