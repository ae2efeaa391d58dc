"""Binary voxel occupancy of meshes and point clouds (reference spec §2.2).

Occupancy is used only to choose the informative voxels over a training set; inference never
needs it. The authors OR two Kaolin tests: "the voxel centre is inside the watertight mesh"
(``check_sign``) and "the voxel intersects the surface" (``trianglemeshes_to_voxelgrids``).
Here:

* :func:`mesh_surface_voxels` — voxels whose closed box intersects a triangle, by the exact
  separating-axis test (Akenine-Möller: 3 box axes, the triangle normal, 9 edge crosses),
  vectorized over (triangle, candidate voxel) pairs taken from each triangle's bounding box.
* :func:`mesh_inside` — voxel centres inside the mesh by **ray parity along grid columns** in
  the three axis directions. Each triangle is rasterized onto the columns its projection
  covers (vectorized over all (triangle, column) pairs) with a top-left fill rule and edge
  functions evaluated in a canonical endpoint order, so a column through a shared edge or
  vertex counts exactly one crossing and a column grazing a silhouette counts zero or two.
  Each crossing toggles the parity of the voxels above it (``bincount`` + ``cumsum``).
  Robustness to **non-watertight** meshes: a column with an odd total number of crossings
  passes through a hole and abstains; a voxel is inside when more axes vote inside than
  outside among those that do not abstain.
* :func:`mesh_occupancy` — ``mesh_inside | mesh_surface_voxels``.
* :func:`point_cloud_occupancy` — voxels containing a point, optionally dilated.

Slow references beside them (used by the tests): :func:`winding_number_reference` (generalized
winding number by brute-force solid angles), :func:`surface_voxels_reference` (per voxel,
per triangle polygon clipping in Python loops) and :func:`point_cloud_occupancy_reference`.

Timing (``scripts/bench_udf.py --occupancy``, shared 2-core CPU): 0.16 s median for a
5,120-face ellipsoid on the 121³ grid (inside ≈ 0.06–0.09 s, surface ≈ 0.04–0.07 s). Large
triangles cost O(L²) candidates, not O(L³): the plane test prunes each bounding-box column.
"""

from __future__ import annotations

import itertools

import numpy as np
from numpy.typing import ArrayLike, NDArray

from litege_core.descriptor._arrays import as_faces, as_points
from litege_core.descriptor.grid import VoxelGrid
from litege_core.errors import InputError

#: Max (triangle, voxel-or-column) candidate pairs materialised at once.
_CANDIDATE_BUDGET = 1 << 20
#: Bounding-box slack in voxel units, far above float64 rounding, far below one voxel.
_SLACK = 1e-7


def _mesh_arrays(vertices: ArrayLike, faces: ArrayLike) -> tuple[NDArray, NDArray]:
    verts = as_points(vertices, "vertices")
    return verts, as_faces(faces, verts.shape[0])


def _expand_boxes(lo: NDArray, hi: NDArray) -> tuple[NDArray, NDArray]:
    """Enumerate integer boxes ``[lo, hi]`` (inclusive, ``(T, D)``) without Python loops.

    Returns ``(owner (C,) int64 row of lo/hi, coords (C, D) int64)``; empty boxes are skipped.
    """
    extent = np.maximum(hi - lo + 1, 0)
    counts = extent.prod(axis=1)
    owner = np.repeat(np.arange(lo.shape[0]), counts)
    starts = np.cumsum(counts) - counts
    local = np.arange(owner.shape[0], dtype=np.int64) - starts[owner]
    coords = np.empty((owner.shape[0], lo.shape[1]), dtype=np.int64)
    for axis in range(lo.shape[1] - 1, -1, -1):  # D ≤ 3 axes, not a data loop
        local, coords[:, axis] = np.divmod(local, extent[owner, axis])
        coords[:, axis] += lo[owner, axis]
    return owner, coords


def _chunks_by_budget(counts: NDArray, budget: int) -> list[tuple[int, int]]:
    """Split ``range(len(counts))`` into consecutive runs whose count sums stay ≤ budget
    (a single row larger than the budget gets a run of its own)."""
    bounds = [0]
    cumulative = np.cumsum(counts)
    n = counts.shape[0]
    while bounds[-1] < n:
        start = bounds[-1]
        base = cumulative[start - 1] if start else 0
        stop = int(np.searchsorted(cumulative, base + budget, side="right"))
        bounds.append(max(stop, start + 1))
    return list(itertools.pairwise(bounds))


# --------------------------------------------------------------------------- inside test
def _edge_function(ax: NDArray, ay: NDArray, bx: NDArray, by: NDArray, px: NDArray, py: NDArray):
    """Orientation of p against the directed edge a→b, evaluated from the lexicographically
    smaller endpoint so the two triangles sharing an edge get exactly opposite values."""
    swap = (bx < ax) | ((bx == ax) & (by < ay))
    sx, sy = np.where(swap, bx, ax), np.where(swap, by, ay)
    ex, ey = np.where(swap, ax, bx), np.where(swap, ay, by)
    value = (ex - sx) * (py - sy) - (ey - sy) * (px - sx)
    return np.where(swap, -value, value)


def _column_parity(
    verts: NDArray, faces: NDArray, grid: VoxelGrid, axis: int
) -> tuple[NDArray, NDArray]:
    """Ray parity along grid columns parallel to ``axis``.

    Returns ``(below, total)``: ``below (res, res, res) bool`` in ``(i, j, k)`` layout, the
    parity of surface crossings below each voxel centre along ``axis``, and ``total
    (res, res, res) bool``, the parity of all crossings of the voxel's column (odd = hole).
    """
    res = grid.resolution
    u_axis, v_axis = [a for a in range(3) if a != axis]
    corners = verts[faces]  # (F, 3, 3)
    pu, pv, pd = corners[:, :, u_axis], corners[:, :, v_axis], corners[:, :, axis]
    area2 = (pu[:, 1] - pu[:, 0]) * (pv[:, 2] - pv[:, 0]) - (pv[:, 1] - pv[:, 0]) * (
        pu[:, 2] - pu[:, 0]
    )
    keep = area2 != 0.0  # triangles seen edge-on by these rays never count
    pu, pv, pd, area2 = pu[keep], pv[keep], pd[keep], area2[keep]
    clockwise = area2 < 0
    order = np.where(clockwise[:, None], [0, 2, 1], [0, 1, 2])  # make every triangle CCW
    pu, pv, pd = (np.take_along_axis(a, order, axis=1) for a in (pu, pv, pd))
    area2 = np.abs(area2)

    axis_c = grid.axis_centers()
    scale = 1.0 / grid.pitch
    lo = np.stack([pu.min(1), pv.min(1)], axis=1)
    hi = np.stack([pu.max(1), pv.max(1)], axis=1)
    lo = np.clip(np.ceil((lo - grid.first_center) * scale - _SLACK), 0, res).astype(np.int64)
    hi = np.clip(np.floor((hi - grid.first_center) * scale + _SLACK), -1, res - 1)
    hi = hi.astype(np.int64)
    counts = np.maximum(hi - lo + 1, 0).prod(axis=1)

    toggles = np.zeros(res * res * (res + 1), dtype=np.int64)
    for start, stop in _chunks_by_budget(counts, _CANDIDATE_BUDGET):
        owner, col = _expand_boxes(lo[start:stop], hi[start:stop])
        owner += start
        qx, qy = axis_c[col[:, 0]], axis_c[col[:, 1]]
        tu, tv, td = pu[owner], pv[owner], pd[owner]
        inside = np.ones(owner.shape[0], dtype=bool)
        weights = []
        for e in range(3):  # edge opposite corner e: corner (e+1) → corner (e+2)
            a, b = (e + 1) % 3, (e + 2) % 3
            value = _edge_function(tu[:, a], tv[:, a], tu[:, b], tv[:, b], qx, qy)
            dx, dy = tu[:, b] - tu[:, a], tv[:, b] - tv[:, a]
            top_left = (dy < 0) | ((dy == 0) & (dx < 0))
            inside &= (value > 0) | ((value == 0) & top_left)
            weights.append(value)
        if not inside.any():
            continue
        w = np.stack(weights, axis=1)[inside] / area2[owner[inside], None]
        depth = (w * td[inside]).sum(axis=1)
        # first voxel whose centre lies above the crossing
        k0 = np.floor((depth - grid.first_center) * scale).astype(np.int64) + 1
        k0 = np.clip(k0, 0, res)
        col = col[inside]
        toggles += np.bincount(
            (col[:, 0] * res + col[:, 1]) * (res + 1) + k0, minlength=toggles.shape[0]
        )
    parity = (
        np.cumsum((toggles & 1).astype(np.uint8).reshape(res, res, res + 1), axis=2, dtype=np.uint8)
        & 1
    )
    below = parity[:, :, :res].astype(bool)
    total = np.broadcast_to(parity[:, :, res:].astype(bool), below.shape)
    # layout is (u, v, depth) with u < v; put depth back at position ``axis``
    return np.moveaxis(below, 2, axis), np.moveaxis(total, 2, axis)


def mesh_inside(vertices: ArrayLike, faces: ArrayLike, grid: VoxelGrid) -> NDArray:
    """Voxel centres inside a (possibly non-watertight) triangle mesh.

    Ray parity along the grid columns in x, y and z with a vote (see the module docstring):
    on a watertight mesh every axis agrees and the result equals the winding-number test up to
    centres lying exactly on the surface.

    Args:
        vertices: ``(N, 3)`` canonical-frame coordinates.
        faces: ``(F, 3)`` triangle indices.
        grid: the voxel grid.

    Returns:
        ``(res³,)`` bool, flat x-major.
    """
    verts, tris = _mesh_arrays(vertices, faces)
    votes_in = np.zeros(grid.shape, dtype=np.int8)
    votes_out = np.zeros(grid.shape, dtype=np.int8)
    for axis in range(3):
        below, odd_column = _column_parity(verts, tris, grid, axis)
        votes_in += below & ~odd_column
        votes_out += ~below & ~odd_column
    return (votes_in > votes_out).reshape(-1)


# --------------------------------------------------------------------------- surface test
def _triangle_box_overlap(tri: NDArray, half: float) -> NDArray:
    """Closed separating-axis test of triangles against axis-aligned cubes at the origin.

    Args:
        tri: ``(C, 3, 3)`` triangle corners relative to each cube's centre.
        half: half edge of the cubes.

    Returns:
        ``(C,)`` bool, True where triangle and closed cube intersect (touching counts).
    """
    hit = (tri.min(axis=1) <= half).all(axis=1) & (tri.max(axis=1) >= -half).all(axis=1)
    edges = tri[:, [1, 2, 0]] - tri  # (C, 3 edges, 3)
    normal = np.cross(edges[:, 0], edges[:, 1])
    dist = np.einsum("cd,cd->c", normal, tri[:, 0])
    hit &= np.abs(dist) <= half * np.abs(normal).sum(axis=1)
    unit = np.eye(3)
    for a in range(3):  # 3 box axes × 3 edges = 9 cross axes
        axes = np.cross(unit[a][None, None, :], edges)  # (C, 3, 3)
        proj = np.einsum("cvd,ced->cve", tri, axes)  # (C, vertex, edge)
        radius = half * np.abs(axes).sum(axis=2)  # (C, edge)
        hit &= ((proj.min(axis=1) <= radius) & (proj.max(axis=1) >= -radius)).all(axis=1)
    return hit


def _surface_candidates(
    corners: NDArray, lo: NDArray, hi: NDArray, grid: VoxelGrid
) -> tuple[NDArray, NDArray]:
    """Candidate (triangle, voxel) pairs for the exact test: voxels of each triangle's bounding
    box that also pass the plane test ``|n·c − d| ≤ (pitch/2)·‖n‖₁``.

    The plane test is applied while enumerating: along the dominant axis of the normal each
    bounding-box column holds at most 4 candidates, so a large triangle costs O(L²), not O(L³).
    Degenerate (zero-area) triangles keep their whole bounding box.

    Args:
        corners: ``(T, 3, 3)`` triangles; lo, hi: ``(T, 3)`` inclusive voxel bounding boxes.

    Returns:
        ``(owner (C,) int64 row of corners, ijk (C, 3) int64)``.
    """
    normal = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    dominant = np.argmax(np.abs(normal), axis=1)
    flat = ~(np.abs(normal).max(axis=1) > 0)
    owners, coords = [], []
    rows = np.flatnonzero(flat)
    if rows.size:
        owner, ijk = _expand_boxes(lo[rows], hi[rows])
        owners.append(rows[owner])
        coords.append(ijk)
    axis_c = grid.axis_centers()
    radius_scale = 0.5 * grid.pitch
    for axis in range(3):
        rows = np.flatnonzero((dominant == axis) & ~flat)
        if not rows.size:
            continue
        u, v = [a for a in range(3) if a != axis]
        col_owner, uv = _expand_boxes(lo[rows][:, [u, v]], hi[rows][:, [u, v]])
        tri = rows[col_owner]
        n = normal[tri]
        offset = np.einsum("cd,cd->c", n, corners[tri, 0])
        radius = radius_scale * np.abs(n).sum(axis=1)
        base = offset - n[:, u] * axis_c[uv[:, 0]] - n[:, v] * axis_c[uv[:, 1]]
        ends = np.stack([(base - radius) / n[:, axis], (base + radius) / n[:, axis]], axis=1)
        k_lo = np.ceil((ends.min(axis=1) - grid.first_center) / grid.pitch - _SLACK)
        k_hi = np.floor((ends.max(axis=1) - grid.first_center) / grid.pitch + _SLACK)
        k_lo = np.maximum(k_lo, lo[tri, axis]).astype(np.int64)
        k_hi = np.minimum(k_hi, hi[tri, axis]).astype(np.int64)
        run_owner, k = _expand_boxes(k_lo[:, None], k_hi[:, None])
        ijk = np.empty((run_owner.shape[0], 3), dtype=np.int64)
        ijk[:, axis] = k[:, 0]
        ijk[:, u] = uv[run_owner, 0]
        ijk[:, v] = uv[run_owner, 1]
        owners.append(tri[run_owner])
        coords.append(ijk)
    if not owners:
        return np.empty(0, dtype=np.int64), np.empty((0, 3), dtype=np.int64)
    return np.concatenate(owners), np.concatenate(coords)


def mesh_surface_voxels(vertices: ArrayLike, faces: ArrayLike, grid: VoxelGrid) -> NDArray:
    """Voxels whose closed box intersects the mesh surface (exact triangle–box test).

    Args:
        vertices: ``(N, 3)`` canonical-frame coordinates.
        faces: ``(F, 3)`` triangle indices.
        grid: the voxel grid (parts of the surface outside it are ignored).

    Returns:
        ``(res³,)`` bool, flat x-major.
    """
    verts, tris = _mesh_arrays(vertices, faces)
    res, scale = grid.resolution, 1.0 / grid.pitch
    corners = verts[tris]
    lo = np.floor((corners.min(axis=1) - grid.lower) * scale - _SLACK)
    hi = np.floor((corners.max(axis=1) - grid.lower) * scale + _SLACK)
    lo = np.clip(lo, 0, res).astype(np.int64)
    hi = np.clip(hi, -1, res - 1).astype(np.int64)
    # budget on the bounding-box columns (the plane test keeps ≤ 4 voxels per column)
    extent = np.maximum(hi - lo + 1, 0)
    counts = extent.prod(axis=1) // np.maximum(extent.max(axis=1), 1)
    occupied = np.zeros(grid.n_voxels, dtype=bool)
    axis_c = grid.axis_centers()
    sub = _CANDIDATE_BUDGET // 4
    for start, stop in _chunks_by_budget(counts, _CANDIDATE_BUDGET // 4):
        owner, ijk = _surface_candidates(corners[start:stop], lo[start:stop], hi[start:stop], grid)
        owner += start
        for s in range(0, owner.shape[0], sub):
            o, v = owner[s : s + sub], ijk[s : s + sub]
            rel = corners[o] - axis_c[v][:, None, :]
            hit = _triangle_box_overlap(rel, 0.5 * grid.pitch)
            v = v[hit]
            occupied[(v[:, 0] * res + v[:, 1]) * res + v[:, 2]] = True
    return occupied


def mesh_occupancy(vertices: ArrayLike, faces: ArrayLike, grid: VoxelGrid) -> NDArray:
    """Inside-or-surface occupancy of a mesh: ``mesh_inside | mesh_surface_voxels``.

    Args:
        vertices: ``(N, 3)`` canonical-frame coordinates.
        faces: ``(F, 3)`` triangle indices (need not be watertight).
        grid: the voxel grid.

    Returns:
        ``(res³,)`` bool, flat x-major.
    """
    return mesh_inside(vertices, faces, grid) | mesh_surface_voxels(vertices, faces, grid)


def point_cloud_occupancy(points: ArrayLike, grid: VoxelGrid, dilation: int = 0) -> NDArray:
    """Voxels containing at least one point, optionally dilated.

    Args:
        points: ``(P, 3)`` canonical-frame coordinates; points outside the grid are ignored.
        grid: the voxel grid.
        dilation: Chebyshev radius in voxels; each occupied voxel also marks the
            ``(2·dilation + 1)³`` cube around it (clipped to the grid).

    Returns:
        ``(res³,)`` bool, flat x-major.
    """
    if isinstance(dilation, bool) or not isinstance(dilation, (int, np.integer)) or dilation < 0:
        raise InputError(f"dilation must be a non-negative integer, got {dilation!r}")
    flat = grid.point_to_voxel(points)
    occupied = np.zeros(grid.n_voxels, dtype=bool)
    occupied[flat[flat >= 0]] = True
    if dilation:
        from scipy import ndimage  # imported on first use (CLI start-up)

        dense = occupied.reshape(grid.shape).view(np.uint8)
        dense = ndimage.maximum_filter(dense, size=2 * int(dilation) + 1, mode="constant", cval=0)
        occupied = dense.reshape(-1).astype(bool)
    return occupied


# --------------------------------------------------------------------------- references
def winding_number_reference(
    vertices: ArrayLike, faces: ArrayLike, queries: ArrayLike, chunk: int = 4096
) -> NDArray:
    """Generalized winding number of a mesh at query points (brute force, O(Q·F)).

    Solid angle per triangle by Van Oosterom & Strackee; ``w ≈ 1`` inside a closed
    outward-oriented mesh, ``≈ 0`` outside. Slow reference for :func:`mesh_inside`.

    Args:
        vertices: ``(N, 3)``; faces: ``(F, 3)``; queries: ``(Q, 3)``.

    Returns:
        ``(Q,)`` float64 winding numbers.
    """
    verts, tris = _mesh_arrays(vertices, faces)
    q = as_points(queries, "queries")
    corners = verts[tris]
    out = np.empty(q.shape[0])
    for s in range(0, q.shape[0], chunk):
        rel = corners[None, :, :, :] - q[s : s + chunk, None, None, :]  # (Q, F, 3, 3)
        a, b, c = rel[:, :, 0], rel[:, :, 1], rel[:, :, 2]
        la, lb, lc = (np.linalg.norm(x, axis=-1) for x in (a, b, c))
        numerator = np.einsum("qfd,qfd->qf", a, np.cross(b, c))
        denominator = (
            la * lb * lc
            + np.einsum("qfd,qfd->qf", a, b) * lc
            + np.einsum("qfd,qfd->qf", a, c) * lb
            + np.einsum("qfd,qfd->qf", b, c) * la
        )
        out[s : s + chunk] = 2.0 * np.arctan2(numerator, denominator).sum(axis=1) / (4 * np.pi)
    return out


def _clip_nonempty(polygon: list[NDArray], lo: NDArray, hi: NDArray) -> bool:
    """Sutherland–Hodgman clip of a convex polygon by a closed box; True if anything is left."""
    for axis in range(3):
        for sign, bound in ((1.0, lo[axis]), (-1.0, hi[axis])):
            clipped: list[NDArray] = []
            n = len(polygon)
            for idx in range(n):
                s, e = polygon[idx - 1], polygon[idx]
                fs, fe = sign * (s[axis] - bound), sign * (e[axis] - bound)
                if fe >= 0:
                    if fs < 0:
                        clipped.append(s + (fs / (fs - fe)) * (e - s))
                    clipped.append(e)
                elif fs >= 0:
                    clipped.append(s + (fs / (fs - fe)) * (e - s))
            polygon = clipped
            if not polygon:
                return False
    return True


def surface_voxels_reference(vertices: ArrayLike, faces: ArrayLike, grid: VoxelGrid) -> NDArray:
    """Slow reference of :func:`mesh_surface_voxels`: for every voxel and every triangle, clip
    the triangle by the closed voxel box in Python loops. Only for tiny grids."""
    verts, tris = _mesh_arrays(vertices, faces)
    half = 0.5 * grid.pitch
    centers = grid.centers()
    out = np.zeros(grid.n_voxels, dtype=bool)
    for flat, c in enumerate(centers):
        lo, hi = c - half, c + half
        for tri in tris:
            if _clip_nonempty([verts[t] for t in tri], lo, hi):
                out[flat] = True
                break
    return out


def point_cloud_occupancy_reference(
    points: ArrayLike, grid: VoxelGrid, dilation: int = 0
) -> NDArray:
    """Slow reference of :func:`point_cloud_occupancy`: per voxel, does any point lie in the
    half-open box grown by ``dilation`` voxels on each side? Only for tiny grids."""
    pts = as_points(points)
    half = (0.5 + dilation) * grid.pitch
    out = np.zeros(grid.n_voxels, dtype=bool)
    inside_grid = ((pts >= grid.lower) & (pts < grid.upper)).all(axis=1)
    pts = pts[inside_grid]
    for flat, c in enumerate(grid.centers()):
        out[flat] = bool((((pts >= c - half) & (pts < c + half)).all(axis=1)).any())
    return out


__all__ = [
    "mesh_inside",
    "mesh_occupancy",
    "mesh_surface_voxels",
    "point_cloud_occupancy",
    "point_cloud_occupancy_reference",
    "surface_voxels_reference",
    "winding_number_reference",
]
