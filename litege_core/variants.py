"""Test variants of a mesh, each with ground-truth correspondence back to the source mesh.

A variant's points are located on the *source* mesh as ``(face_index, barycentric)``
(:class:`SurfaceLocation`). Since every procedural shape of a category shares the template
triangulation, that location gives the corresponding point on every other shape of the family.

Variants (design doc / issue 3): random rotation; isotropic remesh (~5K vertices) and
anisotropic remesh (~10K vertices); broken meshes (a fraction of the faces removed); point clouds
of area-weighted samples; Gaussian noise; parts cut away by two parallel planes.

Remeshing needs the optional ``pymeshlab`` package (extra ``litege[data]``).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from litege_core.errors import ArrayShapeError
from litege_core.sampling import sample_surface
from litege_core.validate import triangle_areas


class SurfaceLocation(NamedTuple):
    """Points located on a triangle mesh: ``face_index (n,)`` int64, ``barycentric (n, 3)``."""

    face_index: NDArray
    barycentric: NDArray

    def points(self, vertices: NDArray, faces: NDArray) -> NDArray:
        """``(n, 3)`` positions of the locations on a mesh with this triangulation."""
        return np.einsum("nk,nkd->nd", self.barycentric, vertices[faces[self.face_index]])


class MeshVariant(NamedTuple):
    """A new mesh and the location of each of its vertices on the source mesh."""

    vertices: NDArray
    faces: NDArray
    source_location: SurfaceLocation


class PointVariant(NamedTuple):
    """A point cloud and the location of each point on the source mesh."""

    points: NDArray
    source_location: SurfaceLocation


def random_rotation(seed: int | np.random.Generator) -> NDArray:
    """A uniformly distributed ``(3, 3)`` rotation matrix (deterministic per seed)."""
    return Rotation.random(random_state=np.random.default_rng(seed)).as_matrix()


def small_rotation(max_angle: float, rng: np.random.Generator) -> NDArray:
    """A ``(3, 3)`` rotation about a uniformly random axis by an angle uniform in
    ``[0, max_angle]`` radians."""
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    return Rotation.from_rotvec(axis * rng.uniform(0.0, max_angle)).as_matrix()


def rotate(points: NDArray, rotation: NDArray) -> NDArray:
    """Rotate ``(N, 3)`` points about the origin: ``p ↦ R p``."""
    return points @ rotation.T


def locate_on_mesh(vertices: NDArray, faces: NDArray, points: NDArray) -> SurfaceLocation:
    """Closest point on the mesh for each of ``points (n, 3)``, as face and barycentrics."""
    import trimesh

    mesh = trimesh.Trimesh(vertices, faces, process=False)
    closest, _, face_index = trimesh.proximity.closest_point(mesh, points)
    face_index = np.asarray(face_index, dtype=np.int64)
    barycentric = trimesh.triangles.points_to_barycentric(mesh.triangles[face_index], closest)
    barycentric = np.clip(barycentric, 0.0, 1.0)
    barycentric /= barycentric.sum(axis=1, keepdims=True)
    return SurfaceLocation(face_index, barycentric)


def _edge_length_for(area: float, n_vertices: int) -> float:
    # A closed mesh of equilateral triangles has F ≈ 2V, so area ≈ 2V·(√3/4)·L².
    return float(np.sqrt(2.0 * area / (np.sqrt(3.0) * n_vertices)))


def _pymeshlab_remesh(vertices: NDArray, faces: NDArray, edge_length: float) -> tuple:
    from litege_core.synth.meshops import run_pymeshlab  # the generators: on first use

    return run_pymeshlab(
        vertices,
        faces,
        "remeshing",
        lambda mesh_set, pymeshlab: mesh_set.meshing_isotropic_explicit_remeshing(
            iterations=6, targetlen=pymeshlab.PureValue(edge_length), featuredeg=180.0
        ),
    )


def isotropic_remesh(
    vertices: NDArray, faces: NDArray, target_vertices: int = 5000, max_rounds: int = 3
) -> MeshVariant:
    """Remesh to about ``target_vertices`` uniform triangles (within ~10 %).

    The edge length is set from the area and corrected from the achieved count for up to
    ``max_rounds`` rounds. Each new vertex is located on the source mesh by closest point.
    """
    return _remesh(vertices, faces, target_vertices, np.ones(3), max_rounds)


def anisotropic_remesh(
    vertices: NDArray,
    faces: NDArray,
    target_vertices: int = 10000,
    stretch: tuple[float, float, float] = (3.0, 1.0, 1.0),
    max_rounds: int = 3,
) -> MeshVariant:
    """Remesh with elongated triangles: remesh isotropically in a space stretched by
    ``stretch`` along the axes, then map back, so triangles are ~3:1 along x by default.
    Unlike T-junction edge splits, the result is a valid manifold mesh."""
    return _remesh(vertices, faces, target_vertices, np.asarray(stretch, float), max_rounds)


def _remesh(
    vertices: NDArray, faces: NDArray, target_vertices: int, stretch: NDArray, max_rounds: int
) -> MeshVariant:
    if target_vertices < 4:
        raise ArrayShapeError(f"target_vertices must be at least 4, got {target_vertices}")
    stretched = vertices * stretch
    area = float(triangle_areas(stretched, faces).sum())
    edge = _edge_length_for(area, target_vertices)
    for _ in range(max_rounds):
        new_vertices, new_faces = _pymeshlab_remesh(stretched, faces, edge)
        ratio = new_vertices.shape[0] / target_vertices
        if abs(ratio - 1.0) <= 0.1:
            break
        edge *= np.sqrt(ratio)
    new_vertices = new_vertices / stretch
    return MeshVariant(new_vertices, new_faces, locate_on_mesh(vertices, faces, new_vertices))


def decimated_mesh(vertices: NDArray, faces: NDArray, n_vertices: int) -> tuple[NDArray, NDArray]:
    """The mesh simplified to about ``n_vertices`` by quadric edge collapse (pymeshlab,
    topology kept): triangles of every size and shape, large where the surface is flat, as a
    low-poly asset or a simplified scan has them. Vertices move (to each collapse's quadric
    optimum), so the result is a new surface: its own exact geodesics are its ground truth.

    Returns:
        ``(V', 3)`` float64 vertices and ``(F', 3)`` int64 faces.

    Raises:
        ArrayShapeError: fewer than 4 target vertices.
        MissingDependencyError: pymeshlab is not installed.
        ComputationError: the simplification failed.
    """
    if n_vertices < 4:
        raise ArrayShapeError(f"n_vertices must be at least 4, got {n_vertices}")
    from litege_core.synth.meshops import run_pymeshlab  # the generators: on first use

    return run_pymeshlab(  # a closed surface has about twice as many faces as vertices
        vertices,
        faces,
        "decimation",
        lambda mesh_set, _: mesh_set.meshing_decimation_quadric_edge_collapse(
            targetfacenum=2 * int(n_vertices), preservetopology=True, planarquadric=True
        ),
    )


def broken_mesh(
    faces: NDArray, fraction_removed: float = 0.4, seed: int | np.random.Generator = 0
) -> NDArray:
    """Indices of the faces kept after removing ``fraction_removed`` of them at random.

    Vertices are kept as they are (so vertex i still corresponds to vertex i); consumers must
    sample the *remaining* surface, never the intact vertex set (reference-spec §1.4 trap).
    """
    if not 0.0 <= fraction_removed < 1.0:
        raise ArrayShapeError(f"fraction_removed must be in [0, 1), got {fraction_removed}")
    rng = np.random.default_rng(seed)
    n_keep = round(faces.shape[0] * (1.0 - fraction_removed))
    return np.sort(rng.choice(faces.shape[0], size=n_keep, replace=False))


def point_cloud(
    vertices: NDArray, faces: NDArray, n_points: int, seed: int | np.random.Generator = 0
) -> PointVariant:
    """``n_points`` area-weighted samples of the mesh with their location on it."""
    samples = sample_surface(vertices, faces, n_points, seed)
    return PointVariant(samples.points, SurfaceLocation(samples.face_index, samples.barycentric))


def add_noise(points: NDArray, sigma: float, seed: int | np.random.Generator = 0) -> NDArray:
    """Add isotropic Gaussian noise of standard deviation ``sigma`` (units of ``points``)."""
    return points + np.random.default_rng(seed).normal(0.0, sigma, size=points.shape)


def add_outliers(
    points: NDArray, fraction: float, seed: int | np.random.Generator = 0, margin: float = 0.1
) -> NDArray:
    """``points`` followed by ``round(fraction · N)`` stray points drawn uniformly in their
    bounding box grown by ``margin`` × its extent on every side (a scan's outliers)."""
    if not (math.isfinite(fraction) and fraction >= 0.0):
        raise ArrayShapeError(f"fraction must be finite and >= 0, got {fraction}")
    low, high = points.min(axis=0), points.max(axis=0)
    pad = margin * (high - low)
    count = round(fraction * points.shape[0])
    stray = np.random.default_rng(seed).uniform(low - pad, high + pad, size=(count, 3))
    return np.concatenate([points, stray])


def repeated_points(n_points: int, fraction: float, seed: int | np.random.Generator = 0) -> NDArray:
    """``(R,)`` int64 indices of ``round(fraction · N)`` of ``N`` points, drawn without
    replacement (seeded): the points a scan sends twice (``points[index]`` appended)."""
    if not (math.isfinite(fraction) and 0.0 <= fraction <= 1.0):
        raise ArrayShapeError(f"fraction must be in [0, 1], got {fraction}")
    count = round(fraction * n_points)
    rng = np.random.default_rng(seed)
    return np.sort(rng.choice(n_points, count, replace=False)).astype(np.int64)


def cut_by_planes(
    points: NDArray,
    fraction_removed: float,
    seed: int | np.random.Generator = 0,
    direction: NDArray | None = None,
) -> NDArray:
    """Boolean mask of the points kept between two parallel planes.

    Points are projected on ``direction`` (default a random unit vector) and those below the
    ``f/2`` quantile or above the ``1 − f/2`` quantile are cut, removing a fraction ``f`` of
    the samples, i.e. of the surface for area-weighted samples (the paper's "missing regions").
    """
    if not 0.0 <= fraction_removed < 1.0:
        raise ArrayShapeError(f"fraction_removed must be in [0, 1), got {fraction_removed}")
    if direction is None:
        direction = np.random.default_rng(seed).normal(size=3)
    direction = np.asarray(direction, dtype=np.float64)
    direction = direction / np.linalg.norm(direction)
    projection = points @ direction
    low, high = np.quantile(projection, [fraction_removed / 2.0, 1.0 - fraction_removed / 2.0])
    return (projection >= low) & (projection <= high)


__all__ = [
    "MeshVariant",
    "PointVariant",
    "SurfaceLocation",
    "add_noise",
    "anisotropic_remesh",
    "broken_mesh",
    "cut_by_planes",
    "isotropic_remesh",
    "locate_on_mesh",
    "point_cloud",
    "random_rotation",
    "repeated_points",
    "rotate",
    "small_rotation",
]
