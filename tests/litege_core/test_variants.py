import numpy as np
import pytest
import trimesh

from litege_core.errors import ArrayShapeError
from litege_core.validate import triangle_areas
from litege_core.variants import (
    add_noise,
    add_outliers,
    anisotropic_remesh,
    broken_mesh,
    cut_by_planes,
    decimated_mesh,
    isotropic_remesh,
    locate_on_mesh,
    point_cloud,
    random_rotation,
    repeated_points,
    rotate,
)

pytest.importorskip("pymeshlab")


@pytest.fixture(scope="module")
def capsule():
    mesh = trimesh.creation.capsule(height=2.0, radius=0.5, count=[24, 24])
    return np.asarray(mesh.vertices), np.asarray(mesh.faces)


def test_random_rotation_is_proper_and_seeded():
    rotation = random_rotation(3)
    np.testing.assert_allclose(rotation @ rotation.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(rotation) == pytest.approx(1.0)
    np.testing.assert_array_equal(rotation, random_rotation(3))
    assert not np.allclose(rotation, random_rotation(4))
    points = np.random.default_rng(0).normal(size=(5, 3))
    np.testing.assert_allclose(rotate(points, rotation)[0], rotation @ points[0])


def test_isotropic_remesh_hits_target_and_maps_back(capsule):
    vertices, faces = capsule
    variant = isotropic_remesh(vertices, faces, target_vertices=1500)
    assert abs(variant.vertices.shape[0] / 1500 - 1) <= 0.1
    mapped = variant.source_location.points(vertices, faces)
    assert np.linalg.norm(mapped - variant.vertices, axis=1).max() < 0.02
    area_before = triangle_areas(vertices, faces).sum()
    assert triangle_areas(variant.vertices, variant.faces).sum() == pytest.approx(
        area_before, rel=0.03
    )


def _edge_stats(vertices, faces):
    """Mean |edge| per axis (3,) and mean longest/shortest edge ratio of the triangles."""
    edges = vertices[faces[:, [1, 2, 0]]] - vertices[faces]
    lengths = np.linalg.norm(edges, axis=2)
    return np.abs(edges.reshape(-1, 3)).mean(axis=0), (lengths.max(1) / lengths.min(1)).mean()


def test_anisotropic_remesh_elongates_triangles_along_x(capsule):
    vertices, faces = capsule
    variant = anisotropic_remesh(vertices, faces, target_vertices=1500)
    isotropic = isotropic_remesh(vertices, faces, target_vertices=1500)
    aniso_axes, aniso_ratio = _edge_stats(variant.vertices, variant.faces)
    iso_axes, iso_ratio = _edge_stats(isotropic.vertices, isotropic.faces)
    # Measured on this capsule: edge ratio 2.18 vs 1.35; x/y extent 0.73 vs 1.00.
    assert aniso_ratio > 1.4 * iso_ratio
    assert aniso_axes[0] / aniso_axes[1] < 0.85 * iso_axes[0] / iso_axes[1]
    assert abs(variant.vertices.shape[0] / 1500 - 1) <= 0.1


def test_locate_on_mesh_recovers_vertices(capsule):
    vertices, faces = capsule
    location = locate_on_mesh(vertices, faces, vertices[:50])
    np.testing.assert_allclose(location.points(vertices, faces), vertices[:50], atol=1e-9)
    np.testing.assert_allclose(location.barycentric.sum(axis=1), 1.0)


def test_broken_mesh_removes_fraction_deterministically(capsule):
    _, faces = capsule
    kept = broken_mesh(faces, 0.4, seed=1)
    assert kept.size == round(0.6 * faces.shape[0])
    assert np.all(np.diff(kept) > 0)
    np.testing.assert_array_equal(kept, broken_mesh(faces, 0.4, seed=1))
    assert not np.array_equal(kept, broken_mesh(faces, 0.4, seed=2))
    with pytest.raises(ArrayShapeError):
        broken_mesh(faces, 1.0)


def test_point_cloud_locations_match_points(capsule):
    vertices, faces = capsule
    variant = point_cloud(vertices, faces, 300, seed=5)
    assert variant.points.shape == (300, 3)
    np.testing.assert_allclose(variant.source_location.points(vertices, faces), variant.points)


@pytest.mark.parametrize("fraction", [0.10, 0.15])
def test_cut_by_planes_removes_fraction(capsule, fraction):
    vertices, faces = capsule
    points = point_cloud(vertices, faces, 4000, seed=0).points
    kept = cut_by_planes(points, fraction, seed=3)
    assert 1 - kept.mean() == pytest.approx(fraction, abs=0.005)
    along_x = cut_by_planes(points, fraction, direction=np.array([1.0, 0, 0]))
    assert points[~along_x, 0].min() < points[along_x, 0].min()


def test_add_noise_has_requested_sigma():
    points = np.zeros((20000, 3))
    noisy = add_noise(points, 0.01, seed=0)
    assert noisy.std() == pytest.approx(0.01, rel=0.03)
    np.testing.assert_array_equal(noisy, add_noise(points, 0.01, seed=0))


def test_add_outliers_appends_seeded_strays_in_the_grown_box():
    points = np.random.default_rng(0).uniform(-1.0, 1.0, size=(1000, 3)) * [2.0, 1.0, 0.5]
    stray = add_outliers(points, 0.05, seed=3)
    assert stray.shape == (1050, 3)
    np.testing.assert_array_equal(stray[:1000], points)
    low, high = points.min(0), points.max(0)
    pad = 0.1 * (high - low)
    assert (stray[1000:] >= low - pad).all() and (stray[1000:] <= high + pad).all()
    assert (np.abs(stray[1000:]) > np.abs(points).max(0)).any()  # some lie outside the box
    np.testing.assert_array_equal(stray, add_outliers(points, 0.05, seed=3))
    assert add_outliers(points, 0.0).shape == points.shape
    for bad in (-0.1, float("nan"), float("inf")):
        with pytest.raises(ArrayShapeError):
            add_outliers(points, bad)


def test_repeated_points_are_a_seeded_draw_without_repeats():
    index = repeated_points(1000, 0.25, seed=4)
    assert index.shape == (250,) and np.unique(index).size == 250
    assert index.min() >= 0 and index.max() < 1000 and (np.diff(index) > 0).all()
    np.testing.assert_array_equal(index, repeated_points(1000, 0.25, seed=4))
    np.testing.assert_array_equal(repeated_points(10, 1.0), np.arange(10))
    assert repeated_points(10, 0.0).size == 0
    for bad in (-0.1, 1.5, float("nan")):
        with pytest.raises(ArrayShapeError):
            repeated_points(10, bad)


def test_decimation_keeps_a_closed_surface_and_refuses_too_few_vertices(blob):
    pytest.importorskip("pymeshlab")
    from litege_core.seams import boundary_edge_fraction

    shape = blob(2, subdivisions=3)
    vertices, faces = decimated_mesh(shape.vertices, shape.faces, 200)
    assert 160 <= vertices.shape[0] <= 240 and faces.shape == (2 * vertices.shape[0] - 4, 3)
    assert boundary_edge_fraction(faces) == 0.0  # still closed, genus 0
    with pytest.raises(ArrayShapeError):
        decimated_mesh(shape.vertices, shape.faces, 3)
