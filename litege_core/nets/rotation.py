"""Rotations for the T-Net: the 6D representation, the geodesic angle, the frame convention.

Reference-spec §1.6. Convention (row-vector point clouds ``(..., N, 3)``):

* a ground-truth rotation ``R_gt`` rotates a canonical cloud as ``pc_rot = pc_canon @ R_gtᵀ``
  (each point becomes ``R_gt p``) — :func:`rotate_points`;
* the T-Net estimates ``R_gt`` from ``pc_rot``, and the cloud is brought back by a **right**
  multiplication ``aligned = pc_rot @ R_pred`` (each point becomes ``R_predᵀ p``) —
  :func:`align_points`. Mesh vertices get the same right multiplication.

So ``align_points(rotate_points(pc, R), R) == pc``, and the canonicalization rotation of
:class:`litege_core.canonical.Transform` (``q = R_c p``) for a T-Net prediction is
``R_c = R_predᵀ``.
"""

from __future__ import annotations

import torch

from litege_core.errors import ArrayShapeError

NORM_EPS = 1e-8
"""Added to every norm in :func:`rotation_from_6d` (as in the authors' code)."""

ANGLE_CLAMP_EPS = 1e-7
"""The cosine is clamped to ``[−1 + eps, 1 − eps]`` before ``arccos`` (finite gradients).

The clamp puts a floor of ``arccos(1 − 1e-7) ≈ 4.5e-4`` rad under every angle."""


def _check_matrices(matrix: torch.Tensor, name: str) -> None:
    if not isinstance(matrix, torch.Tensor):
        raise ArrayShapeError(f"{name} must be a torch.Tensor, got {type(matrix).__name__}")
    if matrix.ndim < 2 or tuple(matrix.shape[-2:]) != (3, 3):
        raise ArrayShapeError(f"{name} must have shape (..., 3, 3), got {tuple(matrix.shape)}")


def rotation_from_6d(v: torch.Tensor) -> torch.Tensor:
    """Rotation matrices from the 6D representation of Zhou et al. (Gram–Schmidt).

    ``u1 = v1/(‖v1‖+ε)``, ``u2 = w/(‖w‖+ε)`` with ``w = v2 − (u1·v2) u1``,
    ``u3 = u1×u2 / (‖u1×u2‖+ε)``, ``ε = 1e-8``; the matrix has **columns** ``(u1, u2, u3)``.

    Args:
        v: ``(..., 6)`` raw network output; ``v1 = v[..., :3]``, ``v2 = v[..., 3:]``.

    Returns:
        ``(..., 3, 3)`` proper rotations (``RᵀR = I``, ``det R = +1``) for non-degenerate
        ``v`` (``v1 ≠ 0`` and ``v2`` not parallel to ``v1``).
    """
    if not isinstance(v, torch.Tensor):
        raise ArrayShapeError(f"v must be a torch.Tensor, got {type(v).__name__}")
    if v.ndim < 1 or v.shape[-1] != 6:
        raise ArrayShapeError(f"v must have shape (..., 6), got {tuple(v.shape)}")
    v1, v2 = v[..., :3], v[..., 3:]
    u1 = v1 / (torch.linalg.vector_norm(v1, dim=-1, keepdim=True) + NORM_EPS)
    w = v2 - (u1 * v2).sum(dim=-1, keepdim=True) * u1
    u2 = w / (torch.linalg.vector_norm(w, dim=-1, keepdim=True) + NORM_EPS)
    c = torch.linalg.cross(u1, u2, dim=-1)
    u3 = c / (torch.linalg.vector_norm(c, dim=-1, keepdim=True) + NORM_EPS)
    return torch.stack((u1, u2, u3), dim=-1)


def rotation_angle(
    R_a: torch.Tensor, R_b: torch.Tensor, *, eps: float = ANGLE_CLAMP_EPS
) -> torch.Tensor:
    """Geodesic angle between rotations: ``arccos(clamp((tr(R_aᵀ R_b) − 1)/2, −1+ε, 1−ε))``.

    Args:
        R_a: ``(..., 3, 3)`` rotations.
        R_b: ``(..., 3, 3)`` rotations, broadcastable against ``R_a``.
        eps: cosine clamp (see :data:`ANGLE_CLAMP_EPS`; ``0`` gives exact zeros at the cost
            of an infinite gradient there).

    Returns:
        ``(...)`` angles in radians, in ``[0, π]`` (not squared).
    """
    _check_matrices(R_a, "R_a")
    _check_matrices(R_b, "R_b")
    # tr(AᵀB) = Σ_ij A_ij B_ij, without forming the product.
    trace = (R_a * R_b).sum(dim=(-2, -1))
    cosine = torch.clamp((trace - 1.0) / 2.0, -1.0 + eps, 1.0 - eps)
    return torch.arccos(cosine)


def rotate_points(points: torch.Tensor, R: torch.Tensor) -> torch.Tensor:
    """Canonical → rotated: ``points @ Rᵀ`` (each point becomes ``R p``).

    Args:
        points: ``(..., N, 3)``.
        R: ``(..., 3, 3)``, batch dims broadcastable against those of ``points``.
    """
    _check_matrices(R, "R")
    return points @ R.transpose(-1, -2)


def align_points(points: torch.Tensor, R: torch.Tensor) -> torch.Tensor:
    """Rotated → canonical with a T-Net estimate ``R``: ``points @ R`` (each point ``Rᵀ p``).

    Args:
        points: ``(..., N, 3)`` rotated cloud (or mesh vertices).
        R: ``(..., 3, 3)`` predicted rotation, batch dims broadcastable against ``points``.
    """
    _check_matrices(R, "R")
    return points @ R


__all__ = [
    "ANGLE_CLAMP_EPS",
    "NORM_EPS",
    "align_points",
    "rotate_points",
    "rotation_angle",
    "rotation_from_6d",
]
