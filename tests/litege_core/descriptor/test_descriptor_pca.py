"""Streamed randomized PCA against the dense SVD reference."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from litege_core.descriptor.pca import (
    explained_variance_curve,
    fit_pca_exact,
    fit_pca_streamed,
    subspace_angles,
)
from litege_core.errors import ArrayShapeError, InputError, NonFiniteError


def _low_rank_plus_noise(n: int = 400, d: int = 600, rank: int = 12, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    scales = 10.0 * 0.7 ** np.arange(rank)
    left = rng.normal(size=(n, rank)) * scales
    right = np.linalg.qr(rng.normal(size=(d, rank)))[0].T
    return (left @ right + 0.01 * rng.normal(size=(n, d)) + rng.uniform(0, 1, d)).astype(np.float32)


def _chunks(x: np.ndarray, rows: int):
    return lambda: (x[s : s + rows] for s in range(0, x.shape[0], rows))


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_streamed_matches_exact(dtype: type) -> None:
    x = _low_rank_plus_noise()
    k = 10
    exact = fit_pca_exact(x, k)
    streamed = fit_pca_streamed(_chunks(x, 37), k, seed=3, dtype=dtype)
    np.testing.assert_allclose(streamed.mean, exact.mean, rtol=1e-6, atol=1e-6)
    assert streamed.total_variance == pytest.approx(exact.total_variance, rel=1e-9)
    assert subspace_angles(streamed.components, exact.components).max() < 1e-3
    np.testing.assert_allclose(streamed.explained_variance, exact.explained_variance, rtol=1e-3)
    np.testing.assert_allclose(
        streamed.explained_variance_ratio, exact.explained_variance_ratio, rtol=1e-3
    )
    # deterministic signs: same components, not just the same subspace
    np.testing.assert_allclose(streamed.components, exact.components, atol=2e-3)
    np.testing.assert_allclose(streamed.components @ streamed.components.T, np.eye(k), atol=1e-6)


def test_exact_reference_matches_numpy_covariance() -> None:
    x = _low_rank_plus_noise(60, 30, rank=5).astype(np.float64)
    pca = fit_pca_exact(x, 30)
    eigenvalues = np.sort(np.linalg.eigvalsh(np.cov(x, rowvar=False)))[::-1]
    np.testing.assert_allclose(pca.explained_variance, eigenvalues, rtol=1e-8, atol=1e-10)
    assert pca.explained_variance_ratio.sum() == pytest.approx(1.0)


def test_power_iterations_and_determinism() -> None:
    x = _low_rank_plus_noise(seed=1)
    a = fit_pca_streamed(_chunks(x, 64), 8, n_power_iter=0, oversample=30, seed=0)
    b = fit_pca_streamed(_chunks(x, 100), 8, n_power_iter=0, oversample=30, seed=0)
    np.testing.assert_allclose(a.components, b.components, atol=1e-8)  # chunking-invariant
    exact = fit_pca_exact(x, 8)
    assert subspace_angles(a.components, exact.components).max() < 1e-2


def test_memmap_source(tmp_path: Path) -> None:
    x = _low_rank_plus_noise(200, 150)
    path = tmp_path / "rows.f32"
    mm = np.memmap(path, np.float32, "w+", shape=x.shape)
    mm[:] = x
    mm.flush()
    ro = np.memmap(path, np.float32, "r", shape=x.shape)
    streamed = fit_pca_streamed(_chunks(ro, 50), 6)
    exact = fit_pca_exact(x, 6)
    np.testing.assert_allclose(streamed.explained_variance, exact.explained_variance, rtol=1e-3)


def test_projection_reconstruction_residual() -> None:
    x = _low_rank_plus_noise(100, 80).astype(np.float64)
    pca = fit_pca_exact(x, 5)
    z = pca.project(x[:7])
    np.testing.assert_allclose(z, (x[:7] - pca.mean) @ pca.components.T)
    np.testing.assert_allclose(pca.project(pca.mean[None]), 0.0, atol=1e-9)
    rebuilt = pca.reconstruct(z)
    np.testing.assert_allclose(pca.project(rebuilt), z, atol=1e-9)
    np.testing.assert_allclose(pca.reconstruction_residual(rebuilt), 0.0, atol=1e-9)
    residual = pca.reconstruction_residual(x[:7])
    centred = x[:7] - pca.mean
    direct = np.linalg.norm(centred - centred @ pca.components.T @ pca.components, axis=1)
    np.testing.assert_allclose(residual, direct)
    # Pythagoras: ‖x − μ‖² = ‖z‖² + residual²
    np.testing.assert_allclose((centred**2).sum(1), (z**2).sum(1) + residual**2, rtol=1e-9)


def test_explained_variance_curve() -> None:
    ratio = np.array([0.5, 0.25, 0.125])
    np.testing.assert_allclose(explained_variance_curve(ratio), [0.5, 0.75, 0.875])
    np.testing.assert_allclose(explained_variance_curve(ratio, [1, 3]), [0.5, 0.875])
    with pytest.raises(InputError):
        explained_variance_curve(ratio, [4])
    with pytest.raises(InputError):
        explained_variance_curve(ratio, [0])


def test_invalid_inputs() -> None:
    x = _low_rank_plus_noise(20, 10, rank=4)
    with pytest.raises(InputError):
        fit_pca_streamed(_chunks(x, 5), 11)
    with pytest.raises(InputError):
        fit_pca_exact(x, 0)
    with pytest.raises(ArrayShapeError):
        fit_pca_streamed(lambda: [x[:5], x[5:, :9]], 2)
    with pytest.raises(ArrayShapeError):
        fit_pca_streamed(lambda: [x[0]], 1)
    with pytest.raises(ArrayShapeError):
        fit_pca_streamed(lambda: [x[:1]], 1)  # fewer than 2 rows
    bad = x.copy()
    bad[3, 3] = np.nan
    with pytest.raises(NonFiniteError):
        fit_pca_streamed(_chunks(bad, 5), 2)
    with pytest.raises(InputError):
        fit_pca_streamed(42, 2)  # type: ignore[arg-type]

    calls = {"n": 0}

    def shrinking() -> Iterator[np.ndarray]:
        calls["n"] += 1
        return iter([x] if calls["n"] == 1 else [x[:10]])

    with pytest.raises(InputError):
        fit_pca_streamed(shrinking, 2)
    pca = fit_pca_exact(x, 2)
    with pytest.raises(ArrayShapeError):
        pca.project(x[:, :5])
    with pytest.raises(ArrayShapeError):
        pca.reconstruct(np.zeros((2, 3)))
