"""A typed ASCII tokenizer (numbers by byte masks and ``np.fromstring``, no Python object per
number) and polygon fan triangulation in trimesh's order, for the text readers."""

from __future__ import annotations

import re

import numpy as np
from numpy.typing import NDArray

from litege_core.errors import FaceIndexError, ShapeFileError

_SPACE = np.zeros(256, dtype=bool)
_SPACE[[9, 10, 11, 12, 13, 32]] = True
_WINDOW = 1 << 20


def line_counts(block: bytes) -> NDArray:
    """How many whitespace-separated tokens each non-empty line of ``block`` holds.

    Lines end at ``\\n``, ``\\r\\n`` or a lone ``\\r``; whitespace is ASCII space, tab,
    ``\\v``, ``\\f`` and the line ends. Works through windows of about
    :data:`_WINDOW` bytes cut at line ends, so its temporary memory is a few times the
    window, plus 8 bytes per line for the result.
    """
    parts = []
    start = 0
    while start < len(block):
        stop = block.find(b"\n", start + _WINDOW) + 1 or len(block)
        parts.append(_window_counts(np.frombuffer(block, np.uint8, stop - start, start)))
        start = stop
    return np.concatenate(parts) if parts else np.zeros(0, dtype=np.int64)


def _window_counts(raw: NDArray) -> NDArray:
    """:func:`line_counts` of one window ``raw`` (uint8) ending at a line end or the end."""
    space = _SPACE[raw]
    starts = ~space
    starts[1:] &= space[:-1]
    del space
    tokens = np.flatnonzero(starts)  # where each token starts
    del starts
    breaks = raw == 10
    lone_cr = raw == 13
    if lone_cr.any():
        lone_cr[:-1] &= raw[1:] != 10
        breaks |= lone_cr
    del lone_cr
    before_break = np.searchsorted(tokens, np.flatnonzero(breaks))  # tokens before each end
    counts = np.diff(before_break, prepend=0, append=tokens.size)
    return counts[counts > 0]


def numbers(block: bytes, expected: int, what: str) -> NDArray:
    """All ``expected`` whitespace-separated numbers of ``block`` as float64 (no Python
    object per number).

    Raises:
        ShapeFileError: a token that is not a number.
    """
    if expected == 0:
        return np.zeros(0)
    try:
        values = np.fromstring(block, dtype=np.float64, sep=" ")
    except ValueError:
        values = None
    if values is None or values.size != expected:
        raise ShapeFileError(f"non-numeric value in {what}")
    return values


def first_columns(values: NDArray, counts: NDArray, width: int) -> NDArray:
    """The first ``width`` values of every line (each line holds ``counts[i] >= width``)."""
    if counts.size and (counts == counts[0]).all():
        return values.reshape(counts.size, int(counts[0]))[:, :width]
    offsets = np.concatenate([[0], np.cumsum(counts)[:-1]])
    return values[offsets[:, None] + np.arange(width)]


def strip_comments(data: bytes) -> bytes:
    """``data`` without ``#`` comments (to the end of their line)."""
    return re.sub(rb"#[^\r\n]*", b"", data) if b"#" in data else data


def lines_starting(data: bytes, prefix: bytes) -> int:
    """Lines of ``data`` that start with ``prefix`` (a byte count, no parsing)."""
    return data.count(b"\n" + prefix) + data.count(b"\r" + prefix) + data.startswith(prefix)


def triangulate(first: NDArray, sizes: NDArray, indices: NDArray, file_format: str) -> NDArray:
    """Triangles ``(T, 3)`` int64 of polygons in trimesh's order (see
    :mod:`litege_core.io`).

    Args:
        first: ``(P,)`` offset of each polygon's first corner in ``indices``.
        sizes: ``(P,)`` corners of each polygon (each ``>= 3``).
        indices: the flat float64 values holding the corners (and possibly other values).
        file_format: for error messages.

    Raises:
        FaceIndexError: a corner that is not an integer.
    """
    return integer_indices(_fan(first, sizes, indices), file_format)


def _fan(first: NDArray, sizes: NDArray, indices: NDArray) -> NDArray:
    if sizes.size and (sizes == 3).all():
        return indices[first[:, None] + np.arange(3)]
    tri = first[sizes == 3]
    quad = first[sizes == 4]
    parts = [indices[tri[:, None] + np.arange(3)]]
    if quad.size:
        corners = indices[quad[:, None] + np.arange(4)]
        parts += [corners[:, [0, 1, 2]], corners[:, [2, 3, 0]]]
    big = sizes > 4
    if big.any():
        fan_first, fan_sizes = first[big], sizes[big]
        n_fan = fan_sizes - 2
        owner = np.repeat(np.arange(fan_first.size), n_fan)
        step = np.arange(owner.size) - np.repeat(np.cumsum(n_fan) - n_fan, n_fan) + 1
        base = fan_first[owner]
        parts.append(
            np.column_stack([indices[base], indices[base + step], indices[base + step + 1]])
        )
    return np.concatenate(parts)


def integer_indices(values: NDArray, file_format: str) -> NDArray:
    """Float64 tokens that must be integer vertex indices → int64."""
    if values.size == 0:
        return values.astype(np.int64)
    low, high = values.min(), values.max()  # NaN fails both comparisons
    integers = values.astype(np.int64) if (low > -(2.0**62) and high < 2.0**62) else None
    if integers is None or not np.array_equal(integers, values):
        raise FaceIndexError(f"{file_format.upper()} file has face indices that are not integers")
    return integers


__all__ = [
    "first_columns",
    "integer_indices",
    "line_counts",
    "lines_starting",
    "numbers",
    "strip_comments",
    "triangulate",
]
