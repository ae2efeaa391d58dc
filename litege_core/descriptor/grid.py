"""The regular voxel grid of the UDF-PCA descriptor (reference spec §2.1).

A :class:`VoxelGrid` is a cube of ``resolution³`` voxels of edge ``pitch`` centred at the
origin of the canonical frame. Voxel ``(i, j, k)`` has its centre at
``((i − c)·pitch, (j − c)·pitch, (k − c)·pitch)`` with ``c = (resolution − 1) / 2`` and covers
the half-open box ``[centre − pitch/2, centre + pitch/2)`` on each axis. Flat indices are
x-major, as ``np.meshgrid(..., indexing="ij")`` flattens: ``flat = (i·res + j)·res + k``.

The default (``resolution=121, pitch=0.02``) is the authors' grid: centres at ``k·0.02`` for
``k = −60…60``, spanning ``[−1.2, 1.2]³`` (cube faces at ``±1.21``), 1,771,561 voxels.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from litege_core.descriptor._arrays import as_numeric, as_points, positive_float, positive_int
from litege_core.errors import ArrayShapeError, IndexOutOfRangeError, InputError

DEFAULT_RESOLUTION = 121
DEFAULT_PITCH = 0.02


@dataclass(frozen=True)
class VoxelGrid:
    """A ``resolution³`` grid of cubic voxels of edge ``pitch`` (canonical units), centred at 0.

    Attributes:
        resolution: voxels per axis (≥ 1).
        pitch: voxel edge length, canonical-frame units (> 0).
    """

    resolution: int = DEFAULT_RESOLUTION
    pitch: float = DEFAULT_PITCH

    def __post_init__(self) -> None:
        object.__setattr__(self, "resolution", positive_int(self.resolution, "resolution"))
        object.__setattr__(self, "pitch", positive_float(self.pitch, "pitch"))
        if self.resolution > 2048:
            raise InputError(f"resolution {self.resolution} is larger than the supported 2048")

    # ----------------------------------------------------------------- geometry
    @property
    def n_voxels(self) -> int:
        """Number of voxels, ``resolution³``."""
        return self.resolution**3

    @property
    def shape(self) -> tuple[int, int, int]:
        """``(res, res, res)``, the dense layout of a flat per-voxel array."""
        return (self.resolution, self.resolution, self.resolution)

    @property
    def first_center(self) -> float:
        """Coordinate of the centre of voxel 0 on every axis: ``−(res − 1)/2 · pitch``."""
        return -0.5 * (self.resolution - 1) * self.pitch

    @property
    def lower(self) -> float:
        """Lower bound of the grid box on every axis (``first_center − pitch/2``)."""
        return self.first_center - 0.5 * self.pitch

    @property
    def upper(self) -> float:
        """Upper bound of the grid box on every axis (``−lower``)."""
        return -self.lower

    def axis_centers(self) -> NDArray:
        """``(res,)`` float64 centre coordinates along one axis, ``(k − (res−1)/2)·pitch``."""
        return (np.arange(self.resolution, dtype=np.float64) - 0.5 * (self.resolution - 1)) * (
            self.pitch
        )

    def centers(self, indices: ArrayLike | None = None, dtype: type = np.float64) -> NDArray:
        """Voxel centres.

        Args:
            indices: ``(M,)`` flat voxel indices, or ``None`` for all ``res³`` voxels in flat
                (x-major) order.
            dtype: ``np.float64`` (default) or ``np.float32``; values are computed in float64
                and then cast, so float32 centres are the rounded float64 ones.

        Returns:
            ``(M, 3)`` centres in canonical units.
        """
        axis = self.axis_centers()
        ijk = self.ijk(np.arange(self.n_voxels) if indices is None else indices)
        return axis[ijk].astype(dtype, copy=False)

    # ----------------------------------------------------------------- indexing
    def flat_index(self, ijk: ArrayLike) -> NDArray:
        """``(M, 3)`` integer voxel coordinates → ``(M,)`` int64 flat indices.

        Raises:
            ArrayShapeError: not an integer ``(M, 3)`` array.
            IndexOutOfRangeError: a coordinate outside ``[0, res)``.
        """
        array = as_numeric(ijk, "ijk")
        if array.ndim != 2 or array.shape[1] != 3:
            raise ArrayShapeError(f"ijk must have shape (M, 3), got {array.shape}")
        if not np.issubdtype(array.dtype, np.integer):
            raise ArrayShapeError(f"ijk must be integers, got dtype {array.dtype}")
        array = array.astype(np.int64, copy=False)
        if array.size and (array.min() < 0 or array.max() >= self.resolution):
            raise IndexOutOfRangeError(
                f"voxel coordinates must lie in [0, {self.resolution}), "
                f"got range [{int(array.min())}, {int(array.max())}]"
            )
        res = self.resolution
        return (array[:, 0] * res + array[:, 1]) * res + array[:, 2]

    def ijk(self, flat: ArrayLike) -> NDArray:
        """``(M,)`` flat indices → ``(M, 3)`` int64 voxel coordinates ``(i, j, k)``.

        Raises:
            ArrayShapeError: not a 1-D integer array.
            IndexOutOfRangeError: an index outside ``[0, res³)``.
        """
        array = self.check_flat_indices(flat)
        res = self.resolution
        out = np.empty((array.shape[0], 3), dtype=np.int64)
        rest, out[:, 2] = np.divmod(array, res)
        out[:, 0], out[:, 1] = np.divmod(rest, res)
        return out

    def check_flat_indices(self, flat: ArrayLike, name: str = "flat indices") -> NDArray:
        """Validate ``(M,)`` integer flat indices in ``[0, res³)``; return them as int64."""
        array = as_numeric(flat, name)
        if array.ndim != 1:
            raise ArrayShapeError(f"{name} must be 1-D, got shape {array.shape}")
        if array.size and not np.issubdtype(array.dtype, np.integer):
            raise ArrayShapeError(f"{name} must be integers, got dtype {array.dtype}")
        array = array.astype(np.int64, copy=False)
        if array.size and (array.min() < 0 or array.max() >= self.n_voxels):
            raise IndexOutOfRangeError(
                f"{name} must lie in [0, {self.n_voxels}), "
                f"got range [{int(array.min())}, {int(array.max())}]"
            )
        return array

    def point_to_ijk(self, points: ArrayLike) -> NDArray:
        """``(P, 3)`` points → ``(P, 3)`` int64 voxel coordinates, *not* clipped (may lie
        outside ``[0, res)`` for points outside the grid box)."""
        pts = as_points(points)
        return np.floor((pts - self.lower) / self.pitch).astype(np.int64)

    def point_to_voxel(self, points: ArrayLike) -> NDArray:
        """``(P, 3)`` points → ``(P,)`` int64 flat index of the voxel containing each point,
        ``−1`` for points outside the grid box (voxels are half-open boxes)."""
        ijk = self.point_to_ijk(points)
        res = self.resolution
        inside = ((ijk >= 0) & (ijk < res)).all(axis=1)
        flat = (ijk[:, 0] * res + ijk[:, 1]) * res + ijk[:, 2]
        return np.where(inside, flat, -1)

    # ----------------------------------------------------------------- serialisation
    def to_dict(self) -> dict[str, Any]:
        """JSON-ready ``{"resolution": int, "pitch": float}``."""
        return {"resolution": self.resolution, "pitch": self.pitch}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> VoxelGrid:
        """Inverse of :meth:`to_dict`; raises InputError on missing or invalid fields."""
        if not isinstance(data, dict) or set(data) != {"resolution", "pitch"}:
            raise InputError(f"a grid dict needs exactly 'resolution' and 'pitch', got {data!r}")
        return cls(resolution=data["resolution"], pitch=data["pitch"])


__all__ = ["DEFAULT_PITCH", "DEFAULT_RESOLUTION", "VoxelGrid"]
