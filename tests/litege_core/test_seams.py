"""Seams of a mesh stored with repeated vertices (:mod:`litege_core.seams`)."""

import numpy as np
import trimesh

from litege_core.seams import (
    boundary_edge_fraction,
    boundary_vertices,
    consistently_wound,
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
