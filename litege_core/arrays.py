"""Small array helpers shared across the core."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray


def frozen(array: ArrayLike, dtype: np.dtype | type | None = None) -> NDArray:
    """A read-only, C-contiguous copy of ``array`` (optionally cast to ``dtype``).

    Always copies, so the caller's own array never becomes read-only by accident.
    """
    out = np.array(array, dtype=dtype, copy=True, order="C")
    out.setflags(write=False)
    return out


DISTINCT_MASK_RATIO = 8
""":func:`distinct_indices` marks a mask when the indices are at least ``1 / ratio`` of its
size, else sorts them."""


def distinct_indices(indices: ArrayLike, size: int) -> NDArray:
    """The distinct values of ``indices`` (ints in ``[0, size)``, any shape), ascending, as a
    ``(D,)`` int64 array: what ``numpy.unique`` gives (:func:`distinct_indices_reference`),
    without its hash table (~15x slower on a few thousand indices): marked in a ``(size,)``
    mask, or sorted where the indices are few against ``size``."""
    indices = np.asarray(indices, dtype=np.int64).reshape(-1)
    if indices.size * DISTINCT_MASK_RATIO < size:
        ordered = np.sort(indices)
        distinct = np.ones(ordered.size, dtype=bool)
        np.not_equal(ordered[1:], ordered[:-1], out=distinct[1:])
        return ordered[distinct]
    mask = np.zeros(size, dtype=bool)
    mask[indices] = True
    return np.flatnonzero(mask).astype(np.int64, copy=False)


def distinct_indices_reference(indices: ArrayLike, size: int) -> NDArray:
    """:func:`distinct_indices` by ``numpy.unique`` (the slow reference; ``size`` unused)."""
    return np.unique(np.asarray(indices, dtype=np.int64))


__all__ = [
    "distinct_indices",
    "distinct_indices_reference",
    "frozen",
]
