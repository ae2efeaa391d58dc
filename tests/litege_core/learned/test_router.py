"""The category router: its input, its files, and its decisions."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
import trimesh

from litege_core.errors import ArtifactError, InputError
from litege_core.learned.router import (
    ROUTER_CONFIG,
    ROUTER_POINTS,
    ROUTER_WEIGHTS,
    CategoryRouter,
    RouterNet,
    first_of_each_category,
    load_router,
    router_points,
)
from litege_core.shape import Shape
from litege_core.variants import random_rotation

ELLIPSOID = trimesh.creation.icosphere(subdivisions=3)


def _cloud(seed: int, n: int = 1500) -> np.ndarray:
    rng = np.random.default_rng(seed)
    x = rng.normal(size=(n, 3))
    return x / np.linalg.norm(x, axis=1, keepdims=True) * [3.0, 1.5, 0.7]


def _router(min_probability: float = 0.9, bias: tuple[float, float] = (0.0, 0.0)):
    """A router whose decision is set by the last layer's bias (weights zeroed)."""
    net = RouterNet(2)
    with torch.no_grad():
        net.classifier[-1].weight.zero_()
        net.classifier[-1].bias.copy_(torch.tensor(bias))
    return CategoryRouter(net, ("quadruped", "biped"), min_probability)


def test_router_points_are_the_canonical_frame_and_deterministic():
    cloud = _cloud(0)
    first = router_points(cloud, seed=3)
    assert first.shape == (ROUTER_POINTS, 3) and first.dtype == np.float32
    np.testing.assert_array_equal(first, router_points(cloud, seed=3))
    moved = 2.5 * cloud @ random_rotation(1).T + [4.0, -1.0, 2.0]
    np.testing.assert_allclose(router_points(moved, seed=3), first, atol=1e-5)
    assert not np.allclose(router_points(cloud, seed=4), first)
    few = router_points(cloud[:100], seed=0)  # fewer points than the input size: repeats
    assert few.shape == (ROUTER_POINTS, 3)


def test_router_net_maps_clouds_to_logits():
    net = RouterNet(3)
    logits = net(torch.zeros(5, ROUTER_POINTS, 3))
    assert logits.shape == (5, 3)
    with pytest.raises(InputError):
        RouterNet(1)
    with pytest.raises(InputError):
        CategoryRouter(net, ("a", "b"))  # 2 categories, 3 classes


def test_route_decides_only_when_confident_and_available():
    shapes = [Shape.from_arrays(_cloud(1)), Shape.from_arrays(ELLIPSOID.vertices, ELLIPSOID.faces)]
    models = {"quadruped": "q", "biped": "h"}
    sure = _router(bias=(0.0, 5.0))  # p(biped) = 0.993
    np.testing.assert_allclose(sure.probabilities(shapes)[:, 1], 1 / (1 + np.exp(-5.0)))
    assert sure.route(shapes, models) == ["h", "h"]
    assert sure.route(shapes, {"quadruped": "q"}) == [None, None]  # no model of its category
    unsure = _router(bias=(0.0, 1.0))  # p = 0.73 < 0.9
    assert unsure.route(shapes, models) == [None, None]
    assert sure.route([], models) == []


def test_save_load_round_trip_and_tampering(tmp_path):
    router = _router(0.8, (1.0, -1.0))
    with torch.no_grad():
        router.net.point_mlp[0].weight.normal_()
    router.save(tmp_path)
    loaded = load_router(tmp_path)
    assert loaded is not None
    assert loaded.categories == router.categories
    assert loaded.min_probability == 0.8
    shapes = [Shape.from_arrays(_cloud(2))]
    np.testing.assert_allclose(loaded.probabilities(shapes), router.probabilities(shapes))
    config = json.loads((tmp_path / ROUTER_CONFIG).read_text())
    config["categories"] = ["only one"]
    (tmp_path / ROUTER_CONFIG).write_text(json.dumps(config))
    with pytest.raises(ArtifactError):
        load_router(tmp_path)
    router.save(tmp_path)
    (tmp_path / ROUTER_WEIGHTS).write_bytes(b"not safetensors")
    with pytest.raises(ArtifactError):
        load_router(tmp_path)


def test_first_model_of_each_category():
    loaded = {"quadrupeds": "quadruped", "dogs": "quadruped", "humans": "biped"}
    assert first_of_each_category(loaded) == {"quadruped": "quadrupeds", "biped": "humans"}
