"""Helpers shared by the learned-model tests."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np
import pytest

from litege_core.canonical import canonicalize_bbox
from litege_core.descriptor import VoxelGrid, fit_basis
from litege_core.descriptor.basis import UdfPcaBasis
from litege_core.learned import shape_samples
from litege_core.learned.fusion_calibration import FusionCalibration
from litege_core.shape import Shape


def _fit_toy_basis(make_shape: Callable[[int], Shape], count: int = 12) -> UdfPcaBasis:
    """An 8-component UDF-PCA basis on a coarse 41³ grid, fitted on ``make_shape(0..count-1)``
    in their canonical (bbox) frames."""
    canonical = []
    for seed in range(count):
        shape = make_shape(seed)
        transform = canonicalize_bbox(shape_samples(shape, 2000, seed))
        canonical.append((transform.apply(shape.vertices), np.asarray(shape.faces)))
    return fit_basis(
        canonical,
        grid=VoxelGrid(resolution=41, pitch=0.06),
        std_threshold=0.1,
        n_components=8,
        n_udf_samples=1000,
        seed=0,
    )


@pytest.fixture(scope="session")
def fit_toy_basis() -> Callable[..., UdfPcaBasis]:
    """``fit_toy_basis(make_shape, count=12)`` → a small basis of those shapes."""
    return _fit_toy_basis


def toy_calibration(bundle_hash: str = "h" * 64, **changes) -> FusionCalibration:
    """A valid calibration for bundle ``bundle_hash`` with ``changes`` applied."""
    base = FusionCalibration(
        k=8,
        prune_ratio=1.6,
        bias_log10_points=(2.5, 3.0, 3.5),
        bias=(0.98, 1.01, 1.02),
        gate=(0.5, -1.0, -2.0, -10.0),
        mesh_bias=1.04,
        bundle_hash=bundle_hash,
        fitted_on={"shapes": {"toy": 3}},
    )
    return dataclasses.replace(base, **changes)


def scorer_state(width: int = 8, seed: int = 0) -> dict[str, np.ndarray]:
    """A random ``state_dict`` (numpy) of a shortcut scorer of ``width``: the layout of
    :class:`~litege_core.train.shortcuts.ShortcutScorer`, its layers' default init scale."""
    rng = np.random.default_rng(seed)
    shapes = {
        "point.0.weight": (width, 3), "point.0.bias": (width,),
        "point.2.weight": (2 * width, width), "point.2.bias": (2 * width,),
        "ends.weight": (2 * width, 2 * width), "edge.weight": (2 * width, 6),
        "edge.bias": (2 * width,), "head.1.weight": (width, 2 * width), "head.1.bias": (width,),
        "head.3.weight": (1, width), "head.3.bias": (1,),
    }  # fmt: skip
    fan_in = {key: shape[-1] if len(shape) == 2 else shapes[key.replace("bias", "weight")][-1]
              for key, shape in shapes.items()}  # fmt: skip
    return {
        key: (rng.uniform(-1, 1, shape) / np.sqrt(fan_in[key])).astype(np.float32)
        for key, shape in shapes.items()
    }
