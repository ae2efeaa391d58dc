"""Informative-voxel statistics against a direct np.std over stacked occupancies."""

from __future__ import annotations

import numpy as np
import pytest

from litege_core.descriptor.grid import VoxelGrid
from litege_core.descriptor.informative import (
    OccupancyStatistics,
    frequency_band,
    occupancy_std_reference,
    std_to_variance,
    variance_to_std,
)
from litege_core.errors import ArrayShapeError, InputError


def _random_occupancies(grid: VoxelGrid, n: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    p = rng.uniform(0, 1, grid.n_voxels) ** 3  # many rarely-occupied voxels, like real data
    return rng.uniform(size=(n, grid.n_voxels)) < p


def test_streamed_std_matches_numpy_std() -> None:
    grid = VoxelGrid(resolution=10, pitch=0.1)
    occ = _random_occupancies(grid, 37)
    stats = OccupancyStatistics(grid)
    stats.add(occ[0])
    stats.add(occ[1].reshape(grid.shape))
    stats.add_batch(occ[2:20])
    stats.add_batch(occ[20:].reshape(-1, *grid.shape))
    assert stats.n_shapes == 37
    assert stats.counts.dtype == np.int32
    np.testing.assert_array_equal(stats.counts, occ.sum(axis=0))
    reference = occupancy_std_reference(occ)
    np.testing.assert_allclose(stats.std(), reference, atol=1e-12)
    for threshold in (0.0, 0.1, 0.14, 0.3, 0.45):
        ref_sel = np.flatnonzero(reference > threshold + 1e-12)
        sel = stats.select(threshold)
        # equal away from ties at the threshold itself
        ties = np.flatnonzero(np.abs(reference - threshold) < 1e-12)
        assert set(ref_sel) <= set(sel) <= set(ref_sel) | set(ties)
        assert np.all(np.diff(sel) > 0) and sel.dtype == np.int64


def test_merge_equals_single_accumulator() -> None:
    grid = VoxelGrid(resolution=6, pitch=0.1)
    occ = _random_occupancies(grid, 12, seed=3)
    a, b, whole = OccupancyStatistics(grid), OccupancyStatistics(grid), OccupancyStatistics(grid)
    a.add_batch(occ[:5])
    b.add_batch(occ[5:])
    whole.add_batch(occ)
    a.merge(b)
    np.testing.assert_array_equal(a.counts, whole.counts)
    assert a.n_shapes == 12
    with pytest.raises(InputError):
        a.merge(OccupancyStatistics(VoxelGrid(resolution=5, pitch=0.1)))


def test_variance_std_band_helpers() -> None:
    assert std_to_variance(0.14) == pytest.approx(0.0196)
    assert variance_to_std(0.0196) == pytest.approx(0.14)
    # spec §2.3 table
    for std, low in ((0.16, 0.026), (0.12, 0.015), (0.10, 0.010), (0.14, 0.020), (0.25, 0.067)):
        p0, p1 = frequency_band(std)
        assert p0 == pytest.approx(low, abs=6e-4) and p1 == pytest.approx(1 - p0)
        assert np.sqrt(p0 * (1 - p0)) == pytest.approx(std)


def test_band_agrees_with_selection() -> None:
    grid = VoxelGrid(resolution=8, pitch=0.1)
    occ = _random_occupancies(grid, 200, seed=5)
    stats = OccupancyStatistics(grid)
    stats.add_batch(occ)
    p0, p1 = frequency_band(0.14)
    p = stats.frequency()
    np.testing.assert_array_equal(stats.select(0.14), np.flatnonzero((p > p0) & (p < p1)))


def test_invalid_inputs() -> None:
    grid = VoxelGrid(resolution=4, pitch=0.1)
    stats = OccupancyStatistics(grid)
    with pytest.raises(InputError):
        stats.std()  # nothing added
    with pytest.raises(ArrayShapeError):
        stats.add(np.zeros(63, dtype=bool))
    with pytest.raises(ArrayShapeError):
        stats.add(np.full(64, 2))
    with pytest.raises(ArrayShapeError):
        stats.add_batch(np.zeros(64, dtype=bool))
    stats.add(np.ones(64, dtype=np.uint8))  # 0/1 integers are accepted
    for bad in (-0.1, 0.6):
        with pytest.raises(InputError):
            stats.select(bad)
    with pytest.raises(InputError):
        variance_to_std(0.3)
