"""Every shipped training config loads through the loader its train command uses."""

from pathlib import Path

import pytest

from topodrake.baselines.train_retrieval import load_retrieval_config
from topodrake.learning.config import load_train_config
from topodrake.learning.onpolicy.dagger import load_dagger_config
from topodrake.learning.reachability.train import load_reach_config
from topodrake.learning.waypoint.scale import load_scale_config
from topodrake.topomap.embedding_train import load_place_config

CONFIGS = Path(__file__).resolve().parents[1] / "configs"
LOADERS = {
    "dagger": load_dagger_config,
    "place": load_place_config,
    "reach": load_reach_config,
    "scale": load_scale_config,
    "sptm": load_retrieval_config,
    "waypoint": load_train_config,
}


def _loader(path: Path):
    return LOADERS[path.name.split("_", 1)[0]]


@pytest.mark.parametrize("path", sorted(CONFIGS.glob("*.yaml")), ids=lambda p: p.name)
def test_shipped_config_loads(path):
    assert path.name.split("_", 1)[0] in LOADERS, f"{path.name}: no loader for this prefix"
    assert _loader(path)(path) is not None
