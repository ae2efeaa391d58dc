"""Seams of a mesh stored with repeated vertices (:mod:`litege_core.seams`)."""

import numpy as np
import trimesh

from litege_core.seams import (
    boundary_edge_fraction,
    boundary_vertices,
    consistently_wound,
    oriented_faces,
    seam_welds,
    unique_edges,
    vertex_normals,
)


def _sphere() -> tuple[np.ndarray, np.ndarray]:
    mesh = trimesh.creation.icosphere(subdivisions=2)
    return np.asarray(mesh.vertices), np.asarray(mesh.faces, dtype=np.int64)


def _slow_unique_edges(faces: np.ndarray) -> dict[tuple[int, int], int]:
    """The reference: each undirected edge and how many faces use it, one face at a time."""
    counts: dict[tuple[int, int], int] = {}
    for a, b, c in faces.tolist():
        for edge in ((a, b), (b, c), (c, a)):
            key = (min(edge), max(edge))
            counts[key] = counts.get(key, 0) + 1
    return counts


def test_unique_edges_match_the_face_by_face_count():
    _, faces = _sphere()
    faces = np.concatenate([faces, faces[:3]])  # three faces twice: counts of 2 and more
    edges, counts = unique_edges(faces)
    assert dict(zip(map(tuple, edges.tolist()), counts.tolist(), strict=True)) == (
        _slow_unique_edges(faces)
    )
    assert (edges[:, 0] < edges[:, 1]).all()
    order = np.lexsort((edges[:, 1], edges[:, 0]))
    assert (order == np.arange(len(edges))).all()  # sorted lexicographically
    assert edges.dtype == counts.dtype == np.int64
    empty, none = unique_edges(np.zeros((0, 3), dtype=np.int64))
    assert empty.shape == (0, 2) and none.shape == (0,)


def test_a_soup_welds_back_to_its_mesh():
    vertices, faces = _sphere()
    corner = faces.reshape(-1)  # soup vertex → mesh vertex
    soup_points, soup_faces = vertices[corner], np.arange(corner.size).reshape(-1, 3)
    welds = seam_welds(soup_points, soup_faces)
    np.testing.assert_array_equal(soup_points[welds], soup_points)  # same positions
    assert np.unique(welds).size == vertices.shape[0]
    assert np.array_equal(np.unique(corner[welds]), np.arange(vertices.shape[0]))
    assert boundary_vertices(soup_faces, corner.size).all()  # every soup edge is on a rim
    assert boundary_edge_fraction(soup_faces, soup_points) == 0.0  # welded: a closed sphere
    assert boundary_edge_fraction(soup_faces) == 1.0  # as stored: every edge a rim
    assert boundary_edge_fraction(faces, vertices) == 0.0


def test_coincident_vertices_inside_closed_surfaces_stay_apart():
    """Two closed spheres touching at one vertex: not a seam, so not welded."""
    vertices, faces = _sphere()
    other = vertices - vertices[5] + vertices[0]  # its vertex 5 lies on vertex 0
    both = np.concatenate([vertices, other])
    welds = seam_welds(both, np.concatenate([faces, faces + len(vertices)]))
    np.testing.assert_array_equal(welds, np.arange(both.shape[0]))


def test_an_open_mesh_keeps_its_boundary():
    vertices, faces = _sphere()
    open_faces = faces[vertices[faces].mean(axis=1)[:, 2] < 0.5]  # the cap cut off
    assert 0.0 < boundary_edge_fraction(open_faces, vertices) < 0.2
    rim = boundary_vertices(open_faces, vertices.shape[0])
    assert 0 < rim.sum() < vertices.shape[0] // 4


def test_vertex_normals_point_outwards():
    vertices, faces = _sphere()
    normals = vertex_normals(vertices, faces)
    np.testing.assert_allclose(np.einsum("ij,ij->i", normals, vertices), 1.0, atol=0.03)
    unused = np.concatenate([vertices, [[5.0, 5.0, 5.0]]])
    assert not vertex_normals(unused, faces)[-1].any()  # an unreferenced vertex: zero


def test_consistent_winding_is_told_from_a_flipped_face():
    _, faces = _sphere()
    assert consistently_wound(faces)
    assert consistently_wound(faces[::-1, ::-1])  # every face flipped: still consistent
    assert consistently_wound(faces[: len(faces) // 2])  # an open mesh: boundaries count not
    flipped = faces.copy()
    flipped[7] = flipped[7, ::-1]
    assert not consistently_wound(flipped)
    assert not consistently_wound(np.concatenate([faces, faces[:1]]))  # a face twice


def _slow_orientation(faces: np.ndarray) -> np.ndarray | None:
    """The reference: turn faces over one at a time, walking outwards from each part's first
    face across the edges exactly two faces share; ``None`` on a conflict."""
    sharing: dict[tuple[int, int], list[int]] = {}
    for index, face in enumerate(faces.tolist()):
        for edge in ((face[0], face[1]), (face[1], face[2]), (face[2], face[0])):
            sharing.setdefault((min(edge), max(edge)), []).append(index)
    neighbours: dict[int, list[int]] = {i: [] for i in range(len(faces))}
    for pair in sharing.values():
        if len(pair) == 2:
            neighbours[pair[0]].append(pair[1])
            neighbours[pair[1]].append(pair[0])
    oriented: list[list[int] | None] = [None] * len(faces)

    def walks(face: list[int]) -> set[tuple[int, int]]:
        return {(face[0], face[1]), (face[1], face[2]), (face[2], face[0])}

    for start in range(len(faces)):
        if oriented[start] is not None:
            continue
        oriented[start] = faces[start].tolist()
        queue = [start]
        while queue:
            current = queue.pop(0)
            for other in neighbours[current]:
                face = faces[other].tolist()
                mine = walks(oriented[current])  # type: ignore[arg-type]
                wanted = face if not (walks(face) & mine) else face[::-1]
                if oriented[other] is None:
                    oriented[other] = wanted
                    queue.append(other)
                elif walks(oriented[other]) & mine:  # type: ignore[arg-type]
                    return None
    return np.asarray(oriented)


def _moebius_strip(segments: int = 12) -> np.ndarray:
    faces = []
    for i in range(segments):
        a0, a1 = 2 * i, 2 * i + 1
        b0, b1 = (2 * i + 2, 2 * i + 3) if i + 1 < segments else (1, 0)  # the half twist
        faces += [[a0, b0, a1], [a1, b0, b1]]
    return np.asarray(faces, dtype=np.int64)


def test_faces_wound_against_their_neighbours_are_turned_over():
    _, faces = _sphere()
    turned = np.random.default_rng(3).random(len(faces)) < 0.3
    turned[0] = False  # the part keeps its first face's winding
    mixed = faces.copy()
    mixed[turned] = mixed[turned][:, ::-1]
    assert not consistently_wound(mixed)
    oriented = oriented_faces(mixed)
    assert oriented is not None and consistently_wound(oriented)
    np.testing.assert_array_equal(oriented, faces)
    np.testing.assert_array_equal(oriented, _slow_orientation(mixed))
    # two parts, each its own first face; a non-manifold fin constrains nothing
    two = np.concatenate([mixed, mixed[::-1] + faces.max() + 1])
    fin = np.array([[faces[5, 0], faces[5, 1], two.max() + 1]])
    oriented = oriented_faces(np.concatenate([two, fin]))
    assert oriented is not None
    np.testing.assert_array_equal(oriented, _slow_orientation(np.concatenate([two, fin])))
    assert oriented_faces(_moebius_strip()) is None
    assert _slow_orientation(_moebius_strip()) is None
