"""A mesh's vertex noise and its Taubin denoising (``litege_core.learned.mesh_noise``): the
measure against known noise, the smoothing against its slow reference, and the denoised mesh
against the clean surface the noise was added to."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from litege_core.learned.mesh_noise import (
    DENOISE_PAIRS_PER_CHECK,
    denoised_mesh,
    mesh_edges,
    mesh_noise,
    taubin_smooth,
    taubin_smooth_reference,
)


def test_mesh_noise_measures_vertex_noise_not_curvature() -> None:
    """Scale-free; ~0 on clean coarse meshes, rising with the vertex noise (as a
    fraction of the edge length), the same with the faces wound either way or split along
    seams."""
    rng = np.random.default_rng(0)
    fine, coarse = trimesh.creation.icosphere(4), trimesh.creation.icosphere(2)
    assert mesh_noise(np.asarray(coarse.vertices), np.asarray(coarse.faces)) < 0.01
    capsule = trimesh.creation.capsule(radius=0.1, height=1.0, count=[8, 8])  # 66 vertices
    assert mesh_noise(np.asarray(capsule.vertices), np.asarray(capsule.faces)) < 0.05
    points, faces = np.asarray(fine.vertices), np.asarray(fine.faces)
    assert mesh_noise(points, faces) < 0.01
    edge = float(np.median(np.linalg.norm(points[faces[:, 0]] - points[faces[:, 1]], axis=1)))
    levels = [
        mesh_noise(points + rng.normal(0.0, s * edge, points.shape), faces)
        for s in (0.05, 0.1, 0.2, 0.4)
    ]
    assert levels == sorted(levels) and levels[0] > 0.02
    noisy = points + rng.normal(0.0, 0.1 * edge, points.shape)
    value = mesh_noise(noisy, faces)
    assert 0.05 < value < 0.12
    assert mesh_noise(10.0 * noisy, faces) == pytest.approx(value)
    flipped = faces.copy()
    flipped[::3] = flipped[::3, ::-1]  # wound against their neighbours: turned over first
    assert mesh_noise(noisy, flipped) == pytest.approx(value)
    soup = noisy[faces].reshape(-1, 3)  # every face its own vertices: welded at the seams
    assert mesh_noise(soup, np.arange(len(soup)).reshape(-1, 3)) == pytest.approx(value)
    assert mesh_noise(points[:3], np.array([[0, 0, 0]])) == 0.0  # no edge


def _noisy_sphere(fraction: float, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A unit icosphere's vertices, faces and the vertices with noise of ``fraction`` of its
    edge length."""
    sphere = trimesh.creation.icosphere(4)
    points, faces = np.asarray(sphere.vertices), np.asarray(sphere.faces)
    edge = float(np.median(np.linalg.norm(points[faces[:, 0]] - points[faces[:, 1]], axis=1)))
    noise = np.random.default_rng(seed).normal(0.0, fraction * edge, points.shape)
    return points, faces, points + noise


def test_taubin_smoothing_equals_its_reference_and_keeps_seams_together() -> None:
    """The vectorized λ|μ steps equal the vertex-by-vertex reference; a mesh split along a seam
    (every face its own vertices) is smoothed as the welded mesh, copies following their
    vertex."""
    _, faces, noisy = _noisy_sphere(0.3)
    smooth = taubin_smooth(noisy, mesh_edges(noisy, faces), 3)
    np.testing.assert_allclose(smooth, taubin_smooth_reference(noisy, faces, 3), atol=1e-12)
    soup = noisy[faces].reshape(-1, 3)
    soup_faces = np.arange(len(soup)).reshape(-1, 3)
    split = taubin_smooth(soup, mesh_edges(soup, soup_faces), 3)
    np.testing.assert_allclose(split, smooth[faces].reshape(-1, 3), atol=1e-12)


def test_a_clean_mesh_is_left_as_it_is() -> None:
    points, faces, _ = _noisy_sphere(0.0)
    denoised = denoised_mesh(points, faces, 0.08)
    assert denoised.steps == 0 and denoised.points is not None
    np.testing.assert_array_equal(denoised.points, points)
    assert denoised.noise == pytest.approx(mesh_noise(points, faces))


@pytest.mark.parametrize("fraction", [0.3, 1.0])
def test_a_noisy_mesh_is_taken_back_towards_its_clean_surface(fraction: float) -> None:
    """Noise of a third of an edge and of a whole edge: the denoised mesh's noise is at most
    the limit, its vertices lie closer to the unit sphere than the noisy ones, and the
    sphere neither shrinks nor grows by more than 1 % (Taubin's μ step)."""
    _, faces, noisy = _noisy_sphere(fraction)
    before = mesh_noise(noisy, faces)
    assert before > 0.15
    denoised = denoised_mesh(noisy, faces, 0.08)
    assert denoised.noise <= 0.08 and denoised.steps % DENOISE_PAIRS_PER_CHECK == 0
    assert denoised.noise == pytest.approx(mesh_noise(denoised.points, faces))
    radius = np.linalg.norm(denoised.points, axis=1)
    off_noisy = np.abs(np.linalg.norm(noisy, axis=1) - 1.0).mean()
    assert np.abs(radius - 1.0).mean() < 0.5 * off_noisy
    assert abs(radius.mean() - 1.0) < 0.01
    more = denoised_mesh(noisy, faces, 0.04)  # a lower limit smooths longer
    assert more.steps > denoised.steps and more.noise <= 0.04
