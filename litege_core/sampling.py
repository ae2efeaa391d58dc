"""Point sampling: area-weighted surface samples (more samplers are added below)."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from litege_core.errors import ArrayShapeError, DegenerateShapeError
from litege_core.validate import triangle_areas


class SurfaceSamples(NamedTuple):
    """Points on a triangle mesh with their location on it.

    Attributes:
        points: ``(n, 3)`` float64 positions.
        face_index: ``(n,)`` int64 triangle each point lies on.
        barycentric: ``(n, 3)`` float64 weights of the triangle's corners (rows sum to 1).
    """

    points: NDArray
    face_index: NDArray
    barycentric: NDArray


def sample_surface(
    vertices: NDArray, faces: NDArray, n_samples: int, seed: int | np.random.Generator = 0
) -> SurfaceSamples:
    """Draw ``n_samples`` points uniformly by area (faces with replacement, p ∝ area).

    Barycentric coordinates are uniform on the triangle: draw ``u, v ~ U(0, 1)`` and fold
    ``u + v > 1`` back (the authors' convention). Deterministic for a given seed.
    """
    if n_samples < 0:
        raise ArrayShapeError(f"n_samples must be non-negative, got {n_samples}")
    rng = np.random.default_rng(seed)
    areas = triangle_areas(vertices, faces)
    total = areas.sum()
    if not total > 0:
        raise DegenerateShapeError("cannot sample a mesh with zero area")
    cumulative = np.cumsum(areas)
    face_index = np.searchsorted(cumulative, rng.random(n_samples) * cumulative[-1], side="right")
    face_index = np.minimum(face_index, faces.shape[0] - 1).astype(np.int64)
    uv = rng.random((n_samples, 2))
    folded = uv.sum(axis=1) > 1.0
    uv[folded] = 1.0 - uv[folded]
    barycentric = np.column_stack([1.0 - uv[:, 0] - uv[:, 1], uv[:, 0], uv[:, 1]])
    corners = vertices[faces[face_index]]
    points = np.einsum("nk,nkd->nd", barycentric, corners)
    return SurfaceSamples(points, face_index, barycentric)
