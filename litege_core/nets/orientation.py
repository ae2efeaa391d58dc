"""Which cube turn of a frame is canonical: a small 3D CNN over a point-density grid (issue 15).

A frame the T-Net or the principal axes give is often right up to a turn of the cube: the
head where the tail should be, the back down, the body on its side. :class:`OrientationNet`
reads a cloud expressed in some frame and says, for each of the 24 cube rotations ``K``
(:data:`~litege_core.nets.tnet.CUBE_ROTATIONS`), how likely ``cloud @ K`` is the canonical
animal (log-probabilities over the 24; index 0, the identity, asks whether the frame itself is
canonical). It is trained on generated animals in known canonical frames
(:mod:`litege_core.train.orientation`), so unlike the frame judge it needs no reference shapes.

Input: the cloud centred on its mean and divided by its RMS radius (scale-free), trilinearly
splatted into a ``grid³`` density grid over ``[−extent, extent]³`` (points outside are clamped
to the border cells), each grid summing to 1.
"""

from __future__ import annotations

from typing import Any

import torch
from torch import nn

from litege_core.errors import ArrayShapeError, InputError

GRID = 16
"""Cells per axis of the density grid."""
EXTENT = 2.5
"""Half-width of the grid in RMS radii of the cloud (a quadruped's snout or tail tip lies
within about 2.3 RMS radii of its centre)."""
N_TURNS = 24

_CONFIG_KEYS = {"grid", "extent", "conv_widths", "fc_width"}


def density_grids(points: torch.Tensor, grid: int = GRID, extent: float = EXTENT) -> torch.Tensor:
    """Scale-free density grids of clouds.

    Args:
        points: ``(B, N, 3)`` clouds (any units, any centre).
        grid: cells per axis.
        extent: half-width of the grid in RMS radii.

    Returns:
        ``(B, 1, grid, grid, grid)`` float32 grids (axis order x, y, z), each summing to 1.
    """
    if points.ndim != 3 or points.shape[-1] != 3 or points.shape[1] < 1:
        raise ArrayShapeError(f"points must be (B, N, 3) with N >= 1, got {tuple(points.shape)}")
    points = points.float()
    centred = points - points.mean(dim=1, keepdim=True)
    rms = centred.square().sum(-1).mean(-1).clamp_min(1e-12).sqrt()
    # continuous cell coordinates: cell i is centred at (i + 0.5) / grid of the box
    unit = (centred / rms[:, None, None] / (2.0 * extent) + 0.5) * grid - 0.5
    unit = unit.clamp(0.0, grid - 1.0)
    low = unit.floor().clamp(max=grid - 2).long()
    frac = unit - low
    batch, count = points.shape[:2]
    flat = torch.zeros(batch, grid**3, device=points.device)
    for corner in range(8):
        offset = torch.tensor([(corner >> a) & 1 for a in range(3)], device=points.device)
        weight = torch.where(offset.bool(), frac, 1.0 - frac).prod(-1)  # (B, N)
        cell = low + offset
        index = (cell[..., 0] * grid + cell[..., 1]) * grid + cell[..., 2]
        flat.scatter_add_(1, index, weight)
    return (flat / count).reshape(batch, 1, grid, grid, grid)


class OrientationNet(nn.Module):
    """3D CNN: ``(B, N, 3)`` clouds → ``(B, 24)`` logits over the cube turns that make them
    canonical (softmax over the 24; see the module docstring).

    Args:
        grid: cells per axis of the input grid (a multiple of ``2 ** len(conv_widths)``).
        extent: half-width of the grid in RMS radii.
        conv_widths: channels of the 3×3×3 convolution blocks, each followed by ReLU and a
            2× max-pool.
        fc_width: width of the hidden fully connected layer.
    """

    def __init__(
        self,
        grid: int = GRID,
        extent: float = EXTENT,
        conv_widths: tuple[int, ...] | list[int] = (16, 32, 64),
        fc_width: int = 128,
    ) -> None:
        super().__init__()
        widths = tuple(int(w) for w in conv_widths)
        if not widths or min(widths) < 1 or fc_width < 1:
            raise InputError("an OrientationNet needs positive conv and fc widths")
        if grid < 2 ** len(widths) or grid % (2 ** len(widths)):
            raise InputError(f"grid {grid} must be a multiple of {2 ** len(widths)}")
        if extent <= 0.0:
            raise InputError(f"extent must be positive, got {extent!r}")
        self.grid, self.extent, self.conv_widths, self.fc_width = grid, extent, widths, fc_width
        layers: list[nn.Module] = []
        channels = 1
        for width in widths:
            layers += [nn.Conv3d(channels, width, 3, padding=1), nn.ReLU(), nn.MaxPool3d(2)]
            channels = width
        self.features = nn.Sequential(*layers)
        cells = (grid // 2 ** len(widths)) ** 3
        self.head = nn.Sequential(
            nn.Flatten(),
            nn.Linear(channels * cells, fc_width),
            nn.ReLU(),
            nn.Linear(fc_width, N_TURNS),
        )

    def forward(self, points: torch.Tensor) -> torch.Tensor:
        """``(B, N, 3)`` clouds → ``(B, 24)`` logits."""
        grids = density_grids(points, self.grid, self.extent)
        dtype = next(self.parameters()).dtype
        return self.head(self.features(grids.to(dtype)))

    @torch.no_grad()
    def canonical_log_probability(self, points: torch.Tensor) -> torch.Tensor:
        """``(B,)`` log-probability that each ``(B, N, 3)`` cloud is in a canonical frame as it
        is (the identity turn)."""
        return torch.log_softmax(self(points), dim=-1)[:, 0]

    def config(self) -> dict[str, Any]:
        """JSON-safe constructor arguments (for a bundle manifest)."""
        return {
            "grid": self.grid,
            "extent": self.extent,
            "conv_widths": list(self.conv_widths),
            "fc_width": self.fc_width,
        }

    @classmethod
    def from_config(cls, config: dict[str, Any]) -> OrientationNet:
        """Inverse of :meth:`config`; unknown keys raise :class:`InputError`."""
        if not isinstance(config, dict):
            raise InputError(
                f"an OrientationNet config must be a dict, got {type(config).__name__}"
            )
        unknown = set(config) - _CONFIG_KEYS
        if unknown:
            raise InputError(f"unknown OrientationNet config keys: {sorted(unknown)}")
        return cls(**config)


__all__ = ["EXTENT", "GRID", "N_TURNS", "OrientationNet", "density_grids"]
