"""A cloud's local surface (issue 14): flatness, normals and roughness from the k-NN
covariance, the closed-form eigenpairs against ``eigh``."""

from __future__ import annotations

import numpy as np
import pytest


def test_roughness_grows_with_noise_and_ignores_scale(monkeypatch) -> None:
    from litege_core.engines.graph import knn_neighbours
    from litege_core.learned import cloud_surface
    from litege_core.learned.cloud_surface import surface_roughness

    rng = np.random.default_rng(0)
    directions = rng.normal(size=(3000, 3))
    sphere = directions / np.linalg.norm(directions, axis=1, keepdims=True)
    clean = surface_roughness(sphere)
    noisy = surface_roughness(sphere + rng.normal(0.0, 0.03, sphere.shape))
    assert clean < 0.1 < noisy
    assert surface_roughness(7.0 * sphere) == pytest.approx(clean)
    nearest = knn_neighbours(sphere, 16)[1]
    assert surface_roughness(sphere, nearest=nearest) == clean
    monkeypatch.setattr(cloud_surface, "ROUGHNESS_CHUNK", 1000)
    assert surface_roughness(sphere) == pytest.approx(clean)
    assert surface_roughness(sphere[:3]) == 0.0


def test_closed_form_eigenpairs_equal_the_eigh_reference() -> None:
    from litege_core.learned.cloud_surface import _extreme_eigenpairs, _extreme_eigenpairs_reference

    rng = np.random.default_rng(3)
    spreads = [(1.0, 0.5, 0.02), (1.0, 1.0, 1.0), (1.0, 0.3, 0.0), (1.0, 0.0, 0.0), (0, 0, 0)]
    clouds = []
    for spread in spreads:  # flat, round, exactly planar, a line, one spot
        local = rng.normal(size=(200, 16, 3)) * spread
        turn = np.linalg.qr(rng.normal(size=(200, 3, 3)))[0]
        clouds.append(np.einsum("nij,nkj->nki", turn, local))
    local = np.concatenate(clouds)
    local -= local.mean(axis=1, keepdims=True)
    matrices = np.matmul(local.transpose(0, 2, 1), local)
    smallest, largest, normal = _extreme_eigenpairs(matrices)
    low, high, reference = _extreme_eigenpairs_reference(matrices)
    scale = np.maximum(high, 1e-300)
    np.testing.assert_allclose(smallest / scale, low / scale, atol=1e-7)
    np.testing.assert_allclose(largest, high, rtol=1e-9, atol=1e-12)
    defined = (low < 0.9 * high) & (high > 0)  # a unique smallest eigenvector
    defined &= np.r_[np.ones(600, bool), np.zeros(400, bool)]  # not a line or a spot
    cosines = np.abs(np.einsum("ni,ni->n", normal, reference))
    assert np.all(cosines[defined] > 1.0 - 1e-9)
    np.testing.assert_allclose(np.linalg.norm(normal[high > 0], axis=1), 1.0)


def test_local_normals_are_perpendicular_to_the_surface() -> None:
    from litege_core.learned.cloud_surface import local_surface

    rng = np.random.default_rng(1)
    directions = rng.normal(size=(2000, 3))
    sphere = directions / np.linalg.norm(directions, axis=1, keepdims=True)
    flatness, normals = local_surface(sphere)
    assert flatness.shape == (2000,) and normals.shape == (2000, 3)
    np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0)
    # unoriented: along the radius up to sign
    assert np.quantile(np.abs(np.einsum("ni,ni->n", normals, sphere)), 0.01) > 0.99
    flatness, normals = local_surface(sphere[:3])
    assert not flatness.any() and not normals.any()
