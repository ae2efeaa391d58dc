"""Occupancy: ray-parity inside test, exact surface voxels, point occupancy vs slow references."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from litege_core.descriptor import occupancy as occ
from litege_core.descriptor.grid import VoxelGrid
from litege_core.errors import ArrayShapeError, FaceIndexError, InputError, NonFiniteError

SMALL = VoxelGrid(resolution=24, pitch=0.07)


def _meshes() -> dict[str, trimesh.Trimesh]:
    rng = np.random.default_rng(1)
    sphere = trimesh.creation.icosphere(subdivisions=2, radius=0.6)
    sphere.apply_scale([1.1, 0.7, 0.5])
    rotation = trimesh.transformations.random_rotation_matrix(rng.random(3))
    box = trimesh.creation.box(extents=[0.9, 0.5, 0.33], transform=rotation)
    torus = trimesh.creation.torus(
        major_radius=0.45, minor_radius=0.15, major_sections=16, minor_sections=8
    )
    capsule = trimesh.creation.capsule(height=0.6, radius=0.2, count=[8, 8])
    capsule.apply_translation([0.1, -0.05, 0.03])
    return {"ellipsoid": sphere, "rotated_box": box, "torus": torus, "capsule": capsule}


@pytest.mark.parametrize("name", ["ellipsoid", "rotated_box", "torus", "capsule"])
def test_inside_matches_winding_number_on_watertight_meshes(name: str) -> None:
    mesh = _meshes()[name]
    assert mesh.is_watertight
    inside = occ.mesh_inside(mesh.vertices, mesh.faces, SMALL)
    winding = occ.winding_number_reference(mesh.vertices, mesh.faces, SMALL.centers())
    reference = winding > 0.5
    surface = occ.mesh_surface_voxels(mesh.vertices, mesh.faces, SMALL)
    # disagreements only where the surface passes through the voxel (centres on the surface)
    assert not np.any((inside != reference) & ~surface)
    assert inside.sum() > 100
    np.testing.assert_array_equal(
        occ.mesh_occupancy(mesh.vertices, mesh.faces, SMALL), reference | surface
    )


def test_axis_aligned_box_on_grid_lines_counts_exactly() -> None:
    """Faces, edges and diagonals through voxel centres exercise the tie-breaking rules."""
    grid = VoxelGrid()
    box = trimesh.creation.box(extents=[1.0, 1.0, 1.0])  # corners at ±0.5 = voxel centres
    occupied = occ.mesh_occupancy(box.vertices, box.faces, grid).reshape(grid.shape)
    expected = np.zeros(grid.shape, dtype=bool)
    expected[35:86, 35:86, 35:86] = True  # centres with |c| ≤ 0.5 on every axis
    np.testing.assert_array_equal(occupied, expected)
    inside = occ.mesh_inside(box.vertices, box.faces, grid).reshape(grid.shape)
    assert inside[36:85, 36:85, 36:85].all() and not inside[~expected].any()


def test_inside_copes_with_holes() -> None:
    sphere = trimesh.creation.icosphere(subdivisions=2, radius=0.7)
    rng = np.random.default_rng(0)
    keep = np.ones(len(sphere.faces), dtype=bool)
    keep[rng.choice(len(keep), 10, replace=False)] = False  # ~3 % of the faces gone
    holed = sphere.faces[keep]
    closed = occ.winding_number_reference(sphere.vertices, sphere.faces, SMALL.centers()) > 0.5
    surface = occ.mesh_surface_voxels(sphere.vertices, sphere.faces, SMALL)
    inside = occ.mesh_inside(sphere.vertices, holed, SMALL)
    wrong = (inside != closed) & ~surface
    assert wrong.sum() <= 0.01 * closed.sum()
    # a single-direction parity test would mark whole columns wrong through every hole
    _below, odd = occ._column_parity(sphere.vertices, holed, SMALL, axis=2)
    assert odd.any()


def test_surface_voxels_match_clipping_reference() -> None:
    grid = VoxelGrid(resolution=6, pitch=0.2)
    rng = np.random.default_rng(4)
    vertices = rng.uniform(-0.7, 0.7, (15, 3))
    faces = rng.integers(0, 15, (6, 3))
    faces = faces[(faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2])]
    faces = faces[faces[:, 0] != faces[:, 2]]
    small = np.array([[0.01, 0.02, 0.03], [0.05, 0.02, 0.03], [0.01, 0.06, 0.04]])
    vertices = np.vstack([vertices, small + 0.1])  # a triangle inside one voxel
    faces = np.vstack([faces, [[15, 16, 17]]])
    fast = occ.mesh_surface_voxels(vertices, faces, grid)
    slow = occ.surface_voxels_reference(vertices, faces, grid)
    np.testing.assert_array_equal(fast, slow)
    assert 0 < fast.sum() < grid.n_voxels


def test_surface_voxels_independent_of_chunking(monkeypatch: pytest.MonkeyPatch) -> None:
    mesh = _meshes()["torus"]
    full = occ.mesh_surface_voxels(mesh.vertices, mesh.faces, SMALL)
    inside = occ.mesh_inside(mesh.vertices, mesh.faces, SMALL)
    monkeypatch.setattr(occ, "_CANDIDATE_BUDGET", 64)
    np.testing.assert_array_equal(occ.mesh_surface_voxels(mesh.vertices, mesh.faces, SMALL), full)
    np.testing.assert_array_equal(occ.mesh_inside(mesh.vertices, mesh.faces, SMALL), inside)


def test_every_surface_sample_lies_in_a_surface_voxel() -> None:
    mesh = _meshes()["ellipsoid"]
    surface = occ.mesh_surface_voxels(mesh.vertices, mesh.faces, SMALL)
    samples, _ = trimesh.sample.sample_surface(mesh, 20000, seed=0)
    assert surface[SMALL.point_to_voxel(samples)].all()


def test_large_triangles_beyond_the_grid() -> None:
    grid = VoxelGrid(resolution=10, pitch=0.1)
    vertices = np.array([[-3.0, -3.0, 0.02], [3.0, -3.0, 0.02], [0.0, 4.0, 0.02]])
    surface = occ.mesh_surface_voxels(vertices, [[0, 1, 2]], grid).reshape(grid.shape)
    assert surface[:, :, 5].all() and surface.sum() == 100  # the plane z=0.02 cuts layer k=5


@pytest.mark.parametrize("dilation", [0, 1, 2])
def test_point_cloud_occupancy_matches_reference(dilation: int) -> None:
    grid = VoxelGrid(resolution=7, pitch=0.15)
    rng = np.random.default_rng(dilation)
    points = rng.uniform(-0.6, 0.6, (30, 3))
    points[0] = [2.0, 0.0, 0.0]  # outside the grid: ignored
    fast = occ.point_cloud_occupancy(points, grid, dilation)
    slow = occ.point_cloud_occupancy_reference(points, grid, dilation)
    np.testing.assert_array_equal(fast, slow)


def test_invalid_inputs() -> None:
    grid = VoxelGrid(resolution=4, pitch=0.1)
    vertices = np.zeros((3, 3))
    vertices[1, 0] = vertices[2, 1] = 0.1
    with pytest.raises(FaceIndexError):
        occ.mesh_occupancy(vertices, [[0, 1, 3]], grid)
    with pytest.raises(ArrayShapeError):
        occ.mesh_occupancy(vertices[:, :2], [[0, 1, 2]], grid)
    with pytest.raises(NonFiniteError):
        occ.mesh_inside(np.where(vertices == 0.1, np.inf, vertices), [[0, 1, 2]], grid)
    with pytest.raises(InputError):
        occ.point_cloud_occupancy(vertices, grid, dilation=-1)
    with pytest.raises(ArrayShapeError):
        occ.point_cloud_occupancy(np.zeros((4, 2)), grid)
