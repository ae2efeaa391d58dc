"""From a user's shape to its UDF-PCA descriptor (geodesic-regression pipeline, spec §1.2, §2).

``describe_shape`` = sample (meshes: ``n_samples`` area-weighted surface points; point clouds:
their own points, isolated ones left out, evenly spread) → centre, PCA-align and bounding-box
scale → UDF at the informative voxels → PCA projection. The transform is returned so every
output can be mapped back to the user's frame, and the PCA reconstruction residual serves as an
out-of-distribution score.

``frame_candidates`` other than ``"pca"`` replaces the plain PCA sign rule by the lowest-residual
candidate frame of :func:`litege_core.learned.frame.select_frame` (issue 14).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from litege_core.canonical import Transform, canonicalize_bbox
from litege_core.descriptor import UdfPcaBasis
from litege_core.sampling import evenly_spread, sample_surface
from litege_core.shape import Shape

if TYPE_CHECKING:
    import torch

DEFAULT_MESH_SAMPLES = 2000


@dataclass(frozen=True)
class ShapeDescription:
    """A shape's canonical frame and descriptor.

    Attributes:
        transform: user frame → canonical frame.
        samples: ``(P, 3)`` the sampled points, in the canonical frame.
        descriptor: ``(k,)`` float32 PCA coefficients (not whitened).
        residual: PCA reconstruction residual of the UDF (canonical units); large values mean
            the shape is unlike the basis's training shapes.
    """

    transform: Transform
    samples: NDArray
    descriptor: NDArray
    residual: float


def shape_samples(shape: Shape, n_samples: int = DEFAULT_MESH_SAMPLES, seed: int = 0) -> NDArray:
    """``(P, 3)`` points the descriptor is computed from, in the user's frame: a mesh's
    ``n_samples`` surface samples; a cloud's points less its isolated ones, thinned to an even
    spread (:func:`~litege_core.sampling.evenly_spread`, seeded: a scan's stray points would
    pull the frame and write false surface into the UDF, and its denser parts would weigh more
    than the surface they cover; every point is still embedded and answered)."""
    if shape.faces is None:
        return evenly_spread(np.asarray(shape.vertices), seed)
    return sample_surface(shape.vertices, shape.faces, n_samples, seed).points


def describe_shape(
    shape: Shape,
    basis: UdfPcaBasis,
    *,
    n_samples: int = DEFAULT_MESH_SAMPLES,
    seed: int = 0,
    device: str | torch.device = "cpu",
    frame_candidates: str = "pca",
) -> ShapeDescription:
    """Canonicalize ``shape`` and compute its descriptor on ``basis``.

    Args:
        frame_candidates: ``"pca"`` (the PCA sign rule) or a candidate set of
            :data:`litege_core.learned.frame.FRAME_CANDIDATES` scored by the UDF-PCA residual.
    """
    points = shape_samples(shape, n_samples, seed)
    if frame_candidates != "pca":
        from litege_core.learned.frame import select_frame

        choice = select_frame(points, basis, device, frame_candidates)
        return ShapeDescription(
            transform=choice.transform,
            samples=choice.samples,
            descriptor=np.asarray(choice.descriptor, dtype=np.float32),
            residual=choice.residual,
        )
    transform = canonicalize_bbox(points)
    canonical = transform.apply(points)
    result = basis.engine(device).describe_with_residual(canonical[None])
    return ShapeDescription(
        transform=transform,
        samples=canonical,
        descriptor=result.descriptors[0].cpu().numpy(),
        residual=float(result.residual[0]),
    )


__all__ = ["DEFAULT_MESH_SAMPLES", "ShapeDescription", "describe_shape", "shape_samples"]
