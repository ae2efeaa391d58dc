"""T-Net training batches (augmented clouds under random rotations, a pure function of the step)
and the fixed validation set."""

from __future__ import annotations

import math
from collections import deque
from typing import Any, NamedTuple

import numpy as np
import torch
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from litege_core.errors import InputError
from litege_core.nets.tnet import CUBE_ROTATIONS
from litege_core.sampling import sample_surface
from litege_core.train.tnet.config import TNetAugmentConfig, TNetTrainConfig
from litege_core.train.tnet.shapes import ShapeSet
from litege_core.variants import broken_mesh

_VAL_MODES = ("mesh", "cloud500", "broken")


class TNetBatch(NamedTuple):
    """``canonical (B, N, 3)``, ``rotated = canonical @ R_gtᵀ``, ``R_gt (B, 3, 3)`` and, for
    pre-aligned networks, ``frame_turns (B, 3, 3)`` (identity unless ``augment.frame_turns``)."""

    canonical: torch.Tensor
    rotated: torch.Tensor
    R_gt: torch.Tensor
    frame_turns: torch.Tensor | None = None


def augmented_cloud(
    vertices: NDArray,
    faces: NDArray,
    n_points: int,
    augment: TNetAugmentConfig,
    rng: np.random.Generator,
) -> NDArray:
    """One augmented, centred, rescaled cloud in the canonical orientation."""
    if rng.random() < augment.broken_probability:
        fraction = rng.uniform(augment.broken_min, augment.broken_max)
        faces = faces[broken_mesh(faces, fraction, rng)]
    points = sample_surface(vertices, faces, n_points, rng).points
    if rng.random() < augment.noise_probability:
        points = points + rng.normal(0.0, rng.uniform(0.0, augment.noise_sigma), points.shape)
    points = points - points.mean(axis=0)
    scale = math.exp(rng.uniform(math.log(augment.scale_min), math.log(augment.scale_max)))
    if augment.axis_scale > 0.0:
        bound = math.log1p(augment.axis_scale)
        return points * (scale * np.exp(rng.uniform(-bound, bound, 3)))
    return points * scale


class _BatchArrays(NamedTuple):
    """A batch as float32 numpy arrays (what a loader process sends back) and the indices of
    its :data:`~litege_core.nets.tnet.CUBE_ROTATIONS` frame turns (``None``: no turns)."""

    canonical: NDArray
    rotated: NDArray
    R_gt: NDArray
    turn_indices: NDArray | None = None

    def tensors(self) -> TNetBatch:
        turns = None if self.turn_indices is None else CUBE_ROTATIONS[self.turn_indices].float()
        return TNetBatch(
            torch.from_numpy(self.canonical),
            torch.from_numpy(self.rotated),
            torch.from_numpy(self.R_gt),
            turns,
        )


def _batch_arrays(canonical: NDArray, rotations: NDArray) -> _BatchArrays:
    rotated = np.einsum("bnj,bij->bni", canonical, rotations)
    return _BatchArrays(*(np.asarray(a, dtype=np.float32) for a in (canonical, rotated, rotations)))


def _make_batch(canonical: NDArray, rotations: NDArray) -> TNetBatch:
    return _batch_arrays(canonical, rotations).tensors()


def _sample_batch_arrays(
    shapes: ShapeSet, config: TNetTrainConfig, step: int, batch_size: int | None = None
) -> _BatchArrays:
    augment = config.augment
    rng = np.random.default_rng([config.train.seed, 1, step])
    batch = config.train.batch_size if batch_size is None else batch_size
    low, high = math.log(augment.min_points), math.log(augment.max_points)
    n_points = round(math.exp(rng.uniform(low, high)))
    n_points = min(max(n_points, augment.min_points), augment.max_points)
    index = rng.integers(len(shapes), size=batch)
    rotations = Rotation.random(batch, random_state=rng).as_matrix()
    clouds = np.stack(
        [
            augmented_cloud(shapes.vertices[i], shapes.faces[i], n_points, augment, rng)
            for i in index
        ]
    )
    arrays = _batch_arrays(clouds, rotations)
    if augment.frame_turns:
        arrays = arrays._replace(turn_indices=rng.integers(len(CUBE_ROTATIONS), size=batch))
    return arrays


def sample_batch(
    shapes: ShapeSet, config: TNetTrainConfig, step: int, batch_size: int | None = None
) -> TNetBatch:
    """The training batch of (0-based) ``step``; a pure function of ``(seed, step)``."""
    return _sample_batch_arrays(shapes, config, step, batch_size).tensors()


_LOADER_INPUTS: tuple[ShapeSet, TNetTrainConfig] | None = None
"""What a loader process samples from (set in each one by :func:`_set_loader_inputs`)."""


def _set_loader_inputs(shapes: ShapeSet, config: TNetTrainConfig) -> None:
    """Pool initializer of :class:`BatchLoader` (forked: the inputs are inherited, not pickled)."""
    global _LOADER_INPUTS
    _LOADER_INPUTS = (shapes, config)


def _loader_batch(step: int) -> _BatchArrays:
    assert _LOADER_INPUTS is not None, "loader process started without its inputs"
    shapes, config = _LOADER_INPUTS
    return _sample_batch_arrays(shapes, config, step)


class BatchLoader:
    """The training batches of steps ``0, 1, 2, …`` in order, sampled ``workers`` processes
    ahead of the optimizer (at most ``2 × workers`` batches in flight), or in this process when
    ``workers`` is 0. Either way batch ``t`` is :func:`sample_batch` of step ``t``.

    Use as a context manager; the processes are forked on entry (before any CUDA work of the
    caller is safest: they only run numpy) and stopped on exit.
    """

    def __init__(self, shapes: ShapeSet, config: TNetTrainConfig, workers: int) -> None:
        self.shapes, self.config, self.workers = shapes, config, workers
        self._pool: Any = None
        self._pending: deque[Any] = deque()
        self._next_submit = 0

    def __enter__(self) -> BatchLoader:
        if self.workers > 0:
            import multiprocessing

            self._pool = multiprocessing.get_context("fork").Pool(
                self.workers, _set_loader_inputs, (self.shapes, self.config)
            )
            for _ in range(2 * self.workers):
                self._submit()
        return self

    def __exit__(self, *exc: object) -> None:
        if self._pool is not None:
            self._pool.terminate()
            self._pool.join()
            self._pool = None

    def _submit(self) -> None:
        self._pending.append(self._pool.apply_async(_loader_batch, (self._next_submit,)))
        self._next_submit += 1

    def batch(self, step: int) -> TNetBatch:
        """The batch of ``step`` (steps must be asked for in order, from 0)."""
        if self._pool is None:
            return sample_batch(self.shapes, self.config, step)
        expected = self._next_submit - len(self._pending)
        if step != expected:
            raise InputError(f"BatchLoader serves steps in order: asked {step}, next {expected}")
        arrays = self._pending.popleft().get()
        self._submit()
        return arrays.tensors()


class ValidationSet(NamedTuple):
    """Fixed validation batches, one per input kind (``mesh``, ``cloud500``, ``broken``)."""

    batches: dict[str, TNetBatch]

    @property
    def n_items(self) -> int:
        return sum(b.R_gt.shape[0] for b in self.batches.values())


def validation_set(shapes: ShapeSet, config: TNetTrainConfig) -> ValidationSet:
    """Each val shape as a ``val_points``-sample mesh, a 500-point cloud and a 40 %-broken
    mesh, each with its own fixed rotation; seeded by ``train.seed`` only."""
    n_points = config.train.val_points
    batches = {}
    for mode_index, mode in enumerate(_VAL_MODES):
        rng = np.random.default_rng([config.train.seed, 2, mode_index])
        clouds = []
        for verts, tris in zip(shapes.vertices, shapes.faces, strict=True):
            count = n_points
            if mode == "broken":
                tris = tris[broken_mesh(tris, 0.4, rng)]
            elif mode == "cloud500":
                count = 500
            points = sample_surface(verts, tris, count, rng).points
            clouds.append(points - points.mean(axis=0))
        rotations = Rotation.random(len(shapes), random_state=rng).as_matrix()
        batches[mode] = _make_batch(np.stack(clouds), rotations)
    return ValidationSet(batches)


__all__ = [
    "BatchLoader",
    "TNetBatch",
    "ValidationSet",
    "augmented_cloud",
    "sample_batch",
    "validation_set",
]
