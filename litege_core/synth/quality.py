"""Mesh checks for the synthetic shapes: topology, triangle quality, self-intersection.

All functions take ``vertices (V, 3)`` float64 and ``faces (F, 3)`` int64 arrays.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from litege_core.seams import consistently_wound, unique_edges


def euler_characteristic(faces: NDArray) -> int:
    """V − E + F over the vertices referenced by ``faces``."""
    edges, _ = unique_edges(faces)
    return int(len(np.unique(faces)) - len(edges) + len(faces))


def is_closed_manifold(faces: NDArray) -> bool:
    """Every edge has exactly two faces, used once in each direction, and every vertex's
    faces form a single fan (no pinched vertices)."""
    _, counts = unique_edges(faces)
    if np.any(counts != 2):
        return False
    if not consistently_wound(faces):
        return False  # inconsistent orientation
    # Pinched vertices: the link of each vertex must be one cycle. In a closed oriented
    # mesh, follow next-edges around each vertex and compare the cycle length with its degree.
    n = int(faces.max()) + 1
    nxt: dict[tuple[int, int], int] = {}
    for a, b, c in faces.tolist():
        nxt[(a, b)] = c
        nxt[(b, c)] = a
        nxt[(c, a)] = b
    degree = np.bincount(faces.ravel(), minlength=n)
    start: dict[int, int] = {}
    for a, b, _ in faces.tolist():
        start.setdefault(a, b)
    for v, first in start.items():
        w, steps = first, 0
        while True:
            w = nxt[(v, w)]
            steps += 1
            if w == first or steps > degree[v]:
                break
        if steps != degree[v]:
            return False
    return True


def triangle_angles(vertices: NDArray, faces: NDArray) -> NDArray:
    """``(F, 3)`` interior angles in degrees."""
    p = vertices[faces]
    out = np.empty((len(faces), 3))
    for i in range(3):
        u = p[:, (i + 1) % 3] - p[:, i]
        w = p[:, (i + 2) % 3] - p[:, i]
        cos = np.einsum("ij,ij->i", u, w) / np.maximum(
            np.linalg.norm(u, axis=1) * np.linalg.norm(w, axis=1), 1e-300
        )
        out[:, i] = np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))
    return out


def aspect_ratios(vertices: NDArray, faces: NDArray) -> NDArray:
    """``(F,)`` longest edge over shortest altitude, scaled so an equilateral triangle is 1."""
    p = vertices[faces]
    lengths = np.stack([np.linalg.norm(p[:, (i + 1) % 3] - p[:, i], axis=1) for i in range(3)], 1)
    area2 = np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)
    longest = lengths.max(axis=1)
    altitude = area2 / np.maximum(longest, 1e-300)
    return longest / np.maximum(altitude, 1e-300) * (np.sqrt(3.0) / 2.0)


def mesh_report(vertices: NDArray, faces: NDArray) -> dict[str, float | int | bool]:
    """Counts, topology and triangle-quality statistics (angles in degrees)."""
    angles = triangle_angles(vertices, faces)
    aspect = aspect_ratios(vertices, faces)
    edges, _ = unique_edges(faces)
    lengths = np.linalg.norm(vertices[edges[:, 0]] - vertices[edges[:, 1]], axis=1)
    return {
        "vertices": len(vertices),
        "faces": len(faces),
        "euler": euler_characteristic(faces),
        "closed_manifold": is_closed_manifold(faces),
        "min_angle": round(float(angles.min()), 2),
        "min_angle_p1": round(float(np.percentile(angles.min(axis=1), 1)), 2),
        "mean_min_angle": round(float(angles.min(axis=1).mean()), 2),
        "aspect_mean": round(float(aspect.mean()), 3),
        "aspect_p99": round(float(np.percentile(aspect, 99)), 3),
        "aspect_max": round(float(aspect.max()), 3),
        "edge_cv": round(float(lengths.std() / lengths.mean()), 3),
    }


def unit_area(vertices: NDArray, faces: NDArray) -> NDArray:
    """Vertices translated to their centroid and scaled to total surface area 1."""
    p = vertices[faces]
    area = 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1).sum()
    return (vertices - vertices.mean(axis=0)) / np.sqrt(area)


def self_intersections(vertices: NDArray, faces: NDArray) -> NDArray:
    """Pairs of faces that intersect without sharing a vertex, ``(K, 2)`` int64.

    Tests every edge against the triangles whose bounding spheres it may reach (found with a
    k-d tree on triangle centroids) with a vectorized segment–triangle test; two triangles in
    general position intersect exactly when an edge of one crosses the other.
    """
    p = vertices[faces]
    centroid = p.mean(axis=1)
    radius = np.linalg.norm(p - centroid[:, None], axis=2).max(axis=1)
    edges, _ = unique_edges(faces)
    a, b = vertices[edges[:, 0]], vertices[edges[:, 1]]
    mid = 0.5 * (a + b)
    half = 0.5 * np.linalg.norm(b - a, axis=1)
    tree = cKDTree(centroid)
    reach = float(half.max() + radius.max())
    candidates = tree.query_ball_point(mid, reach)
    lens = np.fromiter((len(c) for c in candidates), dtype=np.int64, count=len(candidates))
    ei = np.repeat(np.arange(len(edges)), lens)
    fi = np.fromiter((f for c in candidates for f in c), dtype=np.int64, count=int(lens.sum()))
    near = np.linalg.norm(mid[ei] - centroid[fi], axis=1) <= half[ei] + radius[fi] + 1e-12
    ei, fi = ei[near], fi[near]
    tri = faces[fi]
    shares = (tri == edges[ei, 0:1]).any(axis=1) | (tri == edges[ei, 1:2]).any(axis=1)
    ei, fi = ei[~shares], fi[~shares]
    hit = _segment_hits_triangle(a[ei], b[ei], p[fi])
    ei, fi = ei[hit], fi[hit]
    # Report face pairs: each crossing edge belongs to (up to) two faces.
    return np.unique(np.stack([ei, fi], axis=1), axis=0)


def self_intersects(vertices: NDArray, faces: NDArray) -> bool:
    """Whether any two faces without a shared vertex intersect."""
    return len(self_intersections(vertices, faces)) > 0


def _segment_hits_triangle(a: NDArray, b: NDArray, tri: NDArray, eps: float = 1e-12) -> NDArray:
    """Möller–Trumbore, vectorized: does segment ``a→b`` cross triangle ``tri``? ``(N,)``."""
    d = b - a
    e1 = tri[:, 1] - tri[:, 0]
    e2 = tri[:, 2] - tri[:, 0]
    h = np.cross(d, e2)
    det = np.einsum("ij,ij->i", e1, h)
    ok = np.abs(det) > eps
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    s = a - tri[:, 0]
    u = inv * np.einsum("ij,ij->i", s, h)
    q = np.cross(s, e1)
    v = inv * np.einsum("ij,ij->i", d, q)
    t = inv * np.einsum("ij,ij->i", e2, q)
    return ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t >= 0) & (t <= 1)


__all__ = [
    "aspect_ratios",
    "euler_characteristic",
    "is_closed_manifold",
    "mesh_report",
    "self_intersections",
    "self_intersects",
    "triangle_angles",
    "unit_area",
]
