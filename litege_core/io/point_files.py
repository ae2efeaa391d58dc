"""Point-cloud files: NPY (header checked before any array exists, no pickle) and XYZ."""

from __future__ import annotations

import io
import math

import numpy as np
from numpy.typing import NDArray

from litege_core.errors import ShapeFileError, ShapeTooLargeError
from litege_core.io.limits import MAX_HEADER_BYTES, check_counts
from litege_core.io.tokens import first_columns, line_counts, numbers, strip_comments
from litege_core.validate import ShapeLimits


def read_npy(data: bytes, limits: ShapeLimits) -> NDArray:
    """An ``.npy`` array, header first: the declared dtype, shape and byte length are checked
    before any array exists; the array then views the bytes (no copy)."""
    from numpy.lib import format as npy_format

    stream = io.BytesIO(data)
    try:
        version = npy_format.read_magic(stream)
        if version == (1, 0):
            shape, fortran, dtype = npy_format.read_array_header_1_0(stream, MAX_HEADER_BYTES)
        elif version == (2, 0):
            shape, fortran, dtype = npy_format.read_array_header_2_0(stream, MAX_HEADER_BYTES)
        else:
            raise ValueError(f"unsupported .npy format version {version}")
    except (ValueError, OSError, EOFError, SyntaxError, TypeError) as exc:
        raise ShapeFileError(f"not a readable .npy array (truncated?): {exc}") from exc
    if dtype.hasobject:
        raise ShapeFileError("a .npy point cloud must not hold Python objects (pickle refused)")
    if any(not isinstance(n, int) or n < 0 for n in shape):
        raise ShapeFileError(f".npy header declares an invalid shape {shape}")
    count = math.prod(shape)
    if count > 3 * limits.max_vertices:
        raise ShapeTooLargeError(
            f".npy header declares an array of shape {shape}, more than the limit of "
            f"{limits.max_vertices} points",
            n_vertices=count // 3,
            limit=limits.max_vertices,
        )
    offset = stream.tell()
    needed = count * dtype.itemsize
    if len(data) - offset != needed:
        raise ShapeFileError(
            f".npy header declares {needed} bytes of data, the file holds {len(data) - offset}"
        )
    array = np.frombuffer(data, dtype=dtype, count=count, offset=offset)
    return array.reshape(shape, order="F" if fortran else "C")


def read_xyz(data: bytes, limits: ShapeLimits) -> NDArray:
    """An ``.xyz`` cloud: the first three numbers of every non-empty line (``#`` comments)."""
    text = strip_comments(data)
    counts = line_counts(text)
    check_counts("xyz", limits, int(counts.size), what="has")
    if counts.size == 0:
        return np.zeros((0, 3))
    if counts.min() < 3:
        raise ShapeFileError("every .xyz line needs at least three numbers (x y z)")
    values = numbers(text, int(counts.sum()), ".xyz file")
    return first_columns(values, counts, 3)


__all__ = [
    "read_npy",
    "read_xyz",
]
