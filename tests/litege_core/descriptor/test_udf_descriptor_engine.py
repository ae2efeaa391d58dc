"""DescriptorEngine speed paths (issue 17): the Gram-matrix residual against the direct
formula, and the opt-in voxel lattices against the full descriptor."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from litege_core.descriptor.basis import VOXEL_LATTICES, UdfPcaBasis, lattice_voxels
from litege_core.descriptor.grid import VoxelGrid
from litege_core.descriptor.pca import fit_pca_exact
from litege_core.descriptor.udf import udf_reference
from litege_core.errors import InputError

GRID = VoxelGrid(resolution=24, pitch=0.07)


def _cloud(rng: np.random.Generator, n: int = 400) -> np.ndarray:
    x = rng.normal(size=(n, 3))
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    return (x * rng.uniform(0.3, 0.7, 3) + rng.uniform(-0.1, 0.1, 3)).astype(np.float32)


@pytest.fixture(scope="module")
def basis() -> UdfPcaBasis:
    rng = np.random.default_rng(0)
    indices = np.flatnonzero(np.linalg.norm(GRID.centers(), axis=1) < 0.8)
    centers = GRID.centers(indices)
    rows = np.stack([udf_reference(_cloud(rng), centers) for _ in range(40)])
    return UdfPcaBasis.from_pca(GRID, indices, fit_pca_exact(rows, 10))


@pytest.fixture(scope="module")
def clouds() -> list[np.ndarray]:
    return [_cloud(np.random.default_rng(100 + s), 300 + 50 * s) for s in range(4)]


def test_residual_equals_the_float64_reconstruction(basis, clouds) -> None:
    result = basis.engine("cpu").describe_with_residual(clouds)
    udf = result.udf.numpy().astype(np.float64)
    direct = basis.pca.reconstruction_residual(udf)  # float64 ‖c − PᵀPc‖
    np.testing.assert_allclose(result.residual.numpy(), direct, rtol=3e-5)
    centred = result.udf - torch.from_numpy(np.array(basis.mean))
    float32 = torch.linalg.vector_norm(
        centred - result.descriptors @ torch.from_numpy(np.array(basis.components)), dim=1
    )
    np.testing.assert_allclose(result.residual.numpy(), float32.numpy(), rtol=3e-5)
    # one shape alone gets its batch row
    alone = basis.engine("cpu").describe_with_residual(clouds[2][None])
    np.testing.assert_allclose(alone.residual.numpy(), result.residual.numpy()[2:3], rtol=3e-5)
    torch.testing.assert_close(alone.descriptors[0], result.descriptors[2], rtol=1e-5, atol=1e-5)


def test_lattice_voxels() -> None:
    indices = GRID.flat_index(np.array([[0, 0, 0], [1, 1, 1], [0, 1, 0], [2, 4, 6], [3, 3, 5]]))
    np.testing.assert_array_equal(lattice_voxels(GRID, indices, "full"), np.arange(5))
    np.testing.assert_array_equal(lattice_voxels(GRID, indices, "stride2"), [0, 3])
    np.testing.assert_array_equal(lattice_voxels(GRID, indices, "bcc"), [0, 1, 3, 4])
    with pytest.raises(InputError):
        lattice_voxels(GRID, indices, "stride3")


@pytest.mark.parametrize("lattice", ["bcc", "stride2"])
def test_lattice_codes_are_the_least_squares_fit_on_the_kept_voxels(basis, clouds, lattice) -> None:
    engine = basis.engine("cpu", lattice=lattice)
    assert engine is basis.engine("cpu", lattice=lattice)
    assert engine is not basis.engine("cpu")
    kept = lattice_voxels(basis.grid, basis.voxel_indices, lattice)
    assert engine.n_voxels == kept.size < basis.n_voxels
    result = engine.describe_with_residual(clouds)
    assert result.udf.shape == (len(clouds), kept.size)
    components = basis.components.astype(np.float64)[:, kept]
    for b, cloud in enumerate(clouds):
        udf = udf_reference(cloud, basis.centers[kept].astype(np.float64))
        np.testing.assert_allclose(result.udf[b].numpy(), udf, atol=1e-6)
        centred = udf - basis.mean[kept]
        codes, *_ = np.linalg.lstsq(components.T, centred, rcond=None)
        np.testing.assert_allclose(result.descriptors[b].numpy(), codes, rtol=1e-4, atol=1e-5)
        fit = np.linalg.norm(centred - components.T @ codes)
        expected = fit * np.sqrt(basis.n_voxels / kept.size)
        assert float(result.residual[b]) == pytest.approx(expected, rel=1e-4)
    torch.testing.assert_close(engine.describe_batch(clouds), result.descriptors)
    assert engine.components.shape == (basis.n_components, kept.size)
    # close to the full descriptor: the UDF is smooth at the voxel scale
    full = basis.engine("cpu").describe_batch(clouds)
    relative = torch.linalg.vector_norm(result.descriptors - full, dim=1) / (
        torch.linalg.vector_norm(full, dim=1)
    )
    assert float(relative.max()) < 0.25


def test_engine_rejects_unknown_lattices(basis) -> None:
    assert VOXEL_LATTICES[0] == "full"
    with pytest.raises(InputError):
        basis.engine("cpu", lattice="sparse")


def test_auto_lattice_is_stride2_only_where_its_fit_is_well_determined(basis) -> None:
    from litege_core.descriptor.basis import AUTO_STRIDE2_VOXELS_PER_COMPONENT, LATTICE_CHOICES

    kept = lattice_voxels(GRID, basis.voxel_indices, "stride2").shape[0]
    assert kept >= AUTO_STRIDE2_VOXELS_PER_COMPONENT * basis.n_components  # 10 components
    assert basis.resolve_lattice() == basis.resolve_lattice("auto") == "stride2"
    for lattice in VOXEL_LATTICES:
        assert basis.resolve_lattice(lattice) == lattice  # named lattices are kept as named
    # too few stride2 voxels per component: the full lattice
    rng = np.random.default_rng(1)
    few = np.flatnonzero(np.linalg.norm(GRID.centers(), axis=1) < 0.4)
    rows = np.stack([udf_reference(_cloud(rng), GRID.centers(few)) for _ in range(40)])
    small = UdfPcaBasis.from_pca(GRID, few, fit_pca_exact(rows, 30))
    assert lattice_voxels(GRID, few, "stride2").shape[0] < 8 * 30
    assert small.resolve_lattice("auto") == "full"
    assert LATTICE_CHOICES[0] == "auto" and LATTICE_CHOICES[1:] == VOXEL_LATTICES
    with pytest.raises(InputError, match="lattice must be one of"):
        basis.resolve_lattice("sparse")


def test_shipped_bases_resolve_auto_to_stride2() -> None:
    from litege_core.learned import load_shipped

    for name in ("quadrupeds", "humans"):
        assert load_shipped(name).basis.resolve_lattice("auto") == "stride2"
