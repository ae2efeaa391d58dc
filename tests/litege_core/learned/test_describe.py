import numpy as np
import pytest
import trimesh

from litege_core.learned import describe_shape, shape_samples
from litege_core.shape import Shape
from litege_core.variants import random_rotation


def _ellipsoid(seed: int) -> Shape:
    rng = np.random.default_rng(seed)
    sphere = trimesh.creation.icosphere(subdivisions=3)
    vertices = np.asarray(sphere.vertices) * [1.6 + rng.uniform(-0.3, 0.3), 1.0, 0.6]
    vertices[:, 1] += 0.3 * vertices[:, 0] ** 2 * rng.uniform(0.5, 1.5)  # asymmetric bend
    return Shape.from_arrays(vertices, sphere.faces)


@pytest.fixture(scope="module")
def basis(fit_toy_basis):
    return fit_toy_basis(_ellipsoid)


def test_descriptor_is_invariant_to_rigid_motion_and_scale(basis):
    shape = _ellipsoid(100)
    rotation = random_rotation(7)
    moved = shape.with_vertices(3.5 * shape.vertices @ rotation.T + [4.0, -2.0, 1.0])
    a = describe_shape(shape, basis, seed=3)
    b = describe_shape(moved, basis, seed=3)
    np.testing.assert_allclose(a.descriptor, b.descriptor, atol=1e-4)
    np.testing.assert_allclose(a.samples, b.samples, atol=1e-9)
    # The transform maps the user's frame to the canonical one.
    np.testing.assert_allclose(
        b.transform.apply(moved.vertices), a.transform.apply(shape.vertices), atol=1e-9
    )


def test_point_cloud_descriptor_ignores_point_order(basis):
    points = shape_samples(_ellipsoid(101), 1500, seed=0)
    cloud = Shape.from_arrays(points)
    shuffled = Shape.from_arrays(points[np.random.default_rng(0).permutation(len(points))])
    np.testing.assert_allclose(
        describe_shape(cloud, basis).descriptor,
        describe_shape(shuffled, basis).descriptor,
        atol=1e-5,
    )


def test_stray_points_of_a_cloud_leave_its_frame_and_descriptor_as_they_were(basis):
    """A scan's outliers (here 40 points on a shell well outside the shape) are left out of
    the descriptor's samples: frame and descriptor equal the clean cloud's, though the stray
    points would have moved the frame. A clean cloud keeps every point."""
    from litege_core.canonical import canonicalize_bbox

    points = shape_samples(_ellipsoid(103), 1500, seed=0)
    np.testing.assert_array_equal(shape_samples(Shape.from_arrays(points)), points)
    rng = np.random.default_rng(1)
    directions = rng.normal(size=(40, 3))
    shell = (
        directions / np.linalg.norm(directions, axis=1, keepdims=True) * rng.uniform(3, 4, (40, 1))
    )
    stray = Shape.from_arrays(np.concatenate([points, shell]))
    np.testing.assert_array_equal(shape_samples(stray), points)
    noisy, clean = describe_shape(stray, basis), describe_shape(Shape.from_arrays(points), basis)
    assert noisy.transform.allclose(clean.transform)
    np.testing.assert_array_equal(noisy.descriptor, clean.descriptor)
    assert not canonicalize_bbox(stray.vertices).allclose(clean.transform, atol=1e-3)


def test_residual_flags_out_of_distribution_shapes(basis):
    inside = describe_shape(_ellipsoid(102), basis).residual
    box = trimesh.creation.box(extents=[1.0, 1.0, 1.0])
    torus = trimesh.creation.torus(major_radius=1.0, minor_radius=0.2)
    for other in (box, torus):
        outside = describe_shape(Shape.from_arrays(other.vertices, other.faces), basis).residual
        assert outside > 2 * inside


def test_frame_candidates_pick_the_lowest_residual_frame(basis):
    shape = _ellipsoid(103)
    default = describe_shape(shape, basis, seed=1)
    selected = describe_shape(shape, basis, seed=1, frame_candidates="signs")
    assert selected.residual <= default.residual + 1e-6
    # The selected frame differs from the default by axis signs only.
    signs = selected.transform.rotation @ default.transform.rotation.T
    np.testing.assert_allclose(np.abs(signs), np.eye(3), atol=1e-9)
    np.testing.assert_allclose(
        selected.samples, selected.transform.apply(shape_samples(shape, 2000, 1)), atol=1e-9
    )
    again = describe_shape(shape, basis, seed=1, frame_candidates="pca")
    np.testing.assert_array_equal(again.descriptor, default.descriptor)
