"""VoxelGrid: centres, flattening order, point lookup, serialisation, validation."""

from __future__ import annotations

import numpy as np
import pytest

from litege_core.descriptor.grid import VoxelGrid
from litege_core.errors import ArrayShapeError, IndexOutOfRangeError, InputError, NonFiniteError


def test_default_grid_is_the_authors_grid() -> None:
    grid = VoxelGrid()
    assert (grid.resolution, grid.pitch) == (121, 0.02)
    assert grid.n_voxels == 1_771_561
    axis = grid.axis_centers()
    np.testing.assert_allclose(axis, np.arange(-60, 61) * 0.02, atol=1e-15)
    assert axis[60] == 0.0
    assert grid.lower == pytest.approx(-1.21) and grid.upper == pytest.approx(1.21)


def test_centers_are_x_major_like_meshgrid_ij() -> None:
    grid = VoxelGrid(resolution=5, pitch=0.3)
    axis = grid.axis_centers()
    x, y, z = np.meshgrid(axis, axis, axis, indexing="ij")
    expected = np.stack([x.ravel(), y.ravel(), z.ravel()], axis=1)
    np.testing.assert_array_equal(grid.centers(), expected)
    np.testing.assert_array_equal(grid.centers([0, 7, 124]), expected[[0, 7, 124]])
    assert grid.centers(dtype=np.float32).dtype == np.float32


def test_even_resolution_is_centred() -> None:
    grid = VoxelGrid(resolution=4, pitch=0.5)
    np.testing.assert_allclose(grid.axis_centers(), [-0.75, -0.25, 0.25, 0.75])
    np.testing.assert_allclose(grid.centers().mean(axis=0), 0.0, atol=1e-15)


def test_flat_index_and_ijk_round_trip() -> None:
    grid = VoxelGrid(resolution=7, pitch=0.1)
    flat = np.arange(grid.n_voxels)
    ijk = grid.ijk(flat)
    np.testing.assert_array_equal(grid.flat_index(ijk), flat)
    np.testing.assert_array_equal(ijk[8], [0, 1, 1])
    assert grid.flat_index([[1, 2, 3]])[0] == (1 * 7 + 2) * 7 + 3


def test_point_to_voxel_finds_the_containing_voxel() -> None:
    grid = VoxelGrid(resolution=9, pitch=0.25)
    rng = np.random.default_rng(0)
    centers = grid.centers()
    picks = rng.integers(0, grid.n_voxels, 200)
    jitter = rng.uniform(-0.49, 0.49, (200, 3)) * grid.pitch
    np.testing.assert_array_equal(grid.point_to_voxel(centers[picks] + jitter), picks)
    outside = np.array([[grid.upper + 0.01, 0, 0], [0, grid.lower - 1e-9, 0], [5, 5, 5]])
    np.testing.assert_array_equal(grid.point_to_voxel(outside), [-1, -1, -1])


def test_to_dict_round_trip() -> None:
    grid = VoxelGrid(resolution=64, pitch=0.04)
    assert VoxelGrid.from_dict(grid.to_dict()) == grid
    with pytest.raises(InputError):
        VoxelGrid.from_dict({"resolution": 64})


@pytest.mark.parametrize(
    ("resolution", "pitch"), [(0, 0.02), (-3, 0.02), (2.5, 0.02), (True, 0.1), (8, 0.0), (8, -1.0)]
)
def test_invalid_grid_parameters(resolution: object, pitch: float) -> None:
    with pytest.raises(InputError):
        VoxelGrid(resolution=resolution, pitch=pitch)  # type: ignore[arg-type]
    with pytest.raises(InputError):
        VoxelGrid(resolution=8, pitch=float("nan"))


def test_index_validation() -> None:
    grid = VoxelGrid(resolution=4, pitch=0.1)
    with pytest.raises(IndexOutOfRangeError):
        grid.ijk([64])
    with pytest.raises(IndexOutOfRangeError):
        grid.flat_index([[0, 0, 4]])
    with pytest.raises(ArrayShapeError):
        grid.flat_index([[0, 0]])
    with pytest.raises(ArrayShapeError):
        grid.flat_index([[0.0, 1.0, 2.0]])
    with pytest.raises(ArrayShapeError):
        grid.ijk([[1, 2]])
    with pytest.raises(ArrayShapeError):
        grid.point_to_voxel(np.zeros((3, 2)))
    with pytest.raises(NonFiniteError):
        grid.point_to_voxel([[np.nan, 0.0, 0.0]])
