"""The smooth displacement fitted to a refined map (litege_core.matching.deform)."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
import trimesh
from scipy.sparse.linalg import eigsh
from scipy.spatial import cKDTree

from litege_core.errors import InputError
from litege_core.matching.deform import (
    register_displacement,
    register_displacement_reference,
    smooth_displacement,
    smooth_displacement_reference,
)


def _cotan_operators(vertices: np.ndarray, faces: np.ndarray) -> tuple[sp.csr_matrix, np.ndarray]:
    """Cotangent stiffness ``(V, V)`` (positive semi-definite) and lumped areas ``(V,)``."""
    n = len(vertices)
    rows, cols, vals = [], [], []
    areas = np.zeros(n)
    for a, b, c in faces:
        pa, pb, pc = vertices[a], vertices[b], vertices[c]
        areas[[a, b, c]] += 0.5 * np.linalg.norm(np.cross(pb - pa, pc - pa)) / 3
        for i, j, k in ((a, b, c), (b, c, a), (c, a, b)):
            u, v = vertices[i] - vertices[k], vertices[j] - vertices[k]
            cot = 0.5 * np.dot(u, v) / np.linalg.norm(np.cross(u, v))
            rows += [i, j, i, j]
            cols += [j, i, i, j]
            vals += [-cot, -cot, cot, cot]
    return sp.csr_matrix((vals, (rows, cols)), shape=(n, n)), areas


@pytest.fixture(scope="module")
def ellipsoid():
    """A unit-area ellipsoid's first 30 mass-orthonormal eigenpairs and its 642 vertices."""
    mesh = trimesh.creation.icosphere(subdivisions=3)
    vertices = np.asarray(mesh.vertices) * [1.3, 1.0, 0.8]
    vertices /= np.sqrt(trimesh.Trimesh(vertices, mesh.faces).area)
    stiffness, mass = _cotan_operators(vertices, np.asarray(mesh.faces))
    eigenvalues, basis = eigsh(stiffness, k=30, M=sp.diags(mass), sigma=-1e-6)
    order = np.argsort(eigenvalues)
    return vertices, np.clip(eigenvalues[order], 0.0, None), basis[:, order], np.asarray(mesh.faces)


def test_fast_fit_agrees_with_the_lstsq_reference(ellipsoid):
    _, eigenvalues, basis, _ = ellipsoid
    rng = np.random.default_rng(0)
    rows = rng.choice(basis.shape[0], 200, replace=False)
    offsets = 0.05 * rng.normal(size=(200, 3)) + [0.2, 0.0, -0.1]
    fast = smooth_displacement(basis[rows], eigenvalues, offsets, 1.0, 1e-4, rounds=3)
    slow = smooth_displacement_reference(basis[rows], eigenvalues, offsets, 1.0, 1e-4, rounds=3)
    assert fast.shape == (30, 3)
    np.testing.assert_allclose(fast, slow, atol=1e-8)


def test_a_translation_is_reproduced_exactly(ellipsoid):
    _, eigenvalues, basis, _ = ellipsoid
    shift = np.array([0.3, -0.2, 0.1])
    rows = np.arange(0, basis.shape[0], 3)
    found = smooth_displacement(basis[rows], eigenvalues, np.tile(shift, (rows.size, 1)), 1.0, 1e-3)
    np.testing.assert_allclose(basis @ found, np.tile(shift, (basis.shape[0], 1)), atol=1e-8)


def test_the_fit_averages_noise_and_resists_outliers(ellipsoid):
    _, eigenvalues, basis, _ = ellipsoid
    rng = np.random.default_rng(1)
    truth = basis[:, :8] @ (0.05 * rng.normal(size=(8, 3)))  # a smooth displacement
    rows = rng.choice(basis.shape[0], 300, replace=False)
    offsets = truth[rows] + 0.02 * rng.normal(size=(300, 3))
    wild = rng.choice(300, 10, replace=False)
    offsets[wild] += rng.choice([-0.5, 0.5], size=(10, 3))  # matches on another part
    fitted = basis @ smooth_displacement(basis[rows], eigenvalues, offsets, 1.0, 1e-5)
    before = np.linalg.norm(offsets - truth[rows], axis=1)
    after = np.linalg.norm(fitted - truth, axis=1)
    assert after.mean() < 0.5 * before.mean()
    assert after[rows[wild]].max() < 0.1 * before[wild].min()  # pulled back within the noise
    once = basis @ smooth_displacement(basis[rows], eigenvalues, offsets, 1.0, 1e-5, rounds=1)
    assert after.mean() < np.linalg.norm(once - truth, axis=1).mean()  # reweighting helps


def test_bad_input_is_refused(ellipsoid):
    _, eigenvalues, basis, _ = ellipsoid
    offsets = np.zeros((4, 3))
    with pytest.raises(InputError):
        smooth_displacement(basis[:4], eigenvalues, offsets[:3], 1.0, 1e-3)
    with pytest.raises(InputError):
        smooth_displacement(basis[:4], eigenvalues[:-1], offsets, 1.0, 1e-3)
    with pytest.raises(InputError):
        smooth_displacement(basis[:4], eigenvalues, offsets, 1.0, 0.0)
    with pytest.raises(InputError):
        smooth_displacement(basis[:4], eigenvalues, offsets, 1.0, 1e-3, rounds=0)


def test_registration_undoes_a_stretch_that_the_nearest_vertices_miss(ellipsoid):
    """Y: X stretched and moved (a map that is not an isometry; vertex v of Y is X's v)."""
    vertices, eigenvalues, basis, faces = ellipsoid
    target = vertices * [1.2, 0.9, 1.05] + [0.02, -0.01, 0.0]
    normals = trimesh.Trimesh(target, faces).vertex_normals
    rows = np.arange(0, vertices.shape[0], 2)
    everyone = np.arange(vertices.shape[0])
    _, nearest = cKDTree(target).query(vertices)  # no displacement
    assert (nearest == everyone).mean() < 0.5
    biased = cKDTree(target).query(vertices[rows])[1]  # a map with a shared bias
    offsets = target[biased] - vertices[rows]
    start = np.zeros((basis.shape[1], 3))
    args = (basis[rows], eigenvalues, vertices[rows], offsets, start, target, normals, 1.0)
    for anchor in (0.0, 0.01):
        found = register_displacement(*args, (1e-3, 1e-5), rounds=8, anchor=anchor)
        assert found.shape == (basis.shape[1], 3)
        _, registered = cKDTree(target).query(vertices + basis @ found)
        assert (registered == everyone).mean() > 0.95
    np.testing.assert_array_equal(register_displacement(*args, (1e-3, 1e-5), rounds=0), start)


def test_the_tie_holds_a_registration_to_the_map(ellipsoid):
    """Y = X: a rotation about the long axis slides along Y's surface for free, so only the
    tie to a map (here the rotation) keeps it; without one, the registration undoes it."""
    vertices, eigenvalues, basis, faces = ellipsoid
    normals = trimesh.Trimesh(vertices, faces).vertex_normals
    rows = np.arange(0, vertices.shape[0], 2)
    turn = 0.08
    rotation = np.array(
        [[1, 0, 0], [0, np.cos(turn), -np.sin(turn)], [0, np.sin(turn), np.cos(turn)]]
    )
    offsets = vertices[rows] @ rotation.T - vertices[rows]
    start = smooth_displacement(basis[rows], eigenvalues, offsets, 1.0, 1e-5)
    moved = {}
    args = (basis[rows], eigenvalues, vertices[rows], offsets, start, vertices, normals, 1.0)
    for anchor in (0.0, 1.0):
        found = register_displacement(*args, (1e-3, 1e-5), rounds=8, anchor=anchor)
        moved[anchor] = np.linalg.norm(basis[rows] @ found - offsets, axis=1).mean()
    assert moved[1.0] < 0.5 * moved[0.0]


def test_bad_registration_input_is_refused(ellipsoid):
    vertices, eigenvalues, basis, _ = ellipsoid
    points, offsets, start = vertices[:4], np.zeros((4, 3)), np.zeros((basis.shape[1], 3))

    def register(offsets=offsets, start=start, normals=vertices, smoothing=(1e-3, 1e-5), **kw):
        return register_displacement(
            basis[:4], eigenvalues, points, offsets, start, vertices, normals, 1.0, smoothing, **kw
        )

    assert register(rounds=1).shape == start.shape
    for bad in (
        {"offsets": offsets[:3]},
        {"start": start[:-1]},
        {"normals": vertices[:-1]},
        {"smoothing": (1e-3, 0.0)},
        {"rounds": -1},
        {"anchor": -1.0},
    ):
        with pytest.raises(InputError):
            register(**bad)


def test_fast_registration_agrees_with_the_lstsq_reference(ellipsoid):
    vertices, eigenvalues, basis, faces = ellipsoid
    target = vertices * [1.15, 0.95, 1.0] + [0.01, 0.0, -0.02]
    normals = trimesh.Trimesh(target, faces).vertex_normals
    rng = np.random.default_rng(3)
    rows = rng.choice(vertices.shape[0], 150, replace=False)
    offsets = target[rows] - vertices[rows] + 0.01 * rng.normal(size=(150, 3))
    start = smooth_displacement(basis[rows], eigenvalues, offsets, 1.0, 1e-4)
    for anchor in (0.0, 0.05):
        args = (basis[rows], eigenvalues, vertices[rows], offsets, start, target, normals, 1.0)
        fast = register_displacement(*args, (1e-3, 1e-5), rounds=4, anchor=anchor)
        slow = register_displacement_reference(*args, (1e-3, 1e-5), rounds=4, anchor=anchor)
        np.testing.assert_allclose(fast, slow, atol=1e-8)


def test_vertices_without_a_normal_give_no_surface_term(ellipsoid):
    """A zero normal (an unreferenced vertex) must not poison the solve with NaNs."""
    vertices, eigenvalues, basis, faces = ellipsoid
    target = vertices * [1.1, 1.0, 0.95]
    normals = np.array(trimesh.Trimesh(target, faces).vertex_normals)
    normals[::7] = 0.0
    rows = np.arange(0, vertices.shape[0], 2)
    offsets = target[rows] - vertices[rows]
    start = np.zeros((basis.shape[1], 3))
    args = (basis[rows], eigenvalues, vertices[rows], offsets, start, target, normals, 1.0)
    found = register_displacement(*args, (1e-3, 1e-5), rounds=4)
    assert np.all(np.isfinite(found))
    np.testing.assert_allclose(
        found, register_displacement_reference(*args, (1e-3, 1e-5), rounds=4), atol=1e-8
    )
