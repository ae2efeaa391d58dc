"""Mesh operations for turning real (rigged, scanned, user) meshes into training shapes.

Welding by position, keeping the largest connected component, isotropic remeshing to a
vertex budget (pymeshlab), a closed-manifold check good enough for exact (MMP) geodesics, unit
area normalization and a smooth non-rigid stretch. Every function is deterministic; the random
ones take a :class:`numpy.random.Generator`.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray
from scipy import sparse
from scipy.sparse.csgraph import connected_components

from litege_core.errors import ComputationError, DegenerateShapeError, MissingDependencyError
from litege_core.seams import half_edges


class Welded(NamedTuple):
    """A welded mesh: ``vertices (V', 3)``, ``faces (F', 3)`` and ``representative (V',)``, the
    raw vertex each welded vertex was taken from (to carry per-vertex attributes)."""

    vertices: NDArray
    faces: NDArray
    representative: NDArray


def triangle_area_total(vertices: NDArray, faces: NDArray) -> float:
    """Total surface area (units²) of a triangle mesh."""
    corners = vertices[faces]
    cross = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    return float(0.5 * np.linalg.norm(cross, axis=1).sum())


def weld(vertices: NDArray, faces: NDArray, tolerance: float = 0.0) -> Welded:
    """Merge vertices at the same position, drop faces that become degenerate and duplicated
    faces.

    Args:
        vertices: ``(V, 3)`` raw positions (glTF files split vertices at UV/material seams,
            with bit-identical copies).
        faces: ``(F, 3)`` triangles.
        tolerance: 0 merges exactly equal positions only; otherwise positions are snapped to a
            grid of ``tolerance`` × bounding-box diagonal first (near-coincident copies).
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    if tolerance > 0:
        diagonal = float(np.linalg.norm(np.ptp(vertices, axis=0))) or 1.0
        keys = np.round(vertices / (tolerance * diagonal)).astype(np.int64)
    else:
        keys = vertices
    _, first, inverse = np.unique(keys, axis=0, return_index=True, return_inverse=True)
    inverse = inverse.reshape(-1)
    new_faces = inverse[np.asarray(faces, dtype=np.int64)]
    ok = (
        (new_faces[:, 0] != new_faces[:, 1])
        & (new_faces[:, 1] != new_faces[:, 2])
        & (new_faces[:, 2] != new_faces[:, 0])
    )
    new_faces = new_faces[ok]
    _, unique_rows = np.unique(np.sort(new_faces, axis=1), axis=0, return_index=True)
    new_faces = new_faces[np.sort(unique_rows)]
    return Welded(vertices[first], new_faces, first.astype(np.int64))


def largest_component(faces: NDArray, n_vertices: int) -> tuple[NDArray, NDArray]:
    """The connected component (by shared vertices) with the most faces.

    Returns:
        ``(kept_vertices (V',), faces (F', 3))``: the old indices of the kept vertices (sorted)
        and the component's faces re-indexed into them.
    """
    faces = np.asarray(faces, dtype=np.int64)
    rows = np.repeat(np.arange(faces.shape[0]), 3)
    incidence = sparse.coo_matrix(
        (np.ones(rows.size), (rows, faces.ravel())), shape=(faces.shape[0], n_vertices)
    ).tocsr()
    _, labels = connected_components(incidence.T @ incidence, directed=False)
    face_label = labels[faces[:, 0]]
    best = np.bincount(face_label).argmax()
    kept_faces = faces[face_label == best]
    kept = np.unique(kept_faces)
    remap = np.full(n_vertices, -1, dtype=np.int64)
    remap[kept] = np.arange(kept.size)
    return kept, remap[kept_faces]


class ManifoldReport(NamedTuple):
    """Topology of a triangle mesh: closed (no boundary edge), manifold (every edge in at most
    two faces, the faces around every vertex one fan, no face repeated), consistently
    oriented, connected components, Euler characteristic and the smallest triangle angle
    (degrees)."""

    closed: bool
    manifold: bool
    oriented: bool
    components: int
    euler: int
    min_angle: float

    @property
    def ok(self) -> bool:
        """Closed, manifold, oriented, one component, no sliver below 1°."""
        return (
            self.closed
            and self.manifold
            and self.oriented
            and self.components == 1
            and self.min_angle > 1.0
        )


def min_angles(vertices: NDArray, faces: NDArray) -> NDArray:
    """``(F,)`` smallest interior angle of each triangle, degrees."""
    corners = vertices[faces]
    angles = []
    for i in range(3):
        a = corners[:, (i + 1) % 3] - corners[:, i]
        b = corners[:, (i + 2) % 3] - corners[:, i]
        cos = np.einsum("ij,ij->i", a, b) / np.maximum(
            np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1), 1e-300
        )
        angles.append(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))
    return np.min(angles, axis=0) if faces.size else np.zeros(0)


def manifold_report(vertices: NDArray, faces: NDArray) -> ManifoldReport:
    """Check the topology of ``faces`` (``(F, 3)``) on ``vertices (V, 3)``."""
    faces = np.asarray(faces, dtype=np.int64)
    half = half_edges(faces)
    undirected = np.sort(half, axis=1)
    _, edge_count = np.unique(undirected, axis=0, return_counts=True)
    _, directed_count = np.unique(half, axis=0, return_counts=True)
    used = np.unique(faces)
    _, comp = largest_component_count(faces, vertices.shape[0])
    angles = min_angles(vertices, faces)
    edge_manifold = bool((edge_count <= 2).all())
    repeated = np.unique(np.sort(faces, axis=1), axis=0).shape[0] != faces.shape[0]
    fans_ok = edge_manifold and _single_fans(faces, used.size)
    return ManifoldReport(
        closed=bool((edge_count == 2).all()),
        manifold=edge_manifold and fans_ok and not repeated,
        oriented=bool((directed_count == 1).all()),
        components=comp,
        euler=int(used.size - edge_count.size + faces.shape[0]),
        min_angle=float(angles.min()) if faces.size else 0.0,
    )


def _corner_groups(faces: NDArray) -> NDArray | None:
    """``(3F,)`` fan label of every corner (corner ``c = k·F + f`` is vertex ``faces[f, k]``):
    corners of one vertex in two faces that share an edge get one label. ``None`` when an
    edge has more than two faces."""
    faces = np.asarray(faces, dtype=np.int64)
    n_faces = faces.shape[0]
    half = half_edges(faces)
    _, edge_index, counts = np.unique(
        np.sort(half, axis=1), axis=0, return_inverse=True, return_counts=True
    )
    if (counts > 2).any():
        return None
    edge_index = edge_index.reshape(-1)
    # half-edge h = k·F + f runs from corner (f, k) to corner (f, k + 1)
    k = np.repeat(np.arange(3), n_faces)
    face_of = np.tile(np.arange(n_faces), 3)
    start = k * n_faces + face_of
    end = ((k + 1) % 3) * n_faces + face_of
    order = np.argsort(edge_index, kind="stable")
    sorted_edges = edge_index[order]
    pair = np.flatnonzero(sorted_edges[1:] == sorted_edges[:-1])
    h1, h2 = order[pair], order[pair + 1]
    same = half[h1, 0] == half[h2, 0]
    a = np.concatenate([start[h1], end[h1]])
    b = np.concatenate([np.where(same, start[h2], end[h2]), np.where(same, end[h2], start[h2])])
    graph = sparse.coo_matrix((np.ones(a.size), (a, b)), shape=(3 * n_faces, 3 * n_faces))
    _, labels = connected_components(graph, directed=False)
    return labels


def _single_fans(faces: NDArray, n_used: int) -> bool:
    """Whether the faces around every vertex form one fan (no pinched vertex)."""
    labels = _corner_groups(faces)
    return labels is not None and np.unique(labels).size == n_used


def largest_component_count(faces: NDArray, n_vertices: int) -> tuple[NDArray, int]:
    """``(labels (V,), number of components)`` of the vertices used by ``faces``."""
    faces = np.asarray(faces, dtype=np.int64)
    edges = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]]])
    graph = sparse.coo_matrix(
        (np.ones(edges.shape[0]), (edges[:, 0], edges[:, 1])), shape=(n_vertices, n_vertices)
    )
    _, labels = connected_components(graph, directed=False)
    used = np.unique(faces)
    return labels, int(np.unique(labels[used]).size)


def _pymeshlab(action: str = "remeshing"):
    """The pymeshlab module, or MissingDependencyError naming the extra that installs it."""
    try:
        import pymeshlab
    except ImportError as exc:
        raise MissingDependencyError(
            f"{action} needs pymeshlab: pip install 'litege[data]'"
        ) from exc
    return pymeshlab


def run_pymeshlab(
    vertices: NDArray, faces: NDArray, action: str, apply: Callable[[Any, Any], None]
) -> tuple[NDArray, NDArray]:
    """One pymeshlab job on a mesh: ``apply(mesh_set, pymeshlab)`` runs its filters on a
    ``MeshSet`` holding ``(vertices, faces)``.

    Returns:
        The resulting mesh: ``(V', 3)`` float64 vertices and ``(F', 3)`` int64 faces.

    Raises:
        MissingDependencyError: pymeshlab is not installed.
        ComputationError: a filter failed (``action`` names the job).
    """
    pymeshlab = _pymeshlab(action)
    mesh_set = pymeshlab.MeshSet()
    mesh_set.add_mesh(pymeshlab.Mesh(np.asarray(vertices, np.float64), np.asarray(faces, np.int32)))
    try:
        apply(mesh_set, pymeshlab)
    except pymeshlab.PyMeshLabException as exc:
        raise ComputationError(f"{action} failed: {exc}") from exc
    result = mesh_set.current_mesh()
    return (
        np.asarray(result.vertex_matrix(), dtype=np.float64),
        np.asarray(result.face_matrix(), dtype=np.int64),
    )


def edge_length_for(area: float, n_vertices: int) -> float:
    """Edge length of equilateral triangles giving ``n_vertices`` on a closed surface of
    ``area`` (F ≈ 2V, so area ≈ 2V·(√3/4)·L²)."""
    return float(np.sqrt(2.0 * area / (np.sqrt(3.0) * n_vertices)))


def remesh(
    vertices: NDArray,
    faces: NDArray,
    target_vertices: int,
    *,
    iterations: int = 8,
    feature_degrees: float = 180.0,
    rounds: int = 3,
    tolerance: float = 0.12,
) -> tuple[NDArray, NDArray]:
    """Isotropic explicit remeshing (pymeshlab, Botsch–Kobbelt) to about ``target_vertices``.

    The edge length starts from the area and is corrected from the achieved count for up to
    ``rounds`` rounds (stopping within ``tolerance``). ``feature_degrees`` 180 smooths over
    the facets of low-poly models instead of preserving them as creases.

    Returns:
        ``(vertices (V', 3) float64, faces (F', 3) int64)``, unreferenced vertices removed.
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int32)
    edge = edge_length_for(triangle_area_total(vertices, faces), target_vertices)
    best = None
    for _ in range(max(rounds, 1)):

        def apply(mesh_set: Any, pymeshlab: Any, edge: float = edge) -> None:
            mesh_set.meshing_isotropic_explicit_remeshing(
                iterations=iterations,
                targetlen=pymeshlab.PureValue(edge),
                featuredeg=feature_degrees,
                checksurfdist=False,
            )
            mesh_set.meshing_remove_unreferenced_vertices()

        out = run_pymeshlab(vertices, faces, "remeshing", apply)
        ratio = out[0].shape[0] / target_vertices
        if best is None or abs(ratio - 1.0) < abs(best[0].shape[0] / target_vertices - 1.0):
            best = out
        if abs(ratio - 1.0) <= tolerance:
            break
        edge *= float(np.sqrt(ratio))
    assert best is not None
    return best


def collapse_slivers(
    vertices: NDArray, faces: NDArray, min_angle: float = 1.0, max_collapses: int = 200
) -> tuple[NDArray, NDArray]:
    """Remove sliver triangles (smallest angle below ``min_angle`` degrees) of a closed
    manifold by edge collapses: the worst sliver's shortest edge whose collapse keeps the
    mesh manifold (link condition: the edge's endpoints share exactly its two opposite
    vertices) is collapsed to its midpoint; repeated until no sliver is left, no sliver can
    be collapsed, or ``max_collapses`` collapses. Returns the compacted mesh.

    Remeshing thin, nearly flat parts (a stag's tail fin, pinched hooves) leaves a few such
    slivers; exact geodesics need them gone.
    """
    vertices = np.array(vertices, dtype=np.float64)
    faces = np.array(faces, dtype=np.int64)
    for _ in range(max_collapses):
        angles = min_angles(vertices, faces)
        candidates = np.argsort(angles)
        candidates = candidates[angles[candidates] < min_angle]
        if candidates.size == 0:
            break
        collapsed = False
        for face_index in candidates[:8]:
            face = faces[face_index]
            p = vertices[face]
            lengths = np.linalg.norm(p[[1, 2, 0]] - p, axis=1)  # edge i: face[i] -> face[i + 1]
            for edge in np.argsort(lengths):
                a, b = int(face[edge]), int(face[(edge + 1) % 3])
                result = _collapse(vertices, faces, a, b)
                if result is not None:
                    vertices, faces = result
                    collapsed = True
                    break
            if collapsed:
                break
        if not collapsed:
            break
    used = np.unique(faces)
    remap = np.full(vertices.shape[0], -1, dtype=np.int64)
    remap[used] = np.arange(used.size)
    return vertices[used], remap[faces]


def _collapse(vertices: NDArray, faces: NDArray, a: int, b: int) -> tuple[NDArray, NDArray] | None:
    """Collapse edge ``(a, b)`` into ``a`` at the midpoint, or ``None`` if that breaks the
    manifold (link condition), makes two faces coincide or leaves a zero-area face."""
    around_a = (faces == a).any(axis=1)
    around_b = (faces == b).any(axis=1)
    shared = around_a & around_b
    if shared.sum() != 2:
        return None
    opposite = set(np.unique(faces[shared]).tolist()) - {a, b}
    ring_a = set(np.unique(faces[around_a]).tolist()) - {a}
    ring_b = set(np.unique(faces[around_b]).tolist()) - {b}
    if (ring_a & ring_b) != opposite or len(ring_a | ring_b) < 4:
        return None
    new_vertices = vertices.copy()
    new_vertices[a] = 0.5 * (vertices[a] + vertices[b])
    new_faces = np.where(faces == b, a, faces)[~shared]
    moved = new_faces[(new_faces == a).any(axis=1)]
    if np.unique(np.sort(moved, axis=1), axis=0).shape[0] != moved.shape[0]:
        return None  # two faces around a would coincide (a folded "pillow")
    corners = new_vertices[moved]
    cross = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    if (np.linalg.norm(cross, axis=1) <= 1e-14 * np.ptp(vertices, axis=0).max() ** 2).any():
        return None
    return new_vertices, new_faces


def repair_manifold(
    vertices: NDArray, faces: NDArray, max_hole_edges: int = 30, require_closed: bool = True
) -> tuple[NDArray, NDArray]:
    """Repair a mesh into a manifold: faces on non-manifold edges removed (pymeshlab), holes
    of at most ``max_hole_edges`` edges closed with new faces, then pinched vertices split
    (:func:`split_pinched_vertices`).

    Returns:
        ``(faces (F', 3), origin (V',))``: the repaired faces on the vertices
        ``vertices[origin]`` (``origin`` starts with ``arange(V)``; split copies follow), so
        per-vertex attributes such as skin weights carry over as ``attribute[origin]``.

    Raises:
        ComputationError: the repair failed or did not give an oriented manifold (closed too,
            with ``require_closed``).
    """
    pymeshlab = _pymeshlab()
    vertices = np.asarray(vertices, dtype=np.float64)
    mesh_set = pymeshlab.MeshSet()
    mesh_set.add_mesh(pymeshlab.Mesh(vertices, np.asarray(faces, dtype=np.int32)))
    try:
        mesh_set.meshing_repair_non_manifold_edges(method=0)
        mesh_set.meshing_close_holes(maxholesize=max_hole_edges)
    except pymeshlab.PyMeshLabException as exc:
        raise ComputationError(f"mesh repair failed: {exc}") from exc
    result = mesh_set.current_mesh()
    new_vertices = np.asarray(result.vertex_matrix(), dtype=np.float64)
    new_faces = np.asarray(result.face_matrix(), dtype=np.int64)
    if new_vertices.shape != vertices.shape or not np.array_equal(new_vertices, vertices):
        raise ComputationError("mesh repair changed the vertices")
    new_faces, origin = split_pinched_vertices(new_faces, vertices.shape[0])
    report = manifold_report(vertices[origin], new_faces)
    if not (report.manifold and report.oriented and (report.closed or not require_closed)):
        raise ComputationError(f"mesh repair did not give a usable manifold: {report}")
    return new_faces, origin


def largest_body(
    vertices: NDArray, faces: NDArray, require_closed: bool = True
) -> tuple[NDArray, NDArray]:
    """The mesh's largest component made one oriented manifold body: the largest component,
    :func:`repair_manifold` where it is not a manifold (and, with ``require_closed``, not
    closed), else its pinched vertices split (:func:`split_pinched_vertices`), then the largest
    component again, since a shell that met the body at a single vertex (an antler on its
    pedicle) has come apart.

    Returns:
        ``(kept (V',), faces (F', 3))``: the vertex of ``vertices`` each kept vertex copies
        (a split vertex is kept more than once) and the faces on the kept vertices.

    Raises:
        ComputationError: the repair failed (see :func:`repair_manifold`).
    """
    kept, faces = largest_component(faces, vertices.shape[0])
    report = manifold_report(vertices[kept], faces)
    if not (report.manifold and report.oriented and (report.closed or not require_closed)):
        faces, origin = repair_manifold(vertices[kept], faces, require_closed=require_closed)
    else:
        faces, origin = split_pinched_vertices(faces, kept.size)
    body, faces = largest_component(faces, origin.size)
    return kept[origin[body]], faces


def split_pinched_vertices(faces: NDArray, n_vertices: int) -> tuple[NDArray, NDArray]:
    """Give every extra fan of faces around a pinched vertex its own copy of the vertex.

    Args:
        faces: ``(F, 3)`` triangles of an edge-manifold mesh.
        n_vertices: ``V``.

    Returns:
        ``(faces (F, 3), origin (V',))`` with ``origin[:V] == arange(V)`` and ``origin[v]``
        the vertex a copy ``v ≥ V`` was split from.
    """
    faces = np.asarray(faces, dtype=np.int64)
    groups = _corner_groups(faces)
    if groups is None:
        raise ComputationError("cannot split pinched vertices of a non-edge-manifold mesh")
    corner_vertex = faces.T.reshape(-1)  # corner c = k·F + f
    new_faces = faces.copy()
    origin = list(range(n_vertices))
    first_group: dict[int, int] = {}
    copy_of_group: dict[int, int] = {}
    for c in range(corner_vertex.size):
        v, g = int(corner_vertex[c]), int(groups[c])
        if first_group.setdefault(v, g) == g:
            continue
        if g not in copy_of_group:
            copy_of_group[g] = len(origin)
            origin.append(v)
        new_faces[c % faces.shape[0], c // faces.shape[0]] = copy_of_group[g]
    return new_faces, np.asarray(origin, dtype=np.int64)


def subdivide_loop(
    vertices: NDArray, faces: NDArray, iterations: int = 1
) -> tuple[NDArray, NDArray]:
    """Loop subdivision (pymeshlab): smooths faceted low-poly surfaces before remeshing."""
    return run_pymeshlab(
        vertices,
        faces,
        "subdivision",
        lambda mesh_set, pymeshlab: mesh_set.meshing_surface_subdivision_loop(
            iterations=iterations, threshold=pymeshlab.PercentageValue(0.0)
        ),
    )


def unit_area_scale(vertices: NDArray, faces: NDArray) -> float:
    """``1 / sqrt(area)``: the factor that scales the mesh to unit surface area.

    Raises:
        DegenerateShapeError: zero area.
    """
    area = triangle_area_total(np.asarray(vertices, float), np.asarray(faces))
    if not area > 0:
        raise DegenerateShapeError("the mesh has zero area")
    return 1.0 / float(np.sqrt(area))


def smooth_stretch(
    vertices: NDArray,
    rng: np.random.Generator,
    *,
    axis_range: tuple[float, float] = (0.85, 1.15),
    amplitude: float = 0.04,
    n_waves: int = 4,
) -> NDArray:
    """A random smooth non-rigid deformation: an anisotropic scale along three random
    orthogonal axes (factors in ``axis_range``) followed by a sum of ``n_waves`` low-frequency
    sine displacement fields of total amplitude ≤ ``amplitude`` × bounding-box diagonal.

    The waves' wavelength is at least half the diagonal and ``amplitude`` is small, so the
    displacement gradient stays below 1 and the map is a diffeomorphism (no fold-over).

    Args:
        vertices: ``(V, 3)`` positions.
        rng: the random stream.
    """
    from scipy.spatial.transform import Rotation

    vertices = np.asarray(vertices, dtype=np.float64)
    center = vertices.mean(axis=0)
    rotation = Rotation.random(random_state=rng).as_matrix()
    factors = rng.uniform(*axis_range, size=3)
    out = (vertices - center) @ rotation.T * factors @ rotation + center
    diagonal = float(np.linalg.norm(np.ptp(out, axis=0)))
    for _ in range(n_waves):
        direction = rng.normal(size=3)
        direction /= np.linalg.norm(direction)
        displacement = rng.normal(size=3)
        displacement /= np.linalg.norm(displacement)
        wavelength = diagonal * rng.uniform(0.5, 1.5)
        phase = rng.uniform(0.0, 2.0 * np.pi)
        size = amplitude * diagonal / n_waves * rng.uniform(0.3, 1.0)
        out = (
            out
            + size
            * np.sin(2.0 * np.pi * (out @ direction) / wavelength + phase)[:, None]
            * displacement
        )
    return out


__all__ = [
    "ManifoldReport",
    "Welded",
    "collapse_slivers",
    "edge_length_for",
    "largest_body",
    "largest_component",
    "manifold_report",
    "min_angles",
    "remesh",
    "repair_manifold",
    "run_pymeshlab",
    "smooth_stretch",
    "split_pinched_vertices",
    "subdivide_loop",
    "triangle_area_total",
    "unit_area_scale",
    "weld",
]
