"""The half-body remesher on a small implicit body (fast)."""

import numpy as np

from litege_core.synth import quality
from litege_core.synth.contour import cut_positive_half, marching_tetrahedra
from litege_core.synth.implicit import (
    Ellipsoid,
    RoundCone,
    blend,
    field_gradient,
    project_to_surface,
)
from litege_core.synth.remesh import mirror_half, remesh_half


def test_round_cone_distance_matches_brute_force() -> None:
    cone = RoundCone((0.0, 0.0, 0.0), (1.0, 0.2, 0.0), 0.3, 0.1, "x")
    rng = np.random.default_rng(0)
    points = rng.uniform(-1.0, 2.0, size=(500, 3))
    t = np.linspace(0.0, 1.0, 4001)
    centers = np.outer(1 - t, [0.0, 0.0, 0.0]) + np.outer(t, [1.0, 0.2, 0.0])
    radii = 0.3 * (1 - t) + 0.1 * t
    brute = (np.linalg.norm(points[:, None] - centers[None], axis=2) - radii).min(axis=1)
    outside = brute > 0
    assert np.abs(cone.distance(points)[outside] - brute[outside]).max() < 1e-3


def test_small_body_remeshes_to_symmetric_sphere_topology() -> None:
    body = blend(
        [
            Ellipsoid((0.0, 0.0, 0.0), (0.3, 0.25, 0.5), "trunk"),
            RoundCone((0.15, -0.1, 0.2), (0.35, -0.5, 0.25), 0.1, 0.07, "leg_l"),
            RoundCone((-0.15, -0.1, 0.2), (-0.35, -0.5, 0.25), 0.1, 0.07, "leg_r"),
        ],
        0.05,
    )
    h = 0.04
    lower = np.array([-3 * h + h / 3, -0.7, -0.7])

    def half(p: np.ndarray) -> np.ndarray:
        return np.maximum(body.distance(p), -p[:, 0] - 2 * h)

    v, f = marching_tetrahedra(half, lower, np.array([0.6, 0.4, 0.7]), h)
    hv, hf, cut = cut_positive_half(v, f)
    assert np.all(hv[cut, 0] == 0.0)

    def normals(p: np.ndarray) -> np.ndarray:
        g = field_gradient(body, p)
        return g / np.linalg.norm(g, axis=1, keepdims=True)

    rv, rf, rb = remesh_half(
        hv, hf, cut, 0.06, lambda p: project_to_surface(body, p, 3), normals, iterations=6
    )
    vertices, faces, sym = mirror_half(rv, rf, rb)
    assert quality.is_closed_manifold(faces)
    assert quality.euler_characteristic(faces) == 2
    assert np.abs(vertices[sym] * [-1, 1, 1] - vertices).max() == 0.0
    assert np.abs(body.distance(vertices)).max() < 5e-3
    assert quality.triangle_angles(vertices, faces).min() > 10.0
