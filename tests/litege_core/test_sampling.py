"""Tests of litege_core.sampling: surface samples, farthest-point and Poisson-disk subsets."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial import cKDTree
from scipy.spatial.distance import pdist

from litege_core.errors import (
    ArrayShapeError,
    DegenerateShapeError,
    EmptyShapeError,
    IndexOutOfRangeError,
    InputError,
    NonFiniteError,
)
from litege_core.sampling import (
    _farthest_point_sampling_reference,
    as_points,
    farthest_point_sampling,
    mean_nearest_neighbour_distance,
    poisson_disk_subsample,
    sample_surface,
)


@pytest.fixture(scope="module")
def sphere() -> tuple[np.ndarray, np.ndarray]:
    mesh = trimesh.creation.icosphere(subdivisions=3)
    return np.asarray(mesh.vertices) / np.sqrt(mesh.area), np.asarray(mesh.faces)


@pytest.fixture(scope="module")
def cloud_8k(sphere: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    return sample_surface(*sphere, 8000, seed=0).points


# --------------------------------------------------------------------------- sample_surface


def test_sample_surface_points_lie_on_their_faces(sphere):
    vertices, faces = sphere
    samples = sample_surface(vertices, faces, 500, seed=3)
    assert samples.points.shape == (500, 3)
    assert samples.face_index.dtype == np.int64
    np.testing.assert_allclose(samples.barycentric.sum(axis=1), 1.0)
    assert (samples.barycentric >= 0).all()
    corners = vertices[faces[samples.face_index]]
    np.testing.assert_allclose(
        np.einsum("nk,nkd->nd", samples.barycentric, corners), samples.points
    )


def test_sample_surface_is_deterministic_per_seed(sphere):
    a = sample_surface(*sphere, 100, seed=1).points
    b = sample_surface(*sphere, 100, seed=1).points
    c = sample_surface(*sphere, 100, seed=2).points
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)


@pytest.mark.parametrize("seed", [-1, 1.5, "0"])
def test_bad_seeds_are_input_errors(sphere, seed):
    """A negative or non-integer seed is an InputError, not numpy's ValueError."""
    with pytest.raises(InputError, match="seed must be a non-negative integer"):
        sample_surface(*sphere, 10, seed=seed)
    with pytest.raises(InputError, match="seed must be a non-negative integer"):
        poisson_disk_subsample(sphere[0], 10, seed=seed)


# --------------------------------------------------------------------------- as_points


@pytest.mark.parametrize(
    ("value", "error"),
    [
        (np.zeros((4, 2)), ArrayShapeError),
        (np.zeros(3), ArrayShapeError),
        ([["a", "b", "c"]], ArrayShapeError),
        (np.zeros((0, 3)), EmptyShapeError),
        (np.array([[0.0, np.nan, 0.0]]), NonFiniteError),
    ],
)
def test_as_points_rejects_bad_arrays(value, error):
    with pytest.raises(error):
        as_points(value)


def test_as_points_enforces_min_points():
    with pytest.raises(DegenerateShapeError):
        as_points(np.zeros((3, 3)), min_points=4)
    out = as_points([[1, 2, 3]])
    assert out.dtype == np.float64 and out.flags.c_contiguous


# --------------------------------------------------------------------------- farthest point


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    n_points=st.integers(1, 120),
    fraction=st.floats(0.0, 1.0),
    duplicates=st.booleans(),
)
def test_fps_matches_reference(seed, n_points, fraction, duplicates):
    rng = np.random.default_rng(seed)
    points = rng.normal(size=(n_points, 3)) * rng.uniform(0.1, 10.0, size=3)
    if duplicates:  # exact ties and zero distances
        points = np.round(points[rng.integers(0, n_points, n_points)], 1)
    n_samples = round(fraction * n_points)
    start = int(rng.integers(0, n_points))
    fast = farthest_point_sampling(points, n_samples, start)
    slow = _farthest_point_sampling_reference(points, n_samples, start)
    np.testing.assert_array_equal(fast, slow)
    assert fast.dtype == np.int64
    assert len(np.unique(fast)) == n_samples  # distinct even with duplicate points


def test_fps_is_greedy_max_min():
    points = np.random.default_rng(0).random((300, 3))
    chosen = farthest_point_sampling(points, 10, start_index=7)
    assert chosen[0] == 7
    for k in range(1, 10):
        d = np.linalg.norm(points[:, None] - points[chosen[:k]][None], axis=2).min(axis=1)
        assert d[chosen[k]] == pytest.approx(d.max())


def test_fps_bounds():
    points = np.random.default_rng(0).random((5, 3))
    assert farthest_point_sampling(points, 0).shape == (0,)
    assert sorted(farthest_point_sampling(points, 5)) == [0, 1, 2, 3, 4]
    with pytest.raises(ArrayShapeError):
        farthest_point_sampling(points, 6)
    with pytest.raises(ArrayShapeError):
        farthest_point_sampling(points, -1)
    with pytest.raises(IndexOutOfRangeError):
        farthest_point_sampling(points, 2, start_index=5)


# --------------------------------------------------------------------------- Poisson disk


@pytest.mark.parametrize("n_target", [50, 500])
def test_poisson_is_blue_noise(cloud_8k, n_target):
    chosen = poisson_disk_subsample(cloud_8k, n_target, seed=0)
    random = np.random.default_rng(0).choice(len(cloud_8k), size=len(chosen), replace=False)
    poisson_min = pdist(cloud_8k[chosen]).min()
    assert poisson_min > 3.0 * pdist(cloud_8k[random]).min()
    # Maximal: every candidate is closer to a kept point than kept points are to each other.
    cover = cKDTree(cloud_8k[chosen]).query(cloud_8k)[0].max()
    assert cover < poisson_min


@pytest.mark.parametrize(("n_target", "seed"), [(50, 0), (50, 1), (500, 0), (500, 2), (2000, 0)])
def test_poisson_count_within_tolerance(cloud_8k, n_target, seed):
    chosen = poisson_disk_subsample(cloud_8k, n_target, seed=seed)
    assert abs(len(chosen) - n_target) <= max(1, n_target // 100)
    assert chosen.dtype == np.int64
    assert np.all(np.diff(chosen) > 0)  # sorted, distinct


def test_poisson_is_deterministic_and_seeded(cloud_8k):
    a = poisson_disk_subsample(cloud_8k, 200, seed=5)
    b = poisson_disk_subsample(cloud_8k, 200, seed=5)
    c = poisson_disk_subsample(cloud_8k, 200, seed=6)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)


def test_poisson_is_similarity_invariant(cloud_8k):
    rotation = np.linalg.qr(np.random.default_rng(0).normal(size=(3, 3)))[0]
    moved = 3.0 * cloud_8k @ rotation.T + np.array([5.0, -1.0, 2.0])
    np.testing.assert_array_equal(
        poisson_disk_subsample(moved, 300, seed=1), poisson_disk_subsample(cloud_8k, 300, seed=1)
    )


def test_poisson_small_inputs():
    points = np.random.default_rng(0).random((30, 3))
    np.testing.assert_array_equal(poisson_disk_subsample(points, 30), np.arange(30))
    np.testing.assert_array_equal(poisson_disk_subsample(points, 100), np.arange(30))
    assert len(poisson_disk_subsample(points, 1)) == 1
    with pytest.raises(ArrayShapeError):
        poisson_disk_subsample(points, 0)
    with pytest.raises(DegenerateShapeError):
        poisson_disk_subsample(np.ones((10, 3)), 5)


def test_poisson_with_few_distinct_points_returns_closest_count():
    distinct = np.random.default_rng(0).random((20, 3))
    points = np.repeat(distinct, 10, axis=0)  # 200 candidates, 20 distinct
    chosen = poisson_disk_subsample(points, 50)
    assert len(chosen) == 20
    assert len(np.unique(points[chosen], axis=0)) == 20


# --------------------------------------------------------------------------- mean 1-NN


def test_mean_nearest_neighbour_distance_of_grid():
    grid = np.stack(np.meshgrid(*[np.arange(4.0)] * 3, indexing="ij"), axis=-1).reshape(-1, 3)
    assert mean_nearest_neighbour_distance(0.5 * grid) == pytest.approx(0.5)
    assert mean_nearest_neighbour_distance([[0, 0, 0], [0, 0, 2.0]]) == pytest.approx(2.0)
    with pytest.raises(DegenerateShapeError):
        mean_nearest_neighbour_distance([[0.0, 0.0, 0.0]])


def test_isolated_points_are_the_strays_far_from_the_sampled_surface():
    from litege_core.sampling import isolated_points

    rng = np.random.default_rng(0)
    sphere = rng.normal(size=(2000, 3))
    sphere /= np.linalg.norm(sphere, axis=1, keepdims=True)
    assert not isolated_points(sphere).any()  # a clean cloud: none
    noisy = sphere + rng.normal(0.0, 0.02, sphere.shape)  # noise is not straying
    assert not isolated_points(noisy).any()
    strays = np.array([[3.0, 0.0, 0.0], [0.0, -2.5, 0.5], [1.2, 1.2, 1.2]])
    flagged = isolated_points(np.concatenate([sphere, strays]))
    np.testing.assert_array_equal(np.flatnonzero(flagged), [2000, 2001, 2002])
    # too few points to tell, or half of them or more flagged: none
    assert not isolated_points(np.concatenate([sphere[:6], strays])).any()
    lattice = np.stack(np.meshgrid(*[np.arange(6.0)] * 3), axis=-1).reshape(-1, 3)
    assert not isolated_points(lattice, k=1, factor=0.5).any()  # every point would be
    repeated = np.concatenate([np.repeat(sphere[:100], 20, axis=0), sphere[100:]])
    assert not isolated_points(repeated).any()  # median spacing 0: nothing to measure against


def test_evenly_spread_thins_dense_parts_to_the_typical_spacing():
    from litege_core.sampling import evenly_spread, isolated_points

    rng = np.random.default_rng(3)
    sphere = rng.normal(size=(6000, 3))
    sphere /= np.linalg.norm(sphere, axis=1, keepdims=True)
    uniform = sphere[:2000]
    np.testing.assert_array_equal(evenly_spread(uniform, seed=1), uniform)  # even: as it is
    # the upper half ten times denser than the lower one: about even afterwards
    upper, lower = sphere[sphere[:, 2] > 0][:2000], sphere[sphere[:, 2] <= 0][:200]
    uneven = np.concatenate([upper, lower])
    spread = evenly_spread(uneven, seed=1)
    assert np.isin(spread, uneven).all(axis=1).all()
    ratio = np.count_nonzero(spread[:, 2] > 0) / np.count_nonzero(spread[:, 2] <= 0)
    assert ratio < 2.0  # was 10
    np.testing.assert_array_equal(spread, evenly_spread(uneven, seed=1))  # seeded
    assert not np.array_equal(spread, evenly_spread(uneven, seed=2))
    # stray points are dropped, and take no draw: the rest spreads as without them
    strays = np.array([[3.0, 0.0, 0.0], [0.0, -2.5, 0.5]])
    np.testing.assert_array_equal(evenly_spread(np.concatenate([uneven, strays]), 1), spread)
    shell = rng.normal(size=(40, 3))  # 2 % strays on a far shell: the probe sees them
    shell *= 3.0 / np.linalg.norm(shell, axis=1, keepdims=True)
    np.testing.assert_array_equal(evenly_spread(np.concatenate([uniform, shell])), uniform)
    # too few points to judge the spacing by: not thinned (only strays left out)
    sparse = np.concatenate([upper[:400], lower[:40]])
    np.testing.assert_array_equal(evenly_spread(sparse, seed=1), sparse[~isolated_points(sparse)])
    assert np.count_nonzero(isolated_points(sparse)) < 10
    # a cloud sent twice is the cloud: one sample per position
    np.testing.assert_array_equal(evenly_spread(np.concatenate([uniform, uniform])), uniform)
    tiny = uniform[:9]
    assert evenly_spread(tiny) is tiny
