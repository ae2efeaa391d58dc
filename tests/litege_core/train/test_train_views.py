import numpy as np
import pytest
import torch

from litege_core.canonical import canonicalize_bbox
from litege_core.datasets import GeodesicDataset
from litege_core.descriptor import UdfPcaBasis
from litege_core.errors import InputError
from litege_core.train.augment import AUGMENTED, CLEAN, augmented_view, axis_turn, clean_view
from litege_core.train.config import AugmentConfig
from litege_core.train.data import build_view_tables, load_split_arrays, make_views
from litege_core.variants import random_rotation


@pytest.fixture(scope="module")
def train_split(toy_dataset):
    dataset = GeodesicDataset(toy_dataset)
    return dataset, load_split_arrays(dataset, "train")


def test_descriptor_and_canonical_vertices_absorb_a_rotation(train_split, toy_basis_path):
    dataset, arrays = train_split
    basis = UdfPcaBasis.load(toy_basis_path)
    vertices = arrays["vertices"][1].astype(np.float64)
    view = clean_view(vertices, dataset.faces, 400, np.random.default_rng(0))
    rotation = random_rotation(5)
    plain = canonicalize_bbox(view.points)
    turned = canonicalize_bbox(view.points @ rotation.T)
    np.testing.assert_allclose(
        turned.apply(vertices @ rotation.T), plain.apply(vertices), atol=1e-9
    )
    assert turned.scale == pytest.approx(plain.scale, rel=1e-12)
    codes = basis.describe_batch([plain.apply(view.points), turned.apply(view.points @ rotation.T)])
    torch.testing.assert_close(codes[0], codes[1], atol=1e-4, rtol=1e-4)


def test_augmented_views_are_seeded_and_within_settings(train_split):
    dataset, arrays = train_split
    vertices = arrays["vertices"][0].astype(np.float64)
    settings = AugmentConfig(
        min_points=300, max_points=8000, noise_probability=1.0, cut_probability=1.0
    )
    area = float(arrays["area"][0])
    first = augmented_view(vertices, dataset.faces, area, settings, np.random.default_rng(7))
    again = augmented_view(vertices, dataset.faces, area, settings, np.random.default_rng(7))
    np.testing.assert_array_equal(first.points, again.points)
    assert first.kind == AUGMENTED
    assert 0.10 <= first.cut_fraction <= 0.15
    assert first.noise_sigma == pytest.approx(0.01 * np.sqrt(area))
    assert 255 <= first.points.shape[0] <= 8000
    np.testing.assert_allclose(first.rotation @ first.rotation.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(first.rotation) == pytest.approx(1.0)
    counts = [
        augmented_view(
            vertices,
            dataset.faces,
            area,
            AugmentConfig(cut_probability=0.0),
            np.random.default_rng(s),
        ).points.shape[0]
        for s in range(40)
    ]
    assert min(counts) >= 300 and max(counts) <= 8000 and np.median(counts) < 3000


def test_view_tables_layout(train_split, toy_basis_path):
    dataset, arrays = train_split
    basis = UdfPcaBasis.load(toy_basis_path)

    def build(**chunking):
        return build_view_tables(
            arrays,
            dataset.faces,
            basis,
            n_views=3,
            clean_samples=400,
            augment=AugmentConfig(min_points=200, max_points=800),
            seed=1,
            **chunking,
        )

    tables = build(chunk=5)
    n_shapes, n_vertices = arrays["vertices"].shape[:2]
    assert tables.n_views == 3 * n_shapes and tables.n_shapes == n_shapes
    assert tables.descriptors.shape == (3 * n_shapes, basis.n_components)
    assert tables.vertices.shape == (3 * n_shapes, n_vertices, 3)
    assert tables.vertices.dtype == torch.float32
    assert tables.shape.tolist() == [s for s in range(n_shapes) for _ in range(3)]
    assert tables.kind.tolist() == [CLEAN, AUGMENTED, AUGMENTED] * n_shapes
    assert tables.distances.dtype == torch.float16 and tables.residual.shape == (3 * n_shapes,)
    # view 0 of shape 2 equals a direct recomputation
    views = make_views(
        arrays["vertices"][2].astype(np.float64),
        dataset.faces,
        float(arrays["area"][2]),
        3,
        400,
        AugmentConfig(min_points=200, max_points=800),
        1,
        int(arrays["seed"][2]),
    )
    transform = canonicalize_bbox(views[0].points)
    np.testing.assert_allclose(
        tables.vertices[6].numpy(), transform.apply(arrays["vertices"][2]), atol=1e-5
    )
    assert float(tables.scale[6]) == pytest.approx(transform.scale, rel=1e-6)
    expected = basis.describe(transform.apply(views[0].points))
    np.testing.assert_allclose(tables.descriptors[6].numpy(), expected, atol=1e-5)
    # a second build is identical (deterministic seeds everywhere); another chunking changes
    # the matmul batch shapes, so only float32 rounding may differ
    again = build(chunk=5)
    rechunked = build()
    torch.testing.assert_close(rechunked.descriptors, tables.descriptors, rtol=1e-5, atol=1e-6)
    assert torch.equal(again.descriptors, tables.descriptors)
    assert torch.equal(again.vertices, tables.vertices)


def test_frame_jitter_turns_the_canonical_frame_of_augmented_views(train_split, toy_basis_path):
    dataset, arrays = train_split
    basis = UdfPcaBasis.load(toy_basis_path)
    vertices = arrays["vertices"][0].astype(np.float64)
    area = float(arrays["area"][0])
    plain = AugmentConfig(min_points=200, max_points=800)
    jittered = AugmentConfig(min_points=200, max_points=800, frame_jitter_degrees=12.0)
    # the jitter is drawn last: the view itself is the one drawn without it
    before = augmented_view(vertices, dataset.faces, area, plain, np.random.default_rng(3))
    after = augmented_view(vertices, dataset.faces, area, jittered, np.random.default_rng(3))
    np.testing.assert_array_equal(after.points, before.points)
    assert before.frame is None
    angles = []
    for seed in range(60):
        view = augmented_view(vertices, dataset.faces, area, jittered, np.random.default_rng(seed))
        np.testing.assert_allclose(view.frame @ view.frame.T, np.eye(3), atol=1e-12)
        assert np.linalg.det(view.frame) == pytest.approx(1.0)
        angles.append(np.degrees(np.arccos(np.clip((np.trace(view.frame) - 1) / 2, -1, 1))))
    assert max(angles) <= 12.0 + 1e-9 and min(angles) < 3.0 < 9.0 < max(angles)

    def build(augment):
        return build_view_tables(
            arrays, dataset.faces, basis, n_views=2, clean_samples=400, augment=augment, seed=1
        )

    straight, turned = build(plain), build(jittered)
    assert torch.equal(straight.vertices[0], turned.vertices[0])  # the clean view: no jitter
    assert torch.equal(straight.scale, turned.scale)  # distances are unchanged
    # view 1 (augmented): canonical vertices and descriptor both in the turned frame
    views = make_views(vertices, dataset.faces, area, 2, 400, jittered, 1, int(arrays["seed"][0]))
    frame = views[1].frame
    np.testing.assert_allclose(
        turned.vertices[1].numpy(), straight.vertices[1].numpy() @ frame.T, atol=1e-5
    )
    transform = canonicalize_bbox(views[1].points)
    expected = basis.describe(transform.apply(views[1].points) @ frame.T)
    np.testing.assert_allclose(turned.descriptors[1].numpy(), expected, atol=1e-5)
    assert not np.allclose(turned.descriptors[1].numpy(), straight.descriptors[1].numpy())


def test_axis_turn_is_a_quarter_turn_about_the_first_axis():
    quarter = axis_turn(1)
    np.testing.assert_array_equal(quarter @ [1.0, 0.0, 0.0], [1.0, 0.0, 0.0])
    np.testing.assert_array_equal(quarter @ [0.0, 1.0, 0.0], [0.0, 0.0, 1.0])
    np.testing.assert_array_equal(axis_turn(2), np.diag([1.0, -1.0, -1.0]))
    np.testing.assert_array_equal(axis_turn(3) @ quarter, np.eye(3))
    np.testing.assert_array_equal(axis_turn(4), np.eye(3))


def test_axis_turns_turn_that_share_of_augmented_views(train_split):
    dataset, arrays = train_split
    vertices = arrays["vertices"][0].astype(np.float64)
    area = float(arrays["area"][0])
    plain = AugmentConfig(min_points=200, max_points=400)
    turning = AugmentConfig(min_points=200, max_points=400, axis_turn_probability=0.5)
    before = augmented_view(vertices, dataset.faces, area, plain, np.random.default_rng(3))
    after = augmented_view(vertices, dataset.faces, area, turning, np.random.default_rng(3))
    np.testing.assert_array_equal(after.points, before.points)  # drawn last: same cloud
    quarters = []
    for seed in range(80):
        view = augmented_view(vertices, dataset.faces, area, turning, np.random.default_rng(seed))
        if view.frame is None:
            quarters.append(0)
            continue
        matches = [k for k in (1, 2, 3) if np.array_equal(view.frame, axis_turn(k))]
        assert len(matches) == 1  # an exact quarter, half or three-quarter turn
        quarters.append(matches[0])
    counts = np.bincount(quarters, minlength=4)
    assert 25 <= counts[0] <= 55 and all(counts[1:] >= 5)
    # with jitter too: the turn follows the jitter
    both = AugmentConfig(
        min_points=200, max_points=400, frame_jitter_degrees=5.0, axis_turn_probability=1.0
    )
    view = augmented_view(vertices, dataset.faces, area, both, np.random.default_rng(0))
    jitter_only = AugmentConfig(min_points=200, max_points=400, frame_jitter_degrees=5.0)
    jitter = augmented_view(vertices, dataset.faces, area, jitter_only, np.random.default_rng(0))
    turns = [axis_turn(k) @ jitter.frame for k in (1, 2, 3)]
    assert any(np.allclose(view.frame, turn, atol=1e-12) for turn in turns)


def test_frame_jitter_bounds():
    with pytest.raises(InputError, match="frame_jitter_degrees"):
        AugmentConfig(frame_jitter_degrees=-1.0)
    with pytest.raises(InputError, match="frame_jitter_degrees"):
        AugmentConfig(frame_jitter_degrees=120.0)
    with pytest.raises(InputError, match="axis_turn_probability"):
        AugmentConfig(axis_turn_probability=1.5)
