"""Distillation of a small head (issue 17) from a tiny untrained teacher: views, labels, a few
steps that reduce the loss, determinism, and the agreement report."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import trimesh

from litege_core.errors import InputError
from litege_core.learned import Predictor
from litege_core.train.config import AugmentConfig
from litege_core.train.distill import (
    DISTILL_SEED_OFFSET,
    DistillConfig,
    agreement_inputs,
    distill_small_head,
    label_view,
    measure_agreement,
    mesh_view,
    view_shape,
)

TINY = {
    "features": 16,
    "hidden": 8,
    "steps": 60,
    "batch_pairs": 256,
    "views_per_batch": 2,
    "pool_views": 3,
    "pairs_per_view": 1024,
    "refresh_every": 25,
    "warmup_steps": 5,
    "lr": 1e-2,
    "log_every": 10,
}


def test_views_are_meshes_and_augmented_clouds(toy_predictor) -> None:
    config = DistillConfig(**TINY, mesh_fraction=0.5)
    kinds = set()
    for index in range(6):
        rng = np.random.default_rng([0, index, 0])
        shape, kind, frame = view_shape(
            "quadruped", "dog", DISTILL_SEED_OFFSET + index, rng, config
        )
        assert frame is None  # no jitter or axis turns in the default augment settings
        kinds.add(kind)
        assert shape.is_mesh == (kind == "mesh")
        if kind == "cloud":
            assert 300 * 0.85 <= shape.n_points <= 8000
    assert kinds == {"mesh", "cloud"}
    view = label_view(toy_predictor, shape, 0, kind, config, seed=0)
    assert view.embeddings.shape == (shape.n_points, 32)
    assert view.src.shape == view.dst.shape == view.target.shape == (1024,)
    assert (view.src != view.dst).all() and (view.target >= 0).all()
    near = np.linalg.norm(
        shape.vertices[view.src[:256].numpy()] - shape.vertices[view.dst[:256].numpy()], axis=1
    )
    uniform = np.linalg.norm(
        shape.vertices[view.src[512:].numpy()] - shape.vertices[view.dst[512:].numpy()], axis=1
    )
    assert np.median(near) < 0.3 * np.median(uniform)  # the first quarter are near pairs


def test_views_turned_as_in_training_are_labelled_in_the_turned_frame(toy_predictor) -> None:
    turning = AugmentConfig(axis_turn_probability=1.0)
    config = DistillConfig(**TINY, mesh_fraction=0.0, augment=turning)
    rng = np.random.default_rng([0, 0, 0])
    shape, kind, frame = view_shape("quadruped", "dog", DISTILL_SEED_OFFSET, rng, config)
    assert kind == "cloud" and frame is not None
    turned = label_view(toy_predictor, shape, 0, kind, config, seed=0, frame=frame)
    plain = label_view(toy_predictor, shape, 0, kind, config, seed=0)
    state = toy_predictor.register_turned(shape, frame[None])[0]
    with torch.no_grad():
        expected = toy_predictor.folded.embed(state.canonical_vertices, state.shape_bias)
    torch.testing.assert_close(turned.embeddings, expected.cpu())
    assert torch.equal(turned.src, plain.src)  # the same pairs, labelled in another frame
    assert not torch.allclose(turned.target, plain.target)


def test_a_few_steps_reduce_the_loss_deterministically(toy_predictor) -> None:
    config = DistillConfig(**TINY)
    first = distill_small_head(toy_predictor, config, category="quadruped")
    assert first.steps == 60 and first.stopped_by == "steps" and first.views == 5
    losses = [loss for _, _, loss in first.history]
    assert len(losses) == 6 and losses[-1] < 0.5 * losses[0]
    again = distill_small_head(toy_predictor, config, category="quadruped")
    # the same draws; only the matrix kernels' rounding (memory alignment) may differ
    np.testing.assert_allclose([h[2] for h in again.history], losses, rtol=1e-3, atol=1e-5)
    for a, b in zip(first.head.parameters(), again.head.parameters(), strict=True):
        torch.testing.assert_close(a, b, rtol=1e-2, atol=1e-3)
    assert first.settings["view_seeds"] == [DISTILL_SEED_OFFSET, DISTILL_SEED_OFFSET + 4]
    student = Predictor(toy_predictor.bundle, head=first.head)
    inputs = {k: v[:1] for k, v in agreement_inputs("quadruped", 1).items()}
    report = measure_agreement(toy_predictor, student, inputs, sources=4)
    assert set(report) == {"mesh", "cloud_2000", "cloud_300"}
    assert all(np.isfinite(r["mean"]) and r["mean"] >= 0 for r in report.values())


def test_bad_settings_are_input_errors(toy_predictor) -> None:
    with pytest.raises(InputError):
        DistillConfig(features=0)
    with pytest.raises(InputError):
        DistillConfig(views_per_batch=10, pool_views=4)
    with pytest.raises(InputError, match="no procedural category"):
        distill_small_head(toy_predictor, DistillConfig(**TINY))  # a "toy" bundle


def test_extra_meshes_make_a_share_of_the_views(toy_predictor) -> None:
    sphere = trimesh.creation.icosphere(subdivisions=2)
    extra = [(np.asarray(sphere.vertices) * [2.0, 1.0, 0.6], np.asarray(sphere.faces))]
    config = DistillConfig(**{**TINY, "steps": 6}, extra_fraction=0.5)
    result = distill_small_head(toy_predictor, config, category="quadruped", extra_meshes=extra)
    assert result.settings["extra_meshes"] == 1
    assert 0 < result.settings["extra_views"] < result.views  # about half of the 3 + 0 views
    shape, kind, _ = mesh_view(*extra[0], np.random.default_rng(0), config)
    assert kind in ("mesh", "cloud") and shape.n_points > 0
    with pytest.raises(InputError, match="extra meshes"):
        distill_small_head(toy_predictor, config, category="quadruped")
    with pytest.raises(InputError):
        DistillConfig(extra_fraction=1.5)
