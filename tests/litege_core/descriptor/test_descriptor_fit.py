"""End-to-end fit_basis on small random primitives."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from litege_core.descriptor.fit import fit_basis, udf_samples
from litege_core.descriptor.grid import VoxelGrid
from litege_core.descriptor.informative import OccupancyStatistics
from litege_core.descriptor.occupancy import mesh_occupancy
from litege_core.descriptor.pca import fit_pca_exact
from litege_core.descriptor.udf import udf_kdtree
from litege_core.errors import InputError
from litege_core.shape import Shape

GRID = VoxelGrid(resolution=61, pitch=0.04)  # the authors' extent at half the resolution


def random_shapes(n: int, seed: int = 0) -> list[tuple[np.ndarray, np.ndarray]]:
    """Primitives with random anisotropic scale, rotation and translation inside ±0.9."""
    rng = np.random.default_rng(seed)
    makers = [
        lambda: trimesh.creation.icosphere(subdivisions=2, radius=0.5),
        lambda: trimesh.creation.box(extents=[0.8, 0.8, 0.8]),
        lambda: trimesh.creation.capsule(height=0.6, radius=0.25, count=[8, 8]),
        lambda: trimesh.creation.cylinder(radius=0.35, height=0.8, sections=16),
        lambda: trimesh.creation.torus(0.4, 0.15, major_sections=16, minor_sections=8),
    ]
    shapes = []
    for i in range(n):
        mesh = makers[i % len(makers)]()
        mesh.apply_scale(rng.uniform(0.6, 1.4, 3))
        mesh.apply_transform(trimesh.transformations.random_rotation_matrix(rng.random(3)))
        mesh.apply_translation(rng.uniform(-0.15, 0.15, 3))
        shapes.append((np.asarray(mesh.vertices), np.asarray(mesh.faces)))
    return shapes


@pytest.fixture(scope="module")
def shapes() -> list[tuple[np.ndarray, np.ndarray]]:
    return random_shapes(40)


def test_fit_basis_end_to_end(shapes) -> None:
    basis = fit_basis(
        iter(shapes), GRID, std_threshold=0.14, n_components=12, n_udf_samples=500, seed=7
    )
    meta = basis.metadata
    assert basis.n_fit_shapes == 40 and basis.n_components == 12
    assert meta["n_informative_voxels"] == basis.n_voxels > 1000
    assert meta["frequency_band"][0] == pytest.approx(0.02, abs=1e-3)

    # the same selection, recomputed directly
    stats = OccupancyStatistics(GRID)
    for v, f in shapes:
        stats.add(mesh_occupancy(v, f, GRID))
    np.testing.assert_array_equal(stats.select(0.14), basis.voxel_indices)

    # the same spectrum as an exact PCA of the UDF rows
    centers = GRID.centers(basis.voxel_indices)
    rows = np.stack(
        [
            udf_kdtree(udf_samples(v, f, 500, np.random.default_rng([7, i])), centers)
            for i, (v, f) in enumerate(shapes)
        ]
    )
    exact = fit_pca_exact(rows, 12)
    np.testing.assert_allclose(basis.explained_variance, exact.explained_variance, rtol=1e-3)
    np.testing.assert_allclose(basis.mean, exact.mean, atol=1e-5)
    curve = basis.pca.explained_variance_curve([1, 5, 12])
    assert 0 < curve[0] < curve[1] < curve[2] <= 1
    # the descriptor of a training shape equals its PCA projection
    z = basis.describe(udf_samples(*shapes[3], 500, np.random.default_rng([7, 3])))
    np.testing.assert_allclose(z, basis.pca.project(rows[3:4])[0], atol=1e-4)
    np.testing.assert_allclose(z[:8], exact.project(rows[3:4])[0, :8], atol=2e-3)


def test_fit_is_deterministic_and_accepts_shapes_and_clouds(shapes) -> None:
    small = shapes[:10]
    kwargs = {"std_threshold": 0.2, "n_components": 4, "n_udf_samples": 200, "seed": 1}
    a = fit_basis(small, GRID, **kwargs)
    b = fit_basis((Shape.from_arrays(v, f) for v, f in small), GRID, **kwargs)
    assert a.content_hash == b.content_hash
    clouds = [trimesh.Trimesh(v, f).sample(300, seed=i) for i, (v, f) in enumerate(small)]
    c = fit_basis(clouds, GRID, point_cloud_dilation=1, **kwargs)
    assert c.metadata["n_fit_point_clouds"] == 10 and c.n_voxels > 0


def test_fit_rejects_bad_requests(shapes) -> None:
    with pytest.raises(InputError):
        fit_basis(shapes[:1], GRID, n_components=1)
    with pytest.raises(InputError):
        fit_basis(shapes[:4], GRID, std_threshold=0.5, n_components=2)
    with pytest.raises(InputError):
        fit_basis(shapes[:4], GRID, n_components=5)
    with pytest.raises(InputError):
        fit_basis([np.zeros((4, 2))], GRID)
