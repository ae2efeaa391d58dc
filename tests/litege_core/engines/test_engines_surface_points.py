"""Exact geodesics between arbitrary surface points (mesh refinement + exact engine)."""

import numpy as np
import pytest

from litege_core.engines import (
    ExactGeodesicEngine,
    insert_surface_points,
    surface_point_distances,
)
from litege_core.errors import ArrayShapeError, IndexOutOfRangeError, InputError
from litege_core.sampling import sample_surface
from litege_core.shape import Shape


def positions(shape: Shape, face_index, barycentric) -> np.ndarray:
    corners = shape.vertices[shape.faces[np.asarray(face_index)]]
    return np.einsum("pk,pkd->pd", np.asarray(barycentric, float), corners)


def test_flat_plane_geodesic_equals_euclidean(flat_grid):
    samples = sample_surface(flat_grid.vertices, flat_grid.faces, 60, seed=1)
    rng = np.random.default_rng(2)
    # add points on edges, at corners, coincident ones and six in one triangle
    extra_faces = [0, 0, 0, 5, 5, *([10] * 6)]
    extra_bary = [
        [1, 0, 0],
        [0.5, 0.5, 0],
        [0.3, 0, 0.7],
        [0.2, 0.3, 0.5],
        [0.2, 0.3, 0.5],
        *rng.dirichlet([1, 1, 1], 6),
    ]
    face_index = np.concatenate([samples.face_index, extra_faces])
    barycentric = np.vstack([samples.barycentric, extra_bary])
    result = surface_point_distances(flat_grid, face_index, barycentric, to_vertices=True)
    points = positions(flat_grid, face_index, barycentric)
    euclidean = np.linalg.norm(points[:, None] - points[None], axis=2)
    # measured max abs error 3e-15 (the unit square is convex and flat)
    np.testing.assert_allclose(result.distances, euclidean, rtol=0, atol=1e-9)
    to_vertices = np.linalg.norm(points[:, None] - flat_grid.vertices[None], axis=2)
    np.testing.assert_allclose(result.to_vertices, to_vertices, rtol=0, atol=1e-9)
    assert result.method == "exact_surface_points"
    refined = result.refined
    assert refined.point_vertex[60] == flat_grid.faces[0, 0]  # corner reused
    assert refined.point_vertex[63] == refined.point_vertex[64]  # coincident points share
    # area is preserved triangle by triangle
    refined_area = Shape.from_arrays(refined.vertices, refined.faces).face_areas
    per_parent = np.bincount(refined.parent_face, refined_area, minlength=flat_grid.n_faces)
    np.testing.assert_allclose(per_parent, flat_grid.face_areas, rtol=1e-12)


def test_points_near_edges_and_corners_on_a_plane(flat_grid):
    # Snapping (1e-9) merges points 1e-12 from an edge with the edge point; points 1e-8 or
    # 1e-6 away create sliver triangles. Measured max abs error with slivers: 2.6e-9.
    rng = np.random.default_rng(5)
    face_index, barycentric = [], []
    for face in rng.integers(flat_grid.n_faces, size=20).tolist():
        t = rng.uniform(0.1, 0.9)
        for eps in (0.0, 1e-12, 1e-8, 1e-6):
            face_index.append(face)
            barycentric.append([t - eps / 2, 1 - t - eps / 2, eps])
        face_index.append(face)
        barycentric.append([1 - 1e-8, 5e-9, 5e-9])
    result = surface_point_distances(flat_grid, face_index, barycentric)
    vertex = result.refined.point_vertex.reshape(20, 5)
    assert np.all(vertex[:, 0] == vertex[:, 1])
    assert len(np.unique(vertex[:, [0, 2, 3, 4]])) == 80
    points = positions(flat_grid, face_index, barycentric)
    euclidean = np.linalg.norm(points[:, None] - points[None], axis=2)
    np.testing.assert_allclose(result.distances, euclidean, rtol=0, atol=1e-8)


def test_point_at_a_vertex_gives_the_vertex_row(sphere3):
    face = 17
    corner = int(sphere3.faces[face, 2])
    result = surface_point_distances(sphere3, [face], [[0.0, 1e-12, 1.0 - 1e-12]], to_vertices=True)
    expected = ExactGeodesicEngine(sphere3).distance(corner)
    assert result.refined.point_vertex[0] == corner
    assert result.refined.vertices.shape == sphere3.vertices.shape  # nothing inserted
    np.testing.assert_array_equal(result.to_vertices[0], expected)


def test_refinement_keeps_vertex_distances_and_is_symmetric(sphere3):
    samples = sample_surface(sphere3.vertices, sphere3.faces, 12, seed=4)
    # a point on an edge given from both incident faces must land on one shared vertex
    a, b = int(sphere3.faces[0, 0]), int(sphere3.faces[0, 1])
    other = int(
        np.flatnonzero(
            (sphere3.faces == a).any(axis=1)
            & (sphere3.faces == b).any(axis=1)
            & (np.arange(sphere3.n_faces) != 0)
        )[0]
    )
    on_other = np.zeros(3)
    on_other[list(sphere3.faces[other]).index(a)] = 0.25
    on_other[list(sphere3.faces[other]).index(b)] = 0.75
    face_index = np.concatenate([samples.face_index, [0, other]])
    barycentric = np.vstack([samples.barycentric, [0.25, 0.75, 0.0], on_other])
    result = surface_point_distances(sphere3, face_index, barycentric, to_vertices=True)
    assert result.refined.point_vertex[12] == result.refined.point_vertex[13]
    assert result.refined.vertices.shape[0] == sphere3.n_points + 13
    d = result.distances
    np.testing.assert_allclose(d, d.T, rtol=1e-6, atol=1e-12)
    # original vertex-to-vertex geodesics are unchanged by the (flat) refinement
    refined_shape = Shape.from_arrays(result.refined.vertices, result.refined.faces)
    refined_rows = ExactGeodesicEngine(refined_shape).distances([0, 100]).distances
    original_rows = ExactGeodesicEngine(sphere3).distances([0, 100]).distances
    np.testing.assert_allclose(refined_rows[:, : sphere3.n_points], original_rows, atol=1e-9)
    # and each point's distances are bounded by the chord and the triangle inequality
    points = positions(sphere3, face_index, barycentric)
    chords = np.linalg.norm(points[:, None] - points[None], axis=2)
    assert np.all(d >= chords - 1e-9)
    assert np.all(d[:, :1] + d[:1, :] >= d - 1e-9)
    assert np.all(
        np.abs(result.to_vertices[:, a] - result.to_vertices[:, b])
        <= np.linalg.norm(sphere3.vertices[a] - sphere3.vertices[b]) + 1e-9
    )


def test_backends_agree_on_surface_points(sphere3):
    samples = sample_surface(sphere3.vertices, sphere3.faces, 5, seed=7)
    a = surface_point_distances(sphere3, samples.face_index, samples.barycentric)
    b = surface_point_distances(sphere3, samples.face_index, samples.barycentric, backend="gdist")
    np.testing.assert_allclose(a.distances, b.distances, rtol=1e-6)


def test_insert_keeps_orientation_and_manifoldness(sphere3):
    samples = sample_surface(sphere3.vertices, sphere3.faces, 40, seed=9)
    barycentric = samples.barycentric.copy()
    barycentric[::4] = [0.5, 0.0, 0.5]  # every 4th point on an edge
    refined = insert_surface_points(
        sphere3.vertices, sphere3.faces, samples.face_index, barycentric
    )
    normals = np.cross(
        refined.vertices[refined.faces[:, 1]] - refined.vertices[refined.faces[:, 0]],
        refined.vertices[refined.faces[:, 2]] - refined.vertices[refined.faces[:, 0]],
    )
    centroid_dirs = refined.vertices[refined.faces].mean(axis=1)
    assert np.all(np.einsum("fd,fd->f", normals, centroid_dirs) > 0)  # still outward
    half = np.sort(refined.faces[:, [[0, 1], [1, 2], [2, 0]]], axis=2).reshape(-1, 2)
    _, counts = np.unique(half, axis=0, return_counts=True)
    assert np.all(counts == 2)  # closed 2-manifold


@pytest.mark.parametrize(
    ("face_index", "barycentric", "error", "match"),
    [
        ([1280], [[1, 0, 0]], IndexOutOfRangeError, "face index"),
        ([], np.empty((0, 3)), InputError, "face is empty"),
        ([0], [[0.5, 0.5]], ArrayShapeError, "shape"),
        ([0, 1], [[1, 0, 0]], ArrayShapeError, "shape"),
        ([0], [[0.7, 0.7, -0.4]], InputError, "non-negative"),
        ([0], [[0.5, 0.4, 0.0]], InputError, "summing to 1"),
        ([0], [[np.nan, 0.5, 0.5]], InputError, "NaN"),
    ],
)
def test_bad_surface_points(sphere3, face_index, barycentric, error, match):
    with pytest.raises(error, match=match):
        surface_point_distances(sphere3, face_index, barycentric)


def test_surface_points_refuse_point_clouds_and_degenerate_faces(sphere_cloud, sphere3):
    with pytest.raises(InputError, match="triangle mesh"):
        surface_point_distances(sphere_cloud, [0], [[1, 0, 0]])
    faces = np.vstack([sphere3.faces, [[0, 0, 1]]])
    shape = Shape.from_arrays(sphere3.vertices, faces)
    with pytest.raises(InputError, match="repeated corner"):
        surface_point_distances(shape, [1280], [[0.2, 0.3, 0.5]])
