"""T-Net: a PointNet that predicts the orientation of a shape for the matching pipeline.

Reference-spec §1.6. Architecture (``(B, N, 3)`` in, ``(B, 6)`` out):

==========================  ==============================================================
shared per-point MLP         Conv1d 1×1 with bias 3→128→512→2048, each + BatchNorm1d + ReLU
pool                         global max over the ``N`` points (any ``N ≥ 1``)
FC head                      Linear 2048→512 + BN + ReLU, 512→128 + BN + ReLU, 128→6
6D → rotation                :func:`litege_core.nets.rotation.rotation_from_6d`
==========================  ==============================================================

The FC layers keep PyTorch's default bias (the spec does not say; a bias before BatchNorm is
redundant but harmless, and keeps the layer layout of the authors' PointNet). At inference run
the module in eval mode (BatchNorm on running statistics); in training mode the FC BatchNorm
needs ``B ≥ 2``. The input is a centred, unit-area (or Poisson-scaled) cloud; feed it the point
count it was trained on (the authors train on 2000, see spec §1.6 and §10 item 8).

Frame convention: see :mod:`litege_core.nets.rotation` — ``aligned = pc_rot @ R_pred``.
"""

from __future__ import annotations

from typing import NamedTuple

import torch
from torch import nn

from litege_core.errors import ArrayShapeError, EmptyShapeError
from litege_core.nets._checks import as_tensor_like, check_last, check_ndim
from litege_core.nets.rotation import (
    ANGLE_CLAMP_EPS,
    align_points,
    rotation_angle,
    rotation_from_6d,
)

POINT_LOSS_WEIGHT = 2.0
"""λ of the point term of :func:`tnet_loss` (the authors' value)."""


def _conv_block(d_in: int, d_out: int) -> list[nn.Module]:
    return [nn.Conv1d(d_in, d_out, kernel_size=1), nn.BatchNorm1d(d_out), nn.ReLU()]


def _fc_block(d_in: int, d_out: int) -> list[nn.Module]:
    return [nn.Linear(d_in, d_out), nn.BatchNorm1d(d_out), nn.ReLU()]


class TNet(nn.Module):
    """PointNet regressing the 6D rotation ``R_gt`` of a rotated point cloud.

    ``forward`` gives the raw 6D vector (what the loss is built from via
    :func:`rotation_from_6d`); :meth:`rotation` gives the ``(B, 3, 3)`` matrix and
    :meth:`align` the aligned cloud.
    """

    def __init__(self) -> None:
        super().__init__()
        self.point_mlp = nn.Sequential(
            *_conv_block(3, 128), *_conv_block(128, 512), *_conv_block(512, 2048)
        )
        self.fc = nn.Sequential(*_fc_block(2048, 512), *_fc_block(512, 128), nn.Linear(128, 6))

    @property
    def _reference(self) -> torch.Tensor:
        return self.fc[-1].weight

    def forward(self, points: torch.Tensor) -> torch.Tensor:
        """Raw 6D rotation estimate.

        Args:
            points: ``(B, N, 3)`` rotated, centred, scale-normalized clouds (``N ≥ 1``).

        Returns:
            ``(B, 6)``; :func:`rotation_from_6d` turns it into ``R_pred``.
        """
        points = as_tensor_like(points, "points", self._reference, min_ndim=3)
        check_ndim(points, 3, "points", "(B, N, 3)")
        check_last(points, 3, "points", "(B, N, 3)")
        if points.shape[0] == 0 or points.shape[1] == 0:
            raise EmptyShapeError(f"points has shape {tuple(points.shape)}: no clouds or points")
        features = self.point_mlp(points.transpose(1, 2))  # (B, 2048, N)
        pooled = features.amax(dim=2)  # (B, 2048)
        return self.fc(pooled)

    def rotation(self, points: torch.Tensor) -> torch.Tensor:
        """``(B, N, 3)`` rotated clouds → ``(B, 3, 3)`` estimated ``R_gt``."""
        return rotation_from_6d(self(points))

    def align(self, points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Estimate the rotation and undo it.

        Args:
            points: ``(B, N, 3)`` rotated clouds.

        Returns:
            ``(aligned (B, N, 3), R_pred (B, 3, 3))`` with ``aligned = points @ R_pred``.
        """
        R_pred = self.rotation(points)
        return align_points(points.to(R_pred.dtype), R_pred), R_pred


class TNetLoss(NamedTuple):
    """Terms of :func:`tnet_loss` (0-dim tensors); ``total`` is what to back-propagate."""

    total: torch.Tensor
    angle: torch.Tensor
    """Mean geodesic angle between ``R_pred`` and ``R_gt`` in radians."""
    point: torch.Tensor
    """Mean per-point Euclidean distance between the aligned and the canonical cloud."""


def tnet_loss(
    R_pred: torch.Tensor,
    R_gt: torch.Tensor,
    points_canonical: torch.Tensor,
    points_rotated: torch.Tensor,
    point_weight: float = POINT_LOSS_WEIGHT,
    *,
    eps: float = ANGLE_CLAMP_EPS,
) -> TNetLoss:
    """The T-Net training loss of spec §1.6.

    ``total = mean_b θ_b + λ · mean_{b,i} ‖(pc_rot @ R_pred)_{b,i} − pc_canon_{b,i}‖₂`` with
    ``θ = rotation_angle(R_pred, R_gt)`` (clamped ``arccos``, **not** squared) and
    ``pc_rot = pc_canon @ R_gtᵀ``.

    Args:
        R_pred: ``(B, 3, 3)`` predicted rotations (from :func:`rotation_from_6d`).
        R_gt: ``(B, 3, 3)`` ground-truth rotations.
        points_canonical: ``(B, N, 3)`` clouds in the canonical frame.
        points_rotated: ``(B, N, 3)`` the same clouds rotated, ``points_canonical @ R_gtᵀ``.
        point_weight: λ (2 in the reference).
        eps: cosine clamp of :func:`rotation_angle`; with the default the angle term of a
            perfect prediction is ``arccos(1 − 1e-7) ≈ 4.5e-4`` rad, not 0.

    Returns:
        :class:`TNetLoss` ``(total, angle, point)``.
    """
    if points_canonical.shape != points_rotated.shape or points_canonical.ndim != 3:
        raise ArrayShapeError(
            "points_canonical and points_rotated must both have shape (B, N, 3), got "
            f"{tuple(points_canonical.shape)} and {tuple(points_rotated.shape)}"
        )
    check_last(points_canonical, 3, "points_canonical", "(B, N, 3)")
    if R_pred.shape != R_gt.shape or tuple(R_pred.shape) != (points_canonical.shape[0], 3, 3):
        raise ArrayShapeError(
            f"R_pred and R_gt must have shape ({points_canonical.shape[0]}, 3, 3), got "
            f"{tuple(R_pred.shape)} and {tuple(R_gt.shape)}"
        )
    angle = rotation_angle(R_pred, R_gt, eps=eps).mean()
    aligned = align_points(points_rotated, R_pred)
    point = torch.linalg.vector_norm(aligned - points_canonical, dim=-1).mean()
    return TNetLoss(angle + point_weight * point, angle, point)


__all__ = ["POINT_LOSS_WEIGHT", "TNet", "TNetLoss", "tnet_loss"]
