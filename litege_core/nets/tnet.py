"""T-Net: a PointNet that predicts the orientation of a shape for the matching pipeline.

Reference-spec §1.6. Architecture (``(B, N, 3)`` in, ``(B, 6)`` out):

==========================  ==============================================================
shared per-point MLP         Conv1d 1×1 with bias 3→128→512→2048, each + BatchNorm1d + ReLU
pool                         global max over the ``N`` points (any ``N ≥ 1``)
FC head                      Linear 2048→512 + BN + ReLU, 512→128 + BN + ReLU, 128→6
6D → rotation                :func:`litege_core.nets.rotation.rotation_from_6d`
==========================  ==============================================================

The widths are configurable (``TNet(conv_widths, fc_widths)``, defaults = the reference above;
:meth:`TNet.config` / :meth:`TNet.from_config` for bundles): the shipped CPU-trained model uses
narrower layers (``configs/tnet-quadrupeds.toml``). The 1×1 convolutions are evaluated as one
matrix product over all ``B·N`` points (``F.linear`` on the squeezed ``Conv1d`` weight, BatchNorm
over ``(B·N, C)``): the same function and the same BatchNorm statistics as ``Conv1d`` on
``(B, C, N)``, about twice as fast on CPU, and the state dict keeps the ``Conv1d`` layout.

**Pre-alignment** (``prealign="pca"``, an option of this implementation, off by default): the
cloud is first expressed in its principal-axis frame ``Q`` (:func:`pca_frames`: axes by
decreasing variance, the first two oriented by the sign of their third moment, the third their
cross product) and the network regresses only the residual rotation of the PCA-aligned cloud;
:meth:`TNet.rotation` returns ``Q @ R_res``, so callers see the same contract (an estimate of
``R_gt``, ``aligned = pc_rot @ R_pred``). The residual is close to a few discrete flips, which a
small network learns in far fewer steps than an arbitrary rotation (the CPU-trained model).
:meth:`TNet.forward` always returns the raw 6D output of the network on its own input.

The FC layers keep PyTorch's default bias (the spec does not say; a bias before BatchNorm is
redundant but harmless, and keeps the layer layout of the authors' PointNet). At inference run
the module in eval mode (BatchNorm on running statistics); in training mode the FC BatchNorm
needs ``B ≥ 2``. The input is a centred, unit-area (or Poisson-scaled) cloud; feed it the point
count it was trained on (the authors train on 2000, see spec §1.6 and §10 item 8).

Frame convention: see :mod:`litege_core.nets.rotation` — ``aligned = pc_rot @ R_pred``.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from typing import Any, NamedTuple

import numpy as np
import torch
from torch import nn
from torch.nn import functional

from litege_core.errors import ArrayShapeError, EmptyShapeError, InputError
from litege_core.nets._checks import as_tensor_like, check_last, check_ndim
from litege_core.nets.rotation import (
    ANGLE_CLAMP_EPS,
    align_points,
    rotation_angle,
    rotation_from_6d,
)

POINT_LOSS_WEIGHT = 2.0
"""λ of the point term of :func:`tnet_loss` (the authors' value)."""

REFERENCE_CONV_WIDTHS: tuple[int, ...] = (128, 512, 2048)
"""Output widths of the shared per-point layers of the reference T-Net."""

REFERENCE_FC_WIDTHS: tuple[int, ...] = (512, 128)
"""Hidden widths of the reference FC head (the pooled vector goes in, 6 numbers come out)."""

PREALIGN_MODES: tuple[str, ...] = ("none", "pca")
"""``TNet(prealign=…)``: ``"none"`` (the reference) or ``"pca"`` (see the module docstring)."""

_CONFIG_KEYS = frozenset({"conv_widths", "fc_widths", "prealign"})


def _cube_rotations() -> torch.Tensor:
    mats = []
    for perm in itertools.permutations(range(3)):
        for signs in itertools.product((1.0, -1.0), repeat=3):
            m = torch.zeros(3, 3, dtype=torch.float64)
            for row, (col, sign) in enumerate(zip(perm, signs, strict=True)):
                m[row, col] = sign
            if torch.linalg.det(m) > 0:
                mats.append(m)
    return torch.stack(mats)


CUBE_ROTATIONS: torch.Tensor = _cube_rotations()
"""The 24 proper signed permutation matrices ``(24, 3, 3)`` float64 (rotations of the cube).

Training with ``frames = pca_frames(x) @ CUBE_ROTATIONS[k]`` (random ``k``) shows a
pre-aligned T-Net every axis order and sign of the PCA frame equally often, so it must read
the orientation from the shape instead of learning the most frequent PCA state."""


@torch.no_grad()
def pca_frames(points: torch.Tensor) -> torch.Tensor:
    """Principal-axis frames ``Q`` ``(B, 3, 3)`` of clouds ``(B, N, 3)`` (no gradient).

    Columns ``(a0, a1, a2)``: the covariance eigenvectors by decreasing eigenvalue (float64
    ``eigh`` of the centred cloud); ``a0`` and ``a1`` are flipped where the third moment of the
    projections ``Σ ((p − p̄)·a)³`` is negative, and ``a2 = a0 × a1`` (a proper rotation).
    ``points @ Q`` expresses the cloud in that frame (row-vector convention).
    """
    values = points.double()
    centred = values - values.mean(dim=1, keepdim=True)
    covariance = centred.transpose(1, 2) @ centred
    _, vectors = torch.linalg.eigh(covariance)  # ascending eigenvalues
    a0, a1 = vectors[..., 2], vectors[..., 1]
    axes = []
    for axis in (a0, a1):
        moment = ((centred @ axis.unsqueeze(-1)).squeeze(-1) ** 3).sum(dim=1)
        axes.append(torch.where((moment < 0).unsqueeze(-1), -axis, axis))
    axes.append(torch.linalg.cross(axes[0], axes[1], dim=-1))
    return torch.stack(axes, dim=-1).to(points.dtype)


def _widths(values: Sequence[int], name: str) -> tuple[int, ...]:
    if isinstance(values, str | bytes) or not isinstance(values, Sequence | np.ndarray):
        raise InputError(f"{name} must be a sequence of positive integers, got {values!r}")
    widths = tuple(values)
    for width in widths:
        if isinstance(width, bool) or not isinstance(width, int | np.integer) or width < 1:
            raise InputError(f"{name} must hold positive integers, got {list(widths)!r}")
    return tuple(int(w) for w in widths)


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

    def __init__(
        self,
        conv_widths: Sequence[int] = REFERENCE_CONV_WIDTHS,
        fc_widths: Sequence[int] = REFERENCE_FC_WIDTHS,
        prealign: str = "none",
    ) -> None:
        """Build the network.

        Args:
            conv_widths: output widths of the shared per-point layers (at least one); the
                last one is the size of the pooled global feature.
            fc_widths: hidden widths of the FC head (may be empty: pooled → 6 directly).
            prealign: ``"none"`` (reference) or ``"pca"`` (residual in the PCA frame).

        Raises:
            InputError: a width that is not a positive integer, no per-point layer, or an
                unknown ``prealign``.
        """
        super().__init__()
        if prealign not in PREALIGN_MODES:
            raise InputError(f"prealign must be one of {list(PREALIGN_MODES)}, got {prealign!r}")
        self.prealign = prealign
        self.conv_widths = _widths(conv_widths, "conv_widths")
        self.fc_widths = _widths(fc_widths, "fc_widths")
        if not self.conv_widths:
            raise InputError("conv_widths needs at least one per-point layer")
        dims = (3, *self.conv_widths)
        self.point_mlp = nn.Sequential(
            *(m for d_in, d_out in itertools.pairwise(dims) for m in _conv_block(d_in, d_out))
        )
        dims = (self.conv_widths[-1], *self.fc_widths)
        self.fc = nn.Sequential(
            *(m for d_in, d_out in itertools.pairwise(dims) for m in _fc_block(d_in, d_out)),
            nn.Linear(dims[-1], 6),
        )

    # ------------------------------------------------------------------ configuration

    def config(self) -> dict[str, Any]:
        """JSON-safe constructor arguments (for a bundle manifest or a weights file)."""
        return {
            "conv_widths": list(self.conv_widths),
            "fc_widths": list(self.fc_widths),
            "prealign": self.prealign,
        }

    @classmethod
    def from_config(cls, config: dict[str, Any]) -> TNet:
        """Inverse of :meth:`config`; unknown keys raise :class:`InputError`, missing keys
        take the reference widths."""
        if not isinstance(config, dict):
            raise InputError(f"a TNet config must be a dict, got {type(config).__name__}")
        unknown = set(config) - _CONFIG_KEYS
        if unknown:
            raise InputError(f"unknown TNet config keys: {sorted(unknown)}")
        return cls(**config)

    def extra_repr(self) -> str:
        return (
            f"conv_widths={self.conv_widths}, fc_widths={self.fc_widths}, "
            f"prealign={self.prealign!r}"
        )

    @property
    def _reference(self) -> torch.Tensor:
        last = self.fc[-1]
        assert isinstance(last, nn.Linear)
        return last.weight

    def _point_features(self, points: torch.Tensor) -> torch.Tensor:
        """``(B, N, 3)`` → ``(B, C)`` max-pooled per-point features.

        Each ``Conv1d`` 1×1 is applied as ``F.linear`` on the ``(B·N, C_in)`` rows; BatchNorm1d
        on ``(B·N, C)`` normalizes over the same ``B·N`` values as on ``(B, C, N)``.
        """
        batch, n_points, _ = points.shape
        rows = points.reshape(batch * n_points, 3)
        layers: list[Any] = list(self.point_mlp)  # (conv, norm, activation) triples
        for conv, norm, act in zip(layers[0::3], layers[1::3], layers[2::3], strict=True):
            rows = act(norm(functional.linear(rows, conv.weight.squeeze(-1), conv.bias)))
        return rows.reshape(batch, n_points, -1).amax(dim=1)

    def forward(self, points: torch.Tensor) -> torch.Tensor:
        """Raw 6D rotation estimate.

        Args:
            points: ``(B, N, 3)`` rotated, centred, scale-normalized clouds (``N ≥ 1``).

        Returns:
            ``(B, 6)``; :func:`rotation_from_6d` turns it into ``R_pred``.
        """
        return self.fc(self._point_features(self._checked(points)))

    def _checked(self, points: torch.Tensor) -> torch.Tensor:
        points = as_tensor_like(points, "points", self._reference, min_ndim=3)
        check_ndim(points, 3, "points", "(B, N, 3)")
        check_last(points, 3, "points", "(B, N, 3)")
        if points.shape[0] == 0 or points.shape[1] == 0:
            raise EmptyShapeError(f"points has shape {tuple(points.shape)}: no clouds or points")
        return points

    def rotation(self, points: torch.Tensor, frames: torch.Tensor | None = None) -> torch.Tensor:
        """``(B, N, 3)`` rotated clouds → ``(B, 3, 3)`` estimated ``R_gt``.

        With ``prealign="pca"``: ``Q @ rotation_from_6d(self(points @ Q))``, ``Q`` =
        :func:`pca_frames` (the gradient flows through the network output only). ``frames``
        replaces ``Q`` by other proper frames ``(B, 3, 3)`` (training: turned PCA frames, see
        :data:`CUBE_ROTATIONS`); not allowed without pre-alignment.
        """
        if self.prealign == "none":
            if frames is not None:
                raise InputError("frames are only used with prealign='pca'")
            return rotation_from_6d(self(points))
        points = self._checked(points)
        if frames is None:
            frames = pca_frames(points)
        elif tuple(frames.shape) != (points.shape[0], 3, 3):
            raise ArrayShapeError(
                f"frames must have shape ({points.shape[0]}, 3, 3), got {tuple(frames.shape)}"
            )
        frames = frames.to(points.dtype)
        return frames @ rotation_from_6d(self(points @ frames))

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


__all__ = [
    "CUBE_ROTATIONS",
    "POINT_LOSS_WEIGHT",
    "PREALIGN_MODES",
    "REFERENCE_CONV_WIDTHS",
    "REFERENCE_FC_WIDTHS",
    "TNet",
    "TNetLoss",
    "pca_frames",
    "tnet_loss",
]
