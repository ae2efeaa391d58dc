"""Small deterministic shapes for the geodesic-engine tests (all at most 2.6K vertices)."""

import numpy as np
import pytest
import trimesh

from litege_core.shape import Shape


def icosphere(subdivisions: int) -> Shape:
    mesh = trimesh.creation.icosphere(subdivisions=subdivisions)
    return Shape.from_arrays(mesh.vertices, mesh.faces)


@pytest.fixture(scope="session")
def sphere3() -> Shape:
    """642-vertex unit icosphere."""
    return icosphere(3)


@pytest.fixture(scope="session")
def sphere4() -> Shape:
    """2562-vertex unit icosphere."""
    return icosphere(4)


@pytest.fixture(scope="session")
def bumpy_torus() -> Shape:
    """2048-vertex torus (R=1, r=0.4) with seeded vertex jitter of 0.01: an irregular mesh."""
    torus = trimesh.creation.torus(1.0, 0.4, major_sections=64, minor_sections=32)
    rng = np.random.default_rng(0)
    return Shape.from_arrays(
        np.asarray(torus.vertices) + 0.01 * rng.standard_normal(torus.vertices.shape),
        torus.faces,
    )


@pytest.fixture(scope="session")
def two_spheres() -> Shape:
    """Two disjoint 162-vertex spheres 5 apart (vertices 0..161 and 162..323)."""
    mesh = trimesh.creation.icosphere(subdivisions=2)
    vertices = np.asarray(mesh.vertices)
    faces = np.asarray(mesh.faces)
    return Shape.from_arrays(
        np.vstack([vertices, vertices + np.array([5.0, 0.0, 0.0])]),
        np.vstack([faces, faces + len(vertices)]),
    )


@pytest.fixture(scope="session")
def sphere_cloud() -> Shape:
    """2000 seeded uniform points on the unit sphere, as a point cloud."""
    points = np.random.default_rng(0).standard_normal((2000, 3))
    return Shape.from_arrays(points / np.linalg.norm(points, axis=1, keepdims=True))


@pytest.fixture(scope="session")
def flat_grid() -> Shape:
    """A 15x15-vertex triangulated unit square in z=0 with jittered interior vertices."""
    n = 15
    x, y = np.meshgrid(np.linspace(0.0, 1.0, n), np.linspace(0.0, 1.0, n))
    vertices = np.column_stack([x.ravel(), y.ravel(), np.zeros(n * n)])
    inside = (vertices[:, :2] > 0).all(axis=1) & (vertices[:, :2] < 1).all(axis=1)
    rng = np.random.default_rng(1)
    vertices[inside, :2] += rng.uniform(-0.02, 0.02, (int(inside.sum()), 2))
    i, j = np.meshgrid(np.arange(n - 1), np.arange(n - 1), indexing="ij")
    a = (i * n + j).ravel()
    faces = np.concatenate(
        [np.column_stack([a, a + 1, a + n + 1]), np.column_stack([a, a + n + 1, a + n])]
    )
    return Shape.from_arrays(vertices, faces)
