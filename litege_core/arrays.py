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


__all__ = [
    "frozen",
]
