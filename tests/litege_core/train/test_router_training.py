"""Router training: views, frame perturbations, and a toy problem it must learn."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from litege_core.errors import InputError
from litege_core.learned.router import ROUTER_POINTS
from litege_core.train.router import (
    RouterTrainConfig,
    perturbed_frame,
    train_router,
    view_points,
)

SPHERE = trimesh.creation.icosphere(subdivisions=2)


def _mesh(scale) -> tuple[np.ndarray, np.ndarray]:
    return np.asarray(SPHERE.vertices) * scale, np.asarray(SPHERE.faces)


def test_views_respect_the_point_range_and_cuts():
    config = RouterTrainConfig(min_points=50, max_points=400, cut_probability=1.0)
    rng = np.random.default_rng(0)
    counts = [view_points(_mesh([2.0, 1.0, 0.5]), config, rng).shape[0] for _ in range(40)]
    assert min(counts) >= 50 and max(counts) <= 400  # a cut never leaves fewer than min
    framed = perturbed_frame(view_points(_mesh([2.0, 1.0, 0.5]), config, rng), config, rng)
    assert framed.shape == (ROUTER_POINTS, 3) and framed.dtype == np.float32


def test_a_toy_problem_is_learned():
    # long thin ellipsoids against round ones, under every augmentation: separable by shape
    rng = np.random.default_rng(1)
    long = [_mesh([rng.uniform(2.5, 3.5), 1.0, rng.uniform(0.4, 0.6)]) for _ in range(6)]
    round_ = [_mesh([rng.uniform(0.9, 1.1), 1.0, rng.uniform(0.9, 1.1)]) for _ in range(6)]
    data = [(m, 0) for m in long] + [(m, 1) for m in round_]
    config = RouterTrainConfig(
        steps=120,
        minutes=2.0,
        batch_size=16,
        lr=3e-3,
        min_points=100,
        max_points=600,
        val_views=2,
        val_every=40,
    )
    result = train_router(data[::2] + data[1::2], data, 2, config)
    assert result.best_val_accuracy >= 0.9
    assert result.history and result.best_step in [step for step, _, _ in result.history]


def test_labels_must_cover_every_category():
    with pytest.raises(InputError):
        train_router([(_mesh(1.0), 0)], [], 2, RouterTrainConfig())
    with pytest.raises(InputError):
        RouterTrainConfig(min_points=500, max_points=100)
