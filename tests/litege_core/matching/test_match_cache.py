"""Tests of litege_core.matching.cache: tiers, neighbour tables, coverage, serialization."""

from __future__ import annotations

import io

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.distance import cdist, pdist

from litege_core.errors import (
    ArrayShapeError,
    ArtifactError,
    EmptyShapeError,
    IndexOutOfRangeError,
    InputError,
    NonFiniteError,
)
from litege_core.matching import DEFAULT_NEIGHBOURS, DEFAULT_TIER_SIZES, NNCache, coverage_radius
from litege_core.sampling import sample_surface


@pytest.fixture(scope="module")
def surface_5k(blob) -> np.ndarray:
    """5000 area-weighted samples of a bent ellipsoid (no symmetric ties)."""
    shape = blob(0, subdivisions=4)
    return sample_surface(np.asarray(shape.vertices), np.asarray(shape.faces), 5000, 0).points


def _cloud(seed: int, n: int) -> np.ndarray:
    return np.random.default_rng(seed).normal(size=(n, 3))


def _check_tables(cache: NNCache, points: np.ndarray) -> None:
    """Every neighbour table holds the true k nearest points of the next tier, nearest first."""
    full = np.arange(points.shape[0])
    for j, (tier, table) in enumerate(zip(cache.tiers, cache.neighbours, strict=True)):
        finer = cache.tiers[j + 1] if j + 1 < len(cache.tiers) else full
        distance = cdist(points[tier], points[finer])
        k = table.shape[1]
        expected = np.sort(distance, axis=1)[:, :k]
        got = np.take_along_axis(distance, table, axis=1)
        np.testing.assert_allclose(got, expected, rtol=0, atol=1e-12)
        assert all(np.unique(row).size == k for row in table)


# --------------------------------------------------------------------------- building


def test_default_fps_cache(surface_5k: np.ndarray) -> None:
    cache = NNCache.build(surface_5k)
    assert cache.tier_sizes == (*DEFAULT_TIER_SIZES, 5000)
    assert cache.neighbour_counts == DEFAULT_NEIGHBOURS
    assert cache.n_tiers == 3
    assert cache.strategy == "fps"
    for array in (*cache.tiers, *cache.neighbours):
        assert array.dtype == np.int64
        assert not array.flags.writeable
    # nested tiers: a prefix of one farthest-point ordering
    np.testing.assert_array_equal(cache.tiers[0], cache.tiers[1][: cache.tier_sizes[0]])
    _check_tables(cache, surface_5k)
    # each point of a tier is its own nearest neighbour in the next (nested) tier
    np.testing.assert_array_equal(cache.tiers[1][cache.neighbours[0][:, 0]], cache.tiers[0])
    np.testing.assert_array_equal(cache.neighbours[1][:, 0], cache.tiers[1])
    assert cache.nbytes == 8 * (60 + 650 + 60 * 65 + 650 * 60)


def test_random_strategy_reproduces_the_reference_sampling(surface_5k: np.ndarray) -> None:
    cache = NNCache.build(surface_5k, strategy="random", seed=7)
    rng = np.random.default_rng(7)
    for tier, size in zip(cache.tiers, DEFAULT_TIER_SIZES, strict=True):
        np.testing.assert_array_equal(tier, rng.choice(5000, size=size, replace=False))
    _check_tables(cache, surface_5k)
    again = NNCache.build(surface_5k, strategy="random", seed=7)
    other = NNCache.build(surface_5k, strategy="random", seed=8)
    np.testing.assert_array_equal(again.neighbours[1], cache.neighbours[1])
    assert not np.array_equal(other.tiers[0], cache.tiers[0])


def test_fps_covers_better_than_random(surface_5k: np.ndarray) -> None:
    """Coverage radius (max distance to the nearest tier point) at equal tier sizes.

    Measured on this 5000-point surface (extent 3.4 × 2.0 × 1.2): FPS 0.378 / 0.108 for
    tiers of 60 / 650; random seeds 0–4: 0.57–0.79 / 0.25–0.28, i.e. FPS is 1.5–2.6× tighter.
    """
    fps = NNCache.build(surface_5k).coverage_radii(surface_5k)
    for seed in range(5):
        random = NNCache.build(surface_5k, strategy="random", seed=seed)
        radii = random.coverage_radii(surface_5k)
        assert np.all(fps * 1.4 < radii), (fps, radii)
    assert fps[1] < fps[0]


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 10_000),
    n_points=st.integers(2, 120),
    sizes=st.lists(st.integers(1, 100), min_size=1, max_size=3, unique=True),
    k=st.integers(1, 12),
    strategy=st.sampled_from(["fps", "random"]),
)
def test_tables_are_exact_knn(
    seed: int, n_points: int, sizes: list[int], k: int, strategy: str
) -> None:
    points = _cloud(seed, n_points)
    sizes = sorted(sizes)
    cache = NNCache.build(points, tier_sizes=sizes, neighbours=k, strategy=strategy, seed=seed)
    kept = tuple(s for s in sizes if s < n_points)
    assert cache.tier_sizes == (*kept, n_points)
    assert cache.neighbour_counts == tuple(min(k, s) for s in cache.tier_sizes[1:])
    for tier in cache.tiers:
        assert np.unique(tier).size == tier.size
        assert tier.min() >= 0 and tier.max() < n_points
    _check_tables(cache, points)
    if strategy == "fps":
        for tier in cache.tiers:
            np.testing.assert_array_equal(tier, cache.tiers[-1][: tier.size])
            # FPS invariant: the covering radius of the first n points is at most the
            # smallest distance between them
            if tier.size > 1:
                assert coverage_radius(points, tier) <= pdist(points[tier]).min() + 1e-12


def test_small_shapes_drop_tiers() -> None:
    points = _cloud(0, 60)
    single = NNCache.build(points)
    assert single.n_tiers == 1 and single.tiers == () and single.tier_sizes == (60,)
    two = NNCache.build(_cloud(0, 100))
    assert two.tier_sizes == (60, 100)
    assert two.neighbour_counts == (65,)  # link j keeps k_j
    clipped = NNCache.build(_cloud(1, 80), tier_sizes=(10, 50), neighbours=(100, 100))
    assert clipped.neighbour_counts == (50, 80)


def test_candidates_restrict_tiers_and_the_last_link() -> None:
    """``candidates``: tiers and the last link's neighbours hold only them (exact k-NN among
    them); all points as candidates build the cache without them; bad candidates are refused."""
    points = _cloud(4, 900)
    excluded = np.arange(0, 900, 7)
    candidates = np.setdiff1d(np.arange(900), excluded)
    cache = NNCache.build(points, candidates=candidates[::-1].copy(), start_index=0)
    assert cache.tier_sizes == (*DEFAULT_TIER_SIZES, 900)
    for tier in (*cache.tiers, cache.neighbours[-1].ravel()):
        assert not np.isin(tier, excluded).any()
    last = cache.neighbours[-1]
    distance = cdist(points[cache.tiers[-1]], points[candidates])
    expected = np.sort(distance, axis=1)[:, : last.shape[1]]
    got = np.linalg.norm(points[cache.tiers[-1]][:, None] - points[last], axis=2)
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-12)
    assert cache.tiers[0][0] == candidates[0]  # start_index 0 is excluded: the first candidate
    plain = NNCache.build(points)
    every = NNCache.build(points, candidates=np.arange(900))
    arrays = zip((*plain.tiers, *plain.neighbours), (*every.tiers, *every.neighbours), strict=True)
    for a, b in arrays:
        np.testing.assert_array_equal(a, b)
    NNCache.from_arrays(cache.to_arrays())  # a valid cache layout
    for bad, error in (
        (np.array([], dtype=np.int64), InputError),
        (np.array([0.5, 1.5]), InputError),
        (np.array([1, 1, 2]), InputError),
        (np.array([[1, 2]]), InputError),
        (np.array([0, 900]), IndexOutOfRangeError),
        (np.array([-1, 3]), IndexOutOfRangeError),
    ):
        with pytest.raises(error):
            NNCache.build(points, candidates=bad)


def test_coverage_radius() -> None:
    points = _cloud(3, 50)
    assert coverage_radius(points, np.arange(50)) == 0.0
    radius = coverage_radius(points, [0])
    assert radius == pytest.approx(np.linalg.norm(points - points[0], axis=1).max())
    with pytest.raises(IndexOutOfRangeError):
        coverage_radius(points, [50])
    with pytest.raises(InputError):
        coverage_radius(points, [])
    with pytest.raises(InputError):
        NNCache.build(points, tier_sizes=(5, 20)).coverage_radii(points[:40])


@pytest.mark.parametrize(
    ("points", "error"),
    [
        (np.zeros((0, 3)), EmptyShapeError),
        (np.zeros((5, 2)), ArrayShapeError),
        (np.array([[0.0, 0.0, np.nan]] * 5), NonFiniteError),
    ],
)
def test_build_rejects_bad_points(points: np.ndarray, error: type[Exception]) -> None:
    with pytest.raises(error):
        NNCache.build(points)


@pytest.mark.parametrize(
    "kwargs",
    [
        {"tier_sizes": (60, 60)},
        {"tier_sizes": (600, 60)},
        {"tier_sizes": (0, 60)},
        {"tier_sizes": (True,)},
        {"neighbours": (10, 10, 10)},
        {"neighbours": 0},
        {"strategy": "poisson"},
        {"seed": 1.5},
    ],
)
def test_build_rejects_bad_configuration(kwargs: dict) -> None:
    with pytest.raises(InputError):
        NNCache.build(_cloud(0, 200), **kwargs)


def test_build_rejects_bad_start_index() -> None:
    with pytest.raises(IndexOutOfRangeError):
        NNCache.build(_cloud(0, 200), start_index=200)


def test_start_index_changes_fps_order() -> None:
    points = _cloud(0, 200)
    cache = NNCache.build(points, tier_sizes=(10, 50), start_index=17)
    assert cache.tiers[0][0] == 17 and cache.start_index == 17


# --------------------------------------------------------------------------- serialization


def _roundtrip_npz(arrays: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    buffer = io.BytesIO()
    np.savez(buffer, **arrays)
    buffer.seek(0)
    with np.load(buffer, allow_pickle=False) as loaded:
        return {key: loaded[key] for key in loaded.files}


@settings(max_examples=25, deadline=None)
@given(
    seed=st.integers(0, 1000),
    n_points=st.integers(1, 150),
    strategy=st.sampled_from(["fps", "random"]),
)
def test_arrays_roundtrip(seed: int, n_points: int, strategy: str) -> None:
    cache = NNCache.build(
        _cloud(seed, n_points), tier_sizes=(8, 40), neighbours=(6, 9), strategy=strategy, seed=seed
    )
    arrays = cache.to_arrays()
    assert all(a.dtype == np.int64 for a in arrays.values())
    restored = NNCache.from_arrays(_roundtrip_npz(arrays))
    assert restored.n_points == cache.n_points
    assert restored.strategy == cache.strategy
    assert restored.seed == cache.seed and restored.start_index == cache.start_index
    assert restored.tier_sizes == cache.tier_sizes
    assert restored.nbytes == cache.nbytes
    before = (*cache.tiers, *cache.neighbours)
    for a, b in zip(before, (*restored.tiers, *restored.neighbours), strict=True):
        np.testing.assert_array_equal(a, b)
        assert not b.flags.writeable


def _corrupt(arrays: dict[str, np.ndarray], case: str) -> dict[str, np.ndarray]:
    arrays = {k: v.copy() for k, v in arrays.items()}
    if case == "missing":
        del arrays["neighbours_1"]
    elif case == "extra":
        arrays["tier_9"] = np.arange(3)
    elif case == "version":
        arrays["meta"][0] = 99
    elif case == "strategy":
        arrays["meta"][3] = 5
    elif case == "meta-float":
        arrays["meta"] = arrays["meta"].astype(np.float64)
    elif case == "neighbour-range":
        arrays["neighbours_0"][0, 0] = 650
    elif case == "negative":
        arrays["neighbours_1"][3, 2] = -1
    elif case == "tier-range":
        arrays["tier_1"][5] = 5000
    elif case == "tier-repeat":
        arrays["tier_1"][5] = arrays["tier_1"][6]
    elif case == "tier-order":
        arrays["tier_0"], arrays["tier_1"] = arrays["tier_1"], arrays["tier_0"]
    elif case == "float-table":
        arrays["neighbours_0"] = arrays["neighbours_0"].astype(np.float32)
    elif case == "table-rows":
        arrays["neighbours_1"] = arrays["neighbours_1"][:-1]
    elif case == "start":
        arrays["meta"][5] = 5000
    return arrays


@pytest.mark.parametrize(
    "case",
    [
        "missing",
        "extra",
        "version",
        "strategy",
        "meta-float",
        "neighbour-range",
        "negative",
        "tier-range",
        "tier-repeat",
        "tier-order",
        "float-table",
        "table-rows",
        "start",
    ],
)
def test_from_arrays_rejects_corrupt_input(surface_5k: np.ndarray, case: str) -> None:
    arrays = NNCache.build(surface_5k).to_arrays()
    NNCache.from_arrays(arrays)  # the uncorrupted arrays load
    with pytest.raises(ArtifactError):
        NNCache.from_arrays(_corrupt(arrays, case))


def test_tensors_are_memoized_per_device(surface_5k: np.ndarray) -> None:
    cache = NNCache.build(surface_5k)
    tiers, tables = cache.tensors("cpu")
    assert cache.tensors(torch.device("cpu"))[0] is tiers
    for tensor, array in zip((*tiers, *tables), (*cache.tiers, *cache.neighbours), strict=True):
        assert tensor.dtype == torch.int64
        np.testing.assert_array_equal(tensor.numpy(), array)
