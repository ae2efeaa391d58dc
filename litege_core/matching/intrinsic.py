"""Intrinsic canonical frames of meshes: reference animals mapped by functional maps (issue 15).

The T-Net reads a frame off the shape's extrinsic layout, so a pose far from its training poses
(a crouching human, a curled cat) can turn it. A functional map does not see the pose: the
wave-kernel map of ``zoomout-hybrid``'s descriptor seed
(:func:`~litege_core.matching.refine.descriptor_map`) matches a canonical reference animal
(:func:`~litege_core.matching.judge.reference_animals`: each procedural family's mean body in
the rest pose, in the canonical frame) onto the mesh, and the proper rotation that best fits
the reference's farthest-point samples to their matches (:func:`robust_rotation`, Procrustes
reweighted against wrong matches) is a frame of the mesh. Of the references, the one whose
fit leaves the smallest residual is kept.

The map is blind to left and right (the wave kernel is symmetric), which does not matter here:
the best *proper* rotation onto a map mirrored about the sagittal plane is the rotation itself,
the mirror folded back along the body's narrowest axis.

``MatchingModel.prepare(frames="intrinsic")`` uses it where the T-Net's turned runs disagree
(as judged frames consult the judge), and keeps the T-Net's frame elsewhere. Meshes only (the
Laplace–Beltrami spectrum), and a few seconds per shape and reference on a CPU. Needs pyFM,
like the refinement (:class:`~litege_core.errors.MissingDependencyError` without it).
Measured with ``scripts/frame_report.py --intrinsic`` (BENCHMARKS.md ``frame-intrinsic``).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from litege_core.errors import InputError
from litege_core.validate import triangle_areas

ROBUST_ROUNDS = 6
"""Reweighting rounds of :func:`robust_rotation`."""


def robust_rotation(
    source: NDArray, target: NDArray, rounds: int = ROBUST_ROUNDS
) -> tuple[NDArray, float]:
    """The proper rotation ``R`` with ``target ≈ R · source + t`` for paired points ``(P, 3)``,
    by Procrustes reweighted ``rounds`` times with Cauchy weights (scale: twice the median
    residual); returns ``R`` ``(3, 3)`` and the last fit's mean residual (input units)."""
    source = np.asarray(source, dtype=np.float64)
    target = np.asarray(target, dtype=np.float64)
    if source.shape != target.shape or source.ndim != 2 or source.shape[1] != 3:
        raise InputError(f"need two (P, 3) point sets, got {source.shape} and {target.shape}")
    if rounds < 1:
        raise InputError("rounds must be positive")
    weights = np.ones(len(source))
    for _ in range(rounds):
        share = weights / weights.sum()
        centred_source = source - share @ source
        centred_target = target - share @ target
        u, _, vt = np.linalg.svd((centred_source * weights[:, None]).T @ centred_target)
        sign = np.sign(np.linalg.det(vt.T @ u.T))
        rotation = vt.T @ np.diag([1.0, 1.0, sign]) @ u.T
        residuals = np.linalg.norm(centred_target - centred_source @ rotation.T, axis=1)
        weights = 1.0 / (1.0 + (residuals / (2.0 * np.median(residuals) + 1e-12)) ** 2)
    return rotation, float(residuals.mean())


@dataclass(frozen=True)
class IntrinsicFrame:
    """One reference animal's frame of a mesh.

    Attributes:
        rotation: ``(3, 3)`` input → canonical frame.
        residual: mean distance of the fit (unit-area units).
        family: the reference animal's family.
    """

    rotation: NDArray
    residual: float
    family: str


class _Mesh:
    """What :func:`~litege_core.matching.refine.spectrum` reads of a prepared shape."""

    def __init__(self, vertices: NDArray, faces: NDArray) -> None:
        self.aligned, self.faces, self.scaling = vertices, faces, "unit_area"
        self._lazy: dict[str, Any] = {}


@functools.lru_cache(maxsize=4)
def _references(category: str) -> tuple[tuple[str, NDArray, Any], ...]:
    """``(family, canonical vertices, spectrum)`` of each reference animal (kept per process)."""
    from litege_core.matching.judge import reference_animals
    from litege_core.matching.refine import ZoomOutSettings, spectrum
    from litege_core.synth import template

    faces = np.asarray(template(category).faces, dtype=np.int64)
    out = []
    for animal in reference_animals(category):
        vertices = np.asarray(animal.vertices, dtype=np.float64)
        out.append((animal.name, vertices, spectrum(_Mesh(vertices, faces), ZoomOutSettings())))
    return tuple(out)


def _unit_area(vertices: NDArray, faces: NDArray) -> NDArray:
    """``(V, 3)`` centred on the vertex mean and scaled to unit surface area."""
    area = float(triangle_areas(vertices, faces).sum())
    if not area > 0:
        raise InputError("intrinsic frames need a mesh with a positive area")
    return (vertices - vertices.mean(axis=0)) / np.sqrt(area)


def intrinsic_frames(vertices: NDArray, faces: NDArray, category: str) -> list[IntrinsicFrame]:
    """Every reference animal's frame of the mesh ``(V, 3)``, ``(F, 3)`` (module doc), in the
    order of :func:`~litege_core.matching.judge.reference_animals`.

    Raises:
        InputError: a category without reference animals, or not a mesh.
        MissingDependencyError: no pyFM.
    """
    from litege_core.matching.refine import (
        ZoomOutSettings,
        descriptor_map,
        import_pyfm,
        pointwise_matches,
        spectrum,
    )

    import_pyfm()
    faces = np.asarray(faces, dtype=np.int64)
    if faces.ndim != 2 or faces.shape[1] != 3 or faces.size == 0:
        raise InputError("intrinsic frames need a triangle mesh")
    settings = ZoomOutSettings()
    scaled = _unit_area(np.asarray(vertices, dtype=np.float64), faces)
    target = spectrum(_Mesh(scaled, faces), settings)
    out = []
    for family, canonical, source in _references(category):
        fmap = descriptor_map(source, target, settings)
        found = pointwise_matches(fmap, source, target, source.samples)
        rotation, residual = robust_rotation(canonical[source.samples], scaled[found])
        out.append(IntrinsicFrame(rotation.T, residual, family))
    return out


def intrinsic_frame(vertices: NDArray, faces: NDArray, category: str) -> IntrinsicFrame:
    """The frame of :func:`intrinsic_frames` with the smallest residual."""
    return min(intrinsic_frames(vertices, faces, category), key=lambda frame: frame.residual)


__all__ = [
    "ROBUST_ROUNDS",
    "IntrinsicFrame",
    "intrinsic_frame",
    "intrinsic_frames",
    "robust_rotation",
]
