"""The place embedding: unit norm, checkpoints, training on synthetic pairs, recall."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from topodrake.errors import TopodrakeError
from topodrake.sensing.config import CameraConfig, LidarConfig
from topodrake.topomap.embedding import (PlaceEmbedding, PlaceNet, PlaceNetConfig,
                                         ThumbnailEmbedding, save_place_checkpoint)
from topodrake.topomap.embedding_eval import recall_at, search_timing
from topodrake.topomap.embedding_train import (PlaceData, PlaceTrainConfig, place_loss,
                                               train_steps)

TINY = dict(channels=[4, 8, 8], hidden=16, dim=8)


def _images(n, seed=0):
    return np.random.default_rng(seed).integers(0, 256, (n, 64, 64, 3), dtype=np.uint8)


def _camera_model(seed=0):
    torch.manual_seed(seed)
    return PlaceNet(PlaceNetConfig(modality="camera", image_size=32, **TINY))


def test_embeddings_are_unit_norm_float32_and_batched():
    emb = PlaceEmbedding(_camera_model(), CameraConfig(), batch=3)
    e = emb.embed(_images(7))
    assert e.shape == (7, 8) and e.dtype == np.float32
    np.testing.assert_allclose(np.linalg.norm(e, axis=1), 1.0, atol=1e-5)
    np.testing.assert_allclose(e, PlaceEmbedding(emb.model, CameraConfig(), batch=100).embed(_images(7)),
                               atol=1e-6)
    lidar = LidarConfig()
    torch.manual_seed(0)
    le = PlaceEmbedding(PlaceNet(PlaceNetConfig(modality="lidar", **TINY)), lidar)
    ranges = np.random.default_rng(1).uniform(0.2, 12.0, (5, lidar.beams))
    ranges[0, :3] = np.inf
    out = le.embed(ranges)
    assert le.observation == "lidar" and le.dim == 8
    np.testing.assert_allclose(np.linalg.norm(out, axis=1), 1.0, atol=1e-5)
    for base in (ThumbnailEmbedding("camera"), ThumbnailEmbedding("lidar")):
        obs = _images(4) if base.observation == "camera" else ranges
        np.testing.assert_allclose(np.linalg.norm(base.embed(obs), axis=1), 1.0, atol=1e-5)


def test_embed_refuses_the_wrong_observation():
    emb = PlaceEmbedding(_camera_model(), CameraConfig())
    with pytest.raises(TopodrakeError, match="uint8 images"):
        emb.embed(np.zeros((2, 64), np.float32))


def test_checkpoint_round_trip_and_fingerprint(tmp_path):
    model = _camera_model()
    path = save_place_checkpoint(tmp_path / "p" / "checkpoint.pt", model, CameraConfig(),
                                 metrics={"x": 1})
    emb = PlaceEmbedding.from_checkpoint(path)
    imgs = _images(4)
    np.testing.assert_allclose(emb.embed(imgs), PlaceEmbedding(model, CameraConfig()).embed(imgs),
                               atol=1e-6)
    assert emb.name == "p" and len(emb.fingerprint()) == 40
    assert emb.fingerprint() == PlaceEmbedding.from_checkpoint(path).fingerprint()
    save_place_checkpoint(path, _camera_model(seed=1), CameraConfig())
    assert PlaceEmbedding.from_checkpoint(path).fingerprint() != emb.fingerprint()


def test_from_checkpoint_refuses_bad_files_with_one_line(tmp_path):
    corrupt = tmp_path / "corrupt.pt"
    corrupt.write_bytes(b"not a torch file")
    foreign = tmp_path / "foreign.pt"
    torch.save({"format": "topodrake-waypoint-net", "version": 1, "model": {}}, foreign)
    wrong = tmp_path / "wrong.pt"
    blob = {"format": "topodrake-place-embedding", "version": 1,
            "network": {"modality": "camera", "image_size": 32, **TINY},
            "sensor": {}, "model": {"head.0.weight": torch.zeros(3, 3)}}
    torch.save(blob, wrong)
    for path in (tmp_path / "missing.pt", corrupt, foreign, wrong):
        with pytest.raises(TopodrakeError) as err:
            PlaceEmbedding.from_checkpoint(path)
        msg = str(err.value)
        assert "\n" not in msg and str(path) in msg


def _synthetic(n_groups=8, per_group=6, seed=0):
    """Frames in groups (same base image plus noise): label 1 within a group, 0 across."""
    rng = np.random.default_rng(seed)
    base = rng.uniform(-0.5, 0.5, (n_groups, 3, 32, 32))
    x = base.repeat(per_group, 0) + 0.05 * rng.standard_normal((n_groups * per_group, 3, 32, 32))
    group = np.arange(n_groups).repeat(per_group)
    pairs = rng.integers(0, len(x), (400, 2))
    pairs[:200, 1] = pairs[:200, 0] // per_group * per_group + rng.integers(0, per_group, 200)
    labels = (group[pairs[:, 0]] == group[pairs[:, 1]]).astype(np.float32)
    return PlaceData(torch.tensor(x, dtype=torch.float16), np.zeros((len(x), 3)),
                     group % 2, pairs, labels)


def _mean_loss(model, data):
    with torch.no_grad():
        x = data.inputs.float()
        e = model(x)
        a, b = data.pairs[:, 0], data.pairs[:, 1]
        h = torch.from_numpy(data.house)
        return float(place_loss(e[a], e[b], torch.from_numpy(data.labels), h[a], h[b], 1.0)[0])


def test_training_on_synthetic_pairs_improves_and_is_deterministic():
    data = _synthetic()
    cfg = PlaceTrainConfig(network=PlaceNetConfig(modality="camera", image_size=32, **TINY),
                           batch_size=32, lr=3e-3, max_steps=60, max_minutes=5.0, seed=0)
    cfg.validate()
    before = _mean_loss(_camera_model(), data)
    runs = []
    for _ in range(2):
        model = _camera_model()
        steps, _, _ = train_steps(model, data, cfg)
        runs.append([p.detach().clone() for p in model.parameters()])
    assert steps == 60
    after = _mean_loss(model, data)
    assert after < 0.6 * before
    for p, q in zip(*runs):
        assert torch.equal(p, q)


def test_grouped_ranking_training_improves():
    data = _synthetic()
    g = 4
    rng = np.random.default_rng(2)
    anchors = rng.integers(0, len(data.inputs), 100).repeat(g)
    partners = rng.integers(0, len(data.inputs), 400)
    partners[::2] = anchors[::2] // 6 * 6 + rng.integers(0, 6, 200)     # half from the group
    group = np.arange(len(data.inputs)) // 6
    data.pairs = np.column_stack([anchors, partners])
    data.labels = (group[anchors] == group[partners]).astype(np.float32)
    cfg = PlaceTrainConfig(network=PlaceNetConfig(modality="camera", image_size=32, **TINY),
                           batch_size=32, lr=3e-3, max_steps=60, rank_weight=1.0, seed=0)
    cfg.data.group = g
    cfg.validate()
    before = _mean_loss(_camera_model(), data)
    model = _camera_model()
    train_steps(model, data, cfg)
    assert _mean_loss(model, data) < 0.6 * before
    with pytest.raises(TopodrakeError, match="group"):
        PlaceTrainConfig(rank_weight=1.0).validate()


def test_recall_at_counts_relevant_frames_in_the_top_k():
    scores = np.array([[0.9, 0.8, 0.1, 0.0], [0.1, 0.2, 0.3, 0.4], [0.5, 0.5, 0.5, 0.5]])
    relevant = np.array([[True, False, True, False], [False, False, False, True],
                         [False, False, False, False]])
    r = recall_at(scores, relevant, ks=(1, 2, 3))
    # query 0: top1 hit (1/1), top2 one of two (1/2), top3 both (2/2); query 1: always found
    assert r == {"1": 1.0, "2": 0.75, "3": 1.0}


def test_search_timing_reports_numpy_per_query_time():
    out = search_timing(n=2000, dim=16, k=8, queries=5)
    assert out["numpy_ms"] > 0


def test_sample_pairs_near_partners_are_near_and_groups_share_anchors():
    from topodrake.topomap.embedding_train import PlaceDataConfig, sample_pairs

    rng = np.random.default_rng(0)
    poses = np.column_stack([rng.uniform(0, 20, 500), rng.uniform(0, 20, 500),
                             rng.uniform(-np.pi, np.pi, 500)])
    thumbs = rng.standard_normal((500, 12))
    cfg = PlaceDataConfig(near_fraction=0.5, lookalike_fraction=0.25, group=4)
    pr = sample_pairs(poses, thumbs, 400, cfg, np.random.default_rng(1))
    assert pr.shape == (400, 2)
    assert np.all(pr[:, 0].reshape(-1, 4) == pr[::4, :1])
    near = pr.reshape(-1, 4, 2)[:, :2].reshape(-1, 2)
    d = np.hypot(*(poses[near[:, 0], :2] - poses[near[:, 1], :2]).T)
    assert np.mean(d < cfg.near_radius_m) > 0.9
    again = sample_pairs(poses, thumbs, 400, cfg, np.random.default_rng(1))
    np.testing.assert_array_equal(pr, again)
