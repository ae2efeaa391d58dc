"""Tests of litege_core.canonical: the Transform algebra and the three pipelines (spec §1)."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
import trimesh
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from litege_core.canonical import (
    BATCHED_MIN_CLOUDS,
    BBOX_SQRT_AREA,
    POISSON_8K_CLOUD,
    POISSON_500_CLOUD,
    POISSON_BROKEN_MESH,
    CanonicalizationMethod,
    PoissonScaleSetting,
    Transform,
    calibrate_poisson_target,
    canonicalize,
    canonicalize_bbox,
    canonicalize_bbox_many,
    canonicalize_poisson,
    canonicalize_unit_area,
    pca_alignment,
)
from litege_core.errors import (
    ArrayShapeError,
    ArtifactError,
    DegenerateShapeError,
    EmptyShapeError,
    InputError,
    NonFiniteError,
)
from litege_core.sampling import (
    mean_nearest_neighbour_distance,
    poisson_disk_subsample,
    sample_surface,
)
from litege_core.shape import Shape
from litege_core.validate import triangle_areas

# --------------------------------------------------------------------------- strategies

unit = st.floats(-1.0, 1.0, allow_nan=False)


@st.composite
def rotations(draw: st.DrawFn) -> np.ndarray:
    """Uniform-ish proper rotations from random quaternions."""
    q = np.array([draw(unit) for _ in range(4)])
    norm = np.linalg.norm(q)
    assume(norm > 1e-3)
    w, x, y, z = q / norm
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


translations = st.lists(st.floats(-100.0, 100.0, allow_nan=False), min_size=3, max_size=3).map(
    np.array
)
scales = st.floats(-2.0, 2.0).map(lambda e: 10.0**e)


@st.composite
def transforms(draw: st.DrawFn) -> Transform:
    return Transform(draw(rotations()), draw(translations), draw(scales))


POINTS = np.random.default_rng(42).normal(size=(50, 3)) * 3.0


def _asymmetric_cloud(n: int = 2000, seed: int = 0) -> np.ndarray:
    """Anisotropic, clearly skewed cloud: distinct eigenvalues, non-zero medians."""
    rng = np.random.default_rng(seed)
    points = rng.normal(size=(n, 3)) * np.array([3.0, 1.5, 0.5])
    points[:, 0] += 0.4 * points[:, 1] ** 2  # banana: shifts the medians off zero
    points[:, 1] += 0.3 * np.abs(points[:, 0])
    return points


CLOUD = _asymmetric_cloud()


def _box_mesh(extents: tuple[float, float, float]) -> tuple[np.ndarray, np.ndarray]:
    mesh = trimesh.creation.box(extents=extents)
    return np.asarray(mesh.vertices), np.asarray(mesh.faces)


# --------------------------------------------------------------------------- Transform


@settings(max_examples=60, deadline=None)
@given(transform=transforms())
def test_apply_then_invert_is_identity(transform):
    forward = transform.apply(POINTS)
    np.testing.assert_allclose(transform.invert(forward), POINTS, atol=1e-9)
    np.testing.assert_allclose(transform.inverse().apply(forward), POINTS, atol=1e-9)
    assert transform.inverse().inverse().allclose(transform, atol=1e-9)


@settings(max_examples=30, deadline=None)
@given(transform=transforms())
def test_apply_maps_each_point_on_its_own(transform):
    """A subset of the points maps to exactly the rows of the whole (lazy canonical points)."""
    many = np.random.default_rng(0).normal(size=(1037, 3)) * 5
    whole = transform.apply(many)
    for rows in (np.array([0]), np.array([1036, 5, 5, 17]), np.arange(3, 700, 7)):
        np.testing.assert_array_equal(transform.apply(many[rows]), whole[rows])
    np.testing.assert_array_equal(transform.apply(many[9]), whole[9])  # one (3,) point


@settings(max_examples=60, deadline=None)
@given(transform=transforms())
def test_forward_formula_and_matrix(transform):
    expected = transform.scale * (transform.rotation @ (POINTS - transform.center).T).T
    np.testing.assert_allclose(transform.apply(POINTS), expected, atol=1e-9)
    homogeneous = np.hstack([POINTS, np.ones((len(POINTS), 1))])
    via_matrix = (transform.as_matrix() @ homogeneous.T).T[:, :3]
    np.testing.assert_allclose(via_matrix, expected, atol=1e-9)
    vectors = POINTS[1:] - POINTS[:-1]
    np.testing.assert_allclose(
        transform.apply_vectors(vectors), expected[1:] - expected[:-1], atol=1e-9
    )


@settings(max_examples=60, deadline=None)
@given(first=transforms(), second=transforms())
def test_compose_matches_sequential_application(first, second):
    sequential = second.apply(first.apply(POINTS))
    tolerance = 1e-9 * max(1.0, np.abs(sequential).max())
    np.testing.assert_allclose(second.compose(first).apply(POINTS), sequential, atol=tolerance)
    np.testing.assert_allclose(first.then(second).apply(POINTS), sequential, atol=tolerance)
    np.testing.assert_allclose(
        second.compose(first).as_matrix(),
        second.as_matrix() @ first.as_matrix(),
        atol=1e-9 * max(1.0, np.abs(second.as_matrix() @ first.as_matrix()).max()),
    )
    assert first.compose(first.inverse()).allclose(Transform.identity(), atol=1e-9)


@settings(max_examples=30, deadline=None)
@given(transform=transforms())
def test_dict_round_trip_is_exact_through_json(transform):
    restored = Transform.from_dict(json.loads(json.dumps(transform.to_dict())))
    np.testing.assert_array_equal(restored.rotation, transform.rotation)
    np.testing.assert_array_equal(restored.center, transform.center)
    assert restored.scale == transform.scale


def test_distance_scaling():
    transform = Transform(np.eye(3), np.zeros(3), 2.5)
    assert transform.scale_distance(2.0) == pytest.approx(5.0)
    assert transform.unscale_distance(5.0) == pytest.approx(2.0)
    np.testing.assert_allclose(transform.unscale_distance(transform.scale_distance([1, 2])), [1, 2])


def test_transform_is_read_only_and_identity_is_neutral():
    identity = Transform.identity()
    np.testing.assert_array_equal(identity.apply(POINTS), POINTS)
    with pytest.raises(ValueError):
        identity.rotation[0, 0] = 2.0
    with pytest.raises(AttributeError):
        identity.scale = 2.0  # type: ignore[misc]


@pytest.mark.parametrize(
    ("rotation", "center", "scale", "error"),
    [
        (np.diag([1.0, 1.0, -1.0]), np.zeros(3), 1.0, InputError),  # reflection
        (2.0 * np.eye(3), np.zeros(3), 1.0, InputError),  # not orthonormal
        (np.eye(2), np.zeros(3), 1.0, ArrayShapeError),
        (np.eye(3), np.zeros(2), 1.0, ArrayShapeError),
        (np.eye(3), np.array([0.0, np.nan, 0.0]), 1.0, InputError),
        (np.eye(3), np.zeros(3), 0.0, InputError),
        (np.eye(3), np.zeros(3), -1.0, InputError),
        (np.eye(3), np.zeros(3), float("inf"), InputError),
        (np.eye(3), np.zeros(3), None, InputError),
        (np.eye(3), np.zeros(3), "big", InputError),
    ],
)
def test_transform_validation(rotation, center, scale, error):
    with pytest.raises(error):
        Transform(rotation, center, scale)


@pytest.mark.parametrize(
    "record",
    [
        {"rotation": np.eye(3).tolist(), "center": [0, 0, 0]},
        {"rotation": "eye", "center": [0, 0, 0], "scale": 1.0},
        {"rotation": np.eye(3).tolist(), "center": [0, 0, 0], "scale": -1.0},
        None,
    ],
)
def test_from_dict_rejects_malformed_records(record):
    with pytest.raises(ArtifactError):
        Transform.from_dict(record)  # type: ignore[arg-type]


def test_apply_rejects_wrong_width():
    with pytest.raises(ArrayShapeError):
        Transform.identity().apply(np.zeros((4, 2)))


# --------------------------------------------------------------------------- PCA / bbox


def _spec_rotation(points: np.ndarray) -> np.ndarray:
    """Literal transcription of spec §1.5 (np.cov, eigh, flips, median rule, cross)."""
    centered = points - points.mean(axis=0)
    values, vectors = np.linalg.eigh(np.cov(centered.T))
    for k in range(3):
        if vectors[0, k] < 0:
            vectors[:, k] *= -1
    vectors = vectors[:, np.argsort(values)[::-1]]
    axes = []
    for k in range(2):
        axis = vectors[:, k]
        axes.append(-axis if np.median(centered @ axis) < 0 else axis)
    return np.stack([axes[0], axes[1], np.cross(axes[0], axes[1])])


def test_pca_alignment_matches_spec_transcription():
    for seed in range(5):
        points = (
            _asymmetric_cloud(500, seed)
            @ np.linalg.qr(np.random.default_rng(seed).normal(size=(3, 3)))[0]
        )
        np.testing.assert_allclose(pca_alignment(points), _spec_rotation(points), atol=1e-12)


def test_pca_sign_rule_and_right_handed_frame():
    rotation = pca_alignment(CLOUD)
    aligned = (CLOUD - CLOUD.mean(axis=0)) @ rotation.T
    assert np.linalg.det(rotation) == pytest.approx(1.0)
    np.testing.assert_allclose(rotation @ rotation.T, np.eye(3), atol=1e-12)
    assert (np.median(aligned[:, :2], axis=0) >= 0).all()
    variances = aligned.var(axis=0)
    assert variances[0] > variances[1] > variances[2]


@settings(max_examples=40, deadline=None)
@given(rotation=rotations(), translation=translations, scale=scales)
def test_bbox_canonical_points_are_similarity_invariant(rotation, translation, scale):
    reference = canonicalize_bbox(CLOUD).apply(CLOUD)
    moved = scale * CLOUD @ rotation.T + translation
    transform = canonicalize_bbox(moved)
    np.testing.assert_allclose(transform.apply(moved), reference, atol=1e-9)
    assert transform.scale * scale == pytest.approx(canonicalize_bbox(CLOUD).scale, rel=1e-9)


def test_bbox_sqrt_area_is_constant():
    canonical = canonicalize_bbox(CLOUD).apply(CLOUD)
    dx, dy, dz = np.ptp(canonical, axis=0)
    assert np.sqrt(2 * (dx * dy + dy * dz + dz * dx)) == pytest.approx(BBOX_SQRT_AREA)
    np.testing.assert_allclose(canonical.mean(axis=0), 0.0, atol=1e-12)


def test_coplanar_points_are_accepted():
    rng = np.random.default_rng(0)
    flat = np.column_stack([rng.normal(size=200) * 3, rng.normal(size=200), np.zeros(200)])
    transform = canonicalize_bbox(flat)
    assert np.linalg.det(transform.rotation) == pytest.approx(1.0)
    assert np.isfinite(transform.apply(flat)).all()


@pytest.mark.parametrize(
    "points",
    [
        np.random.default_rng(0).random((3, 3)),  # fewer than 4 points
        np.ones((10, 3)),  # zero extent
        np.outer(np.linspace(-1, 1, 20), [1.0, 2.0, 3.0]) + 5.0,  # collinear
    ],
)
def test_degenerate_inputs_raise(points):
    with pytest.raises(DegenerateShapeError):
        pca_alignment(points)
    with pytest.raises(DegenerateShapeError):
        canonicalize_bbox(points)


def test_non_finite_input_raises():
    points = CLOUD.copy()
    points[3, 1] = np.nan
    with pytest.raises(NonFiniteError):
        canonicalize_bbox(points)


DEVICES = [
    "cpu",
    pytest.param(
        "cuda", marks=pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")
    ),
]


@pytest.mark.parametrize("device", DEVICES)
def test_bbox_many_agrees_with_the_one_cloud_reference(device):
    rng = np.random.default_rng(3)
    # ragged: a batched group (2000 points), a small group (300) and singletons (301, 17)
    sizes = [2000, 301, 2000, 300, 17, 2000, 300] + [2000] * (BATCHED_MIN_CLOUDS - 2)
    clouds = [
        rng.normal(size=(n, 3)) * rng.uniform(0.5, 3.0, size=3) + rng.normal(size=3) * 10
        for n in sizes
    ]
    batch = canonicalize_bbox_many(clouds, device)
    assert batch.clouds.shape == (len(sizes), max(sizes), 3)
    assert batch.clouds.dtype == torch.float32 and batch.clouds.device.type == device
    for cloud, transform, padded in zip(
        clouds, batch.transforms, batch.clouds.cpu().numpy(), strict=True
    ):
        reference = canonicalize_bbox(cloud)
        assert transform.allclose(reference, atol=1e-12)
        n = cloud.shape[0]
        np.testing.assert_allclose(padded[:n], reference.apply(cloud), rtol=0, atol=1e-5)
        np.testing.assert_array_equal(padded[n:], np.broadcast_to(padded[0], padded[n:].shape))


def test_bbox_many_median_sign_rule_uses_the_mean_of_the_middle_two():
    # an even cloud whose two middle projections straddle 0 on the first axis: the mean of
    # the middle two decides the sign, as np.median does (torch.median would take the lower)
    x = np.array([-5.0, -4.0, -3.0, -0.1, 0.3, 1.0, 2.0, 9.0])
    cloud = np.column_stack([x * 3.0, np.sin(np.arange(8.0)), np.cos(np.arange(8.0)) * 0.1])
    cloud = cloud - cloud.mean(axis=0)
    clouds = [cloud + shift for shift in range(BATCHED_MIN_CLOUDS)]  # the batched path
    for transform, moved in zip(canonicalize_bbox_many(clouds).transforms, clouds, strict=True):
        assert transform.allclose(canonicalize_bbox(moved), atol=1e-12)


@pytest.mark.parametrize(
    "points",
    [
        np.ones((10, 3)),  # zero extent
        np.outer(np.linspace(-1, 1, 20), [1.0, 2.0, 3.0]) + 5.0,  # collinear
    ],
)
@pytest.mark.parametrize("copies", [1, BATCHED_MIN_CLOUDS])  # the one-cloud and batched paths
def test_bbox_many_names_the_degenerate_cloud(points, copies):
    good = np.random.default_rng(0).normal(size=(points.shape[0], 3))
    with pytest.raises(DegenerateShapeError, match=r"clouds\[1\]"):
        canonicalize_bbox_many([good, points] + [good] * (copies - 1))


def test_bbox_many_refuses_an_empty_batch_and_bad_clouds():
    with pytest.raises(InputError):
        canonicalize_bbox_many([])
    with pytest.raises(DegenerateShapeError):
        canonicalize_bbox_many([np.zeros((3, 3))])
    with pytest.raises(NonFiniteError):
        canonicalize_bbox_many([np.full((5, 3), np.nan)])


# --------------------------------------------------------------------------- unit area


def test_unit_area_gives_unit_area_and_centres_the_samples():
    vertices, faces = _box_mesh((3.0, 1.0, 0.2))
    vertices = vertices + np.array([10.0, -4.0, 2.0])
    transform = canonicalize_unit_area(vertices, faces, seed=0)
    canonical = transform.apply(vertices)
    assert triangle_areas(canonical, faces).sum() == pytest.approx(1.0)
    np.testing.assert_allclose(transform.center, [10.0, -4.0, 2.0], atol=0.05)
    np.testing.assert_array_equal(transform.rotation, np.eye(3))
    again = canonicalize_unit_area(vertices, faces, seed=0)
    np.testing.assert_array_equal(again.center, transform.center)


def test_unit_area_applies_the_given_rotation():
    vertices, faces = _box_mesh((3.0, 1.0, 0.2))
    rotation = np.linalg.qr(np.random.default_rng(1).normal(size=(3, 3)))[0]
    rotation *= np.sign(np.linalg.det(rotation))
    plain = canonicalize_unit_area(vertices, faces, seed=0)
    rotated = canonicalize_unit_area(vertices, faces, seed=0, rotation=rotation)
    np.testing.assert_allclose(
        rotated.apply(vertices), plain.apply(vertices) @ rotation.T, atol=1e-12
    )


def test_unit_area_rejects_zero_area():
    vertices = np.array([[0.0, 0, 0], [1, 0, 0], [2, 0, 0]])
    with pytest.raises(DegenerateShapeError):
        canonicalize_unit_area(vertices, np.array([[0, 1, 2]]))


# --------------------------------------------------------------------------- Poisson


@pytest.fixture(scope="module")
def sphere_cloud() -> np.ndarray:
    mesh = trimesh.creation.icosphere(subdivisions=3)
    return sample_surface(np.asarray(mesh.vertices), np.asarray(mesh.faces), 8000, 0).points


def test_poisson_scale_is_invariant_to_input_scale(sphere_cloud):
    reference = canonicalize_poisson(sphere_cloud, 500, 0.03835, seed=0)
    moved = 3.0 * sphere_cloud + np.array([1.0, 2.0, -3.0])
    transform = canonicalize_poisson(moved, 500, 0.03835, seed=0)
    np.testing.assert_allclose(transform.apply(moved), reference.apply(sphere_cloud), atol=1e-9)
    assert transform.scale == pytest.approx(reference.scale / 3.0, rel=1e-12)


def test_poisson_reaches_the_target_spacing(sphere_cloud):
    transform = canonicalize_poisson(sphere_cloud, 500, 0.03835, seed=4)
    canonical = transform.apply(sphere_cloud)
    subset = canonical[poisson_disk_subsample(canonical, 500, seed=4)]
    assert mean_nearest_neighbour_distance(subset) == pytest.approx(0.03835, rel=1e-9)
    np.testing.assert_allclose(canonical.mean(axis=0), 0.0, atol=1e-12)


def test_poisson_degenerate_and_invalid_inputs():
    with pytest.raises(DegenerateShapeError):
        canonicalize_poisson(np.ones((100, 3)), 50, 0.1)
    with pytest.raises(DegenerateShapeError):
        canonicalize_poisson(np.ones((10, 3)), 50, 0.1)  # all points kept, zero spacing
    with pytest.raises(InputError):
        canonicalize_poisson(CLOUD, 50, 0.0)


def test_poisson_presets_hold_the_paper_constants():
    assert (POISSON_8K_CLOUD.n_cloud, POISSON_8K_CLOUD.n_poisson) == (8000, 500)
    assert POISSON_8K_CLOUD.target_mean_nn == 0.03835
    assert (POISSON_500_CLOUD.n_poisson, POISSON_500_CLOUD.target_mean_nn) == (50, 0.12121)
    assert POISSON_BROKEN_MESH.n_poisson == 7000
    assert POISSON_BROKEN_MESH.target_mean_nn == 0.01181
    assert POISSON_BROKEN_MESH.subset_is_cloud


def test_calibration_is_scale_free_and_close_to_the_paper():
    mesh = trimesh.creation.icosphere(subdivisions=3)
    vertices, faces = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    target = calibrate_poisson_target([(vertices, faces)], 8000, 500, seed=0)
    rescaled = calibrate_poisson_target([(7.0 * vertices, faces)], 8000, 500, seed=0)
    assert rescaled == pytest.approx(target, rel=1e-9)
    assert target == pytest.approx(POISSON_8K_CLOUD.target_mean_nn, rel=0.1)
    with pytest.raises(EmptyShapeError):
        calibrate_poisson_target([], 8000, 500)


# --------------------------------------------------------------------------- dispatcher


@pytest.fixture(scope="module")
def box_shape() -> Shape:
    return Shape.from_arrays(*_box_mesh((3.0, 1.5, 0.4)))


@pytest.mark.parametrize("method", list(CanonicalizationMethod))
def test_canonicalize_dispatches(box_shape, method):
    transform, canonical = canonicalize(box_shape, method, seed=1)
    assert isinstance(transform, Transform)
    np.testing.assert_array_equal(canonical, transform.apply(box_shape.vertices))
    assert np.isfinite(canonical).all()
    again, _ = canonicalize(box_shape, method.value, seed=1)
    assert again.allclose(transform, atol=0.0)


def test_canonicalize_unit_area_and_poisson_on_meshes(box_shape):
    _, canonical = canonicalize(box_shape, "unit_area")
    assert triangle_areas(canonical, box_shape.faces).sum() == pytest.approx(1.0)
    unit_area_scale = 1.0 / np.sqrt(box_shape.area)
    for setting in (POISSON_8K_CLOUD, POISSON_BROKEN_MESH):
        transform, _ = canonicalize(box_shape, "poisson", poisson=setting)
        # Paper targets and our sampler agree to ~25 %, so the scale is near unit-area's.
        assert transform.scale == pytest.approx(unit_area_scale, rel=0.3)


def test_canonicalize_broken_mesh_uses_the_poisson_subset_as_cloud(box_shape):
    setting = PoissonScaleSetting(
        "test", n_cloud=4000, n_poisson=500, target_mean_nn=0.05, subset_is_cloud=True
    )
    transform, _ = canonicalize(box_shape, "poisson", poisson=setting, seed=3)
    rng = np.random.default_rng(3)  # replays the dispatcher's random stream
    cloud = sample_surface(box_shape.vertices, box_shape.faces, 4000, rng).points
    subset = cloud[poisson_disk_subsample(cloud, 500, rng)]
    np.testing.assert_allclose(transform.center, subset.mean(axis=0), atol=1e-12)
    assert mean_nearest_neighbour_distance(transform.apply(subset)) == pytest.approx(0.05)


def test_canonicalize_point_cloud_poisson_matches_the_function(sphere_cloud):
    """The dispatcher spreads the cloud evenly first (an even cloud stays as it is)."""
    shape = Shape.from_arrays(sphere_cloud)
    transform, canonical = canonicalize(shape, "poisson", poisson=POISSON_8K_CLOUD, seed=2)
    direct = canonicalize_poisson(sphere_cloud, 500, POISSON_8K_CLOUD.target_mean_nn, seed=2)
    assert transform.allclose(direct, atol=0.0)
    np.testing.assert_array_equal(canonical, direct.apply(sphere_cloud))


def test_canonicalize_rejects_bad_requests(box_shape):
    cloud = box_shape.as_point_cloud()
    with pytest.raises(EmptyShapeError):
        canonicalize(cloud, "unit_area")
    with pytest.raises(InputError):
        canonicalize(box_shape, "sphere")
    with pytest.raises(InputError):
        canonicalize(box_shape, "bbox", rotation=np.eye(3))
    tiny = Shape.from_arrays(np.random.default_rng(0).random((3, 3)))
    with pytest.raises(DegenerateShapeError):
        canonicalize(tiny, "bbox")


def test_poisson_frame_of_a_cloud_leaves_its_stray_points_out(sphere_cloud):
    """A scan's stray points (far from the surface) would pull the centre and the spacing;
    the matching frame of the cloud with them equals the clean cloud's."""
    from litege_core.canonical import poisson_frame

    shell = np.random.default_rng(5).normal(size=(200, 3))  # 2.5 % strays, far out
    stray = shell * (4.0 / np.linalg.norm(shell, axis=1, keepdims=True))
    clean = poisson_frame(Shape.from_arrays(sphere_cloud), POISSON_8K_CLOUD, seed=2)
    noisy = poisson_frame(
        Shape.from_arrays(np.concatenate([sphere_cloud, stray])), POISSON_8K_CLOUD, seed=2
    )
    assert noisy[0].allclose(clean[0], atol=0.0)
    np.testing.assert_array_equal(noisy[1], clean[1])
    assert not np.allclose(np.concatenate([sphere_cloud, stray]).mean(0), clean[0].center)
