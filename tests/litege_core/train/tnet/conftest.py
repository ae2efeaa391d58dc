"""Toy shapes and a tiny config shared by the T-Net training tests."""

from pathlib import Path

import numpy as np
import pytest
import trimesh

from litege_core.train.tnet import TNetTrainConfig, canonical_shape_set

REPO = Path(__file__).resolve().parents[4]


def _toy_mesh(seed: int) -> tuple[np.ndarray, np.ndarray]:
    """An asymmetric blob: a stretched, bent icosphere (no rotational symmetry)."""
    sphere = trimesh.creation.icosphere(subdivisions=1)
    v = np.asarray(sphere.vertices) * [2.0, 1.0, 0.5]
    rng = np.random.default_rng(seed)
    v[:, 1] += 0.3 * v[:, 0] ** 2 + 0.2 * np.clip(v[:, 0], 0, None) * rng.uniform(0.8, 1.2)
    return v * rng.uniform(0.5, 2.0), np.asarray(sphere.faces)


@pytest.fixture(scope="module")
def toy_shapes():
    train = canonical_shape_set([_toy_mesh(s) for s in range(4)])
    val = canonical_shape_set([_toy_mesh(100 + s) for s in range(2)])
    return train, val


TINY = {
    "data": {"n_train": 4, "n_val": 2},
    "augment": {"min_points": 32, "max_points": 64},
    "network": {"conv_widths": [8, 16], "fc_widths": [8]},
    "train": {"batch_size": 4, "steps": 6, "val_every": 3, "val_points": 48, "log_every": 2},
    "report": {"samples": 64},
}


def tiny_config(tmp_path: Path, **overrides) -> TNetTrainConfig:
    config = TNetTrainConfig.from_dict({**TINY, "output": {"dir": str(tmp_path / "run")}})
    return config.replace(**overrides) if overrides else config
