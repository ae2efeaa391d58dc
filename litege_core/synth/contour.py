"""Iso-surface extraction by marching tetrahedra, and cutting a mesh at the plane ``x = 0``.

Marching tetrahedra on the Kuhn (6-tetrahedra, shared main diagonal) split of each grid cube
is consistent across cube faces, so the output is a closed 2-manifold for any field with no
sample exactly at the iso-value. Its triangles are poor (slivers); the remesher fixes that.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

from litege_core.errors import ComputationError

# The six Kuhn tetrahedra of the unit cube: walk from corner 000 to 111 along axes in the
# order of each permutation. Corners are (dx, dy, dz) offsets.
_PERMUTATIONS = ((0, 1, 2), (0, 2, 1), (1, 0, 2), (1, 2, 0), (2, 0, 1), (2, 1, 0))


def _kuhn_tetrahedra() -> list[list[tuple[int, int, int]]]:
    tets = []
    for perm in _PERMUTATIONS:
        corner = [0, 0, 0]
        path = [(0, 0, 0)]
        for axis in perm:
            corner[axis] = 1
            path.append((corner[0], corner[1], corner[2]))
        tets.append(path)
    return tets


def marching_tetrahedra(
    field: Callable[[NDArray], NDArray],
    lower: NDArray,
    upper: NDArray,
    spacing: float,
) -> tuple[NDArray, NDArray]:
    """Extract the zero level set of ``field`` on a regular grid.

    Args:
        field: maps ``(N, 3)`` points to ``(N,)`` values, negative inside.
        lower, upper: ``(3,)`` corners of the sampled box (the surface must lie inside).
        spacing: grid step in the field's units.

    Returns:
        ``vertices (V, 3)`` float64 and ``faces (F, 3)`` int64, outward oriented
        (normals point towards increasing ``field``).
    """
    axes = [np.arange(lo, hi + spacing, spacing) for lo, hi in zip(lower, upper, strict=True)]
    shape = tuple(len(a) for a in axes)
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    values = field(grid)
    values = np.where(values == 0.0, 1e-12, values)
    cube = values.reshape(shape)
    faces_min = min(cube[[0, -1]].min(), cube[:, [0, -1]].min(), cube[:, :, [0, -1]].min())
    if faces_min <= 0:
        raise ComputationError("iso-surface touches the sampling box; enlarge the bounds")
    index = np.arange(grid.shape[0]).reshape(shape)
    base = index[:-1, :-1, :-1].ravel()
    strides = np.array([shape[1] * shape[2], shape[2], 1])
    tets = np.concatenate(
        [
            np.stack([base + int(np.dot(c, strides)) for c in tet], axis=1)
            for tet in _kuhn_tetrahedra()
        ]
    )
    inside = values[tets] < 0.0
    count = inside.sum(axis=1)
    mixed = (count > 0) & (count < 4)
    tets, inside, count = tets[mixed], inside[mixed], count[mixed]

    edge_pairs: list[NDArray] = []  # (T, 3, 2) node pairs per triangle corner
    # One corner alone on its side: a single triangle around it.
    lone_in = count == 1
    lone_out = count == 3
    for mask, lone_is_inside in ((lone_in, True), (lone_out, False)):
        t, ins = tets[mask], inside[mask]
        lone_col = np.argmax(ins if lone_is_inside else ~ins, axis=1)
        order = np.argsort(np.arange(4)[None, :] == lone_col[:, None], axis=1, kind="stable")
        others = np.take_along_axis(t, order[:, :3], axis=1)
        lone = t[np.arange(len(t)), lone_col]
        edge_pairs.append(np.stack([np.stack([lone, others[:, j]], 1) for j in range(3)], 1))
    # Two and two: a quad, split in two triangles.
    t, ins = tets[count == 2], inside[count == 2]
    order_in = np.argsort(~ins, axis=1, kind="stable")
    nodes = np.take_along_axis(t, order_in, axis=1)  # two inside, then two outside
    i0, i1, o0, o1 = nodes.T
    e00, e01, e11, e10 = (np.stack(p, 1) for p in ((i0, o0), (i0, o1), (i1, o1), (i1, o0)))
    edge_pairs.append(np.stack([e00, e01, e11], 1))
    edge_pairs.append(np.stack([e00, e11, e10], 1))
    pairs = np.concatenate(edge_pairs)  # (F, 3, 2)

    lo = np.minimum(pairs[..., 0], pairs[..., 1])
    hi = np.maximum(pairs[..., 0], pairs[..., 1])
    keys = lo.astype(np.int64) * grid.shape[0] + hi
    unique_keys, faces = np.unique(keys.ravel(), return_inverse=True)
    faces = faces.reshape(-1, 3).astype(np.int64)
    u, v = unique_keys // grid.shape[0], unique_keys % grid.shape[0]
    fu, fv = values[u], values[v]
    t_cut = fu / (fu - fv)
    vertices = grid[u] + t_cut[:, None] * (grid[v] - grid[u])

    # Orient: the normal must point from the inside nodes towards the outside nodes.
    inside_node = np.where(values[pairs[:, 0, 0]] < 0, pairs[:, 0, 0], pairs[:, 0, 1])
    outside_node = np.where(values[pairs[:, 0, 0]] < 0, pairs[:, 0, 1], pairs[:, 0, 0])
    tri = vertices[faces]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    flip = np.einsum("ij,ij->i", normal, grid[outside_node] - grid[inside_node]) < 0
    faces[flip] = faces[flip][:, ::-1]
    return vertices, faces


def cut_positive_half(vertices: NDArray, faces: NDArray) -> tuple[NDArray, NDArray, NDArray]:
    """Keep the part of a closed mesh with ``x ≥ 0``; the cut lies exactly on ``x = 0``.

    Args:
        vertices: ``(V, 3)``; no vertex may lie exactly on the plane.
        faces: ``(F, 3)`` oriented triangles.

    Returns:
        ``vertices (V', 3)``, ``faces (F', 3)`` (unused vertices removed) and a boolean
        ``(V',)`` mask of the vertices created on the cut (``x == 0``).
    """
    x = vertices[:, 0]
    if np.any(x == 0.0):
        raise ComputationError("a vertex lies exactly on the cutting plane")
    positive = x > 0.0
    n = len(vertices)
    cut_keys: dict[int, int] = {}
    new_points: list[NDArray] = []

    def cut(a: int, b: int) -> int:
        key = min(a, b) * n + max(a, b)
        if key not in cut_keys:
            t = x[a] / (x[a] - x[b])
            p = vertices[a] + t * (vertices[b] - vertices[a])
            p[0] = 0.0
            cut_keys[key] = n + len(new_points)
            new_points.append(p)
        return cut_keys[key]

    out: list[tuple[int, int, int]] = []
    pos_count = positive[faces].sum(axis=1)
    out.extend(map(tuple, faces[pos_count == 3].tolist()))
    for face in faces[(pos_count == 1) | (pos_count == 2)].tolist():
        flags = [bool(positive[v]) for v in face]
        if sum(flags) == 1:
            r = flags.index(True)
            a, b, c = face[r], face[(r + 1) % 3], face[(r + 2) % 3]
            out.append((a, cut(a, b), cut(c, a)))
        else:
            r = flags.index(False)
            c, a, b = face[r], face[(r + 1) % 3], face[(r + 2) % 3]
            cb, ca = cut(b, c), cut(c, a)
            out.append((a, b, cb))
            out.append((a, cb, ca))
    all_points = np.concatenate([vertices, np.array(new_points).reshape(-1, 3)])
    new_faces = np.array(out, dtype=np.int64)
    used = np.unique(new_faces)
    remap = -np.ones(len(all_points), dtype=np.int64)
    remap[used] = np.arange(len(used))
    on_cut = np.zeros(len(all_points), dtype=bool)
    on_cut[n:] = True
    return all_points[used], remap[new_faces], on_cut[used]


__all__ = [
    "cut_positive_half",
    "marching_tetrahedra",
]
