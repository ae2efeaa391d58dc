"""Mesh operations for real and user meshes: welding, components, manifold checks, sliver
collapse, remeshing, smooth stretch, and folder shapes."""

import numpy as np
import pytest
import trimesh

from litege_core.errors import EmptyShapeError, FaceIndexError, InputError
from litege_core.synth import folder, meshops

SPHERE = trimesh.creation.icosphere(subdivisions=2)


def _split_at_seams(vertices, faces):
    """Duplicate every vertex once per face corner (like glTF's per-material primitives)."""
    return vertices[faces.ravel()], np.arange(faces.size).reshape(-1, 3)


def test_weld_recovers_the_mesh_and_keeps_a_representative():
    raw_vertices, raw_faces = _split_at_seams(np.asarray(SPHERE.vertices), np.asarray(SPHERE.faces))
    welded = meshops.weld(raw_vertices, raw_faces)
    assert welded.vertices.shape == SPHERE.vertices.shape
    assert welded.faces.shape == SPHERE.faces.shape
    np.testing.assert_array_equal(raw_vertices[welded.representative], welded.vertices)
    report = meshops.manifold_report(welded.vertices, welded.faces)
    assert report.ok and report.euler == 2


def test_largest_component_drops_small_shells():
    small = trimesh.creation.icosphere(subdivisions=0)
    vertices = np.concatenate([SPHERE.vertices, small.vertices * 0.1 + 3.0])
    faces = np.concatenate([SPHERE.faces, small.faces + len(SPHERE.vertices)])
    kept, new_faces = meshops.largest_component(faces, len(vertices))
    np.testing.assert_array_equal(kept, np.arange(len(SPHERE.vertices)))
    np.testing.assert_array_equal(new_faces, SPHERE.faces)


def test_manifold_report_flags_holes_flips_and_non_manifold_edges():
    vertices, faces = np.asarray(SPHERE.vertices), np.asarray(SPHERE.faces)
    assert not meshops.manifold_report(vertices, faces[1:]).closed
    flipped = faces.copy()
    flipped[0] = flipped[0, ::-1]
    assert not meshops.manifold_report(vertices, flipped).oriented
    fin = np.concatenate([faces, [[faces[0, 0], faces[0, 1], 5]]])
    assert not meshops.manifold_report(vertices, fin).manifold
    # two closed shells touching at one vertex: every edge has two faces, the vertex is pinched
    other = vertices + (vertices[0] - vertices[7])
    pinched = meshops.weld(np.concatenate([vertices, other]), np.concatenate([faces, faces + 162]))
    report = meshops.manifold_report(pinched.vertices, pinched.faces)
    assert report.closed and report.oriented and not report.manifold
    # a repeated face (both orientations) glued onto a closed mesh
    pillow = np.concatenate([faces, [[0, 1, 200], [1, 0, 200]]])
    extra = np.concatenate([vertices, np.zeros((39, 3)) + 2.0])
    assert not meshops.manifold_report(extra, pillow).manifold


def test_collapse_slivers_removes_a_needle_and_keeps_a_closed_manifold():
    vertices, faces = np.asarray(SPHERE.vertices, float).copy(), np.asarray(SPHERE.faces)
    a, b = faces[0, :2]
    vertices[b] = vertices[a] + 1e-4 * (vertices[b] - vertices[a])  # a needle at face 0
    assert meshops.min_angles(vertices, faces).min() < 1.0
    new_vertices, new_faces = meshops.collapse_slivers(vertices, faces, min_angle=5.0)
    report = meshops.manifold_report(new_vertices, new_faces)
    assert report.closed and report.oriented and report.manifold and report.euler == 2
    assert report.min_angle > 5.0 and len(new_vertices) == len(vertices) - 1


def test_repair_manifold_removes_a_fin_and_keeps_vertices():
    vertices, faces = np.asarray(SPHERE.vertices), np.asarray(SPHERE.faces)
    fin = np.concatenate([faces, [[faces[0, 0], faces[0, 1], 100]]])
    repaired, origin = meshops.repair_manifold(vertices, fin)
    np.testing.assert_array_equal(origin[: len(vertices)], np.arange(len(vertices)))
    report = meshops.manifold_report(vertices[origin], repaired)
    assert report.closed and report.manifold and report.oriented


def test_split_pinched_vertices_separates_the_fans():
    vertices, faces = np.asarray(SPHERE.vertices), np.asarray(SPHERE.faces)
    other = vertices + (vertices[0] - vertices[7])
    pinched = meshops.weld(np.concatenate([vertices, other]), np.concatenate([faces, faces + 162]))
    new_faces, origin = meshops.split_pinched_vertices(pinched.faces, len(pinched.vertices))
    assert len(origin) > len(pinched.vertices)
    np.testing.assert_array_equal(
        pinched.vertices[origin][new_faces], pinched.vertices[pinched.faces]
    )
    report = meshops.manifold_report(pinched.vertices[origin], new_faces)
    assert report.manifold and report.closed and report.components == 2 and report.euler == 4


def test_remesh_hits_the_vertex_budget_on_a_closed_manifold():
    vertices, faces = meshops.remesh(SPHERE.vertices, SPHERE.faces, 600, tolerance=0.1)
    assert abs(len(vertices) / 600 - 1.0) < 0.2
    report = meshops.manifold_report(vertices, faces)
    assert report.closed and report.manifold and report.euler == 2


def test_smooth_stretch_is_seeded_and_does_not_fold():
    vertices, faces = np.asarray(SPHERE.vertices), np.asarray(SPHERE.faces)
    first = meshops.smooth_stretch(vertices, np.random.default_rng(3))
    np.testing.assert_array_equal(first, meshops.smooth_stretch(vertices, np.random.default_rng(3)))
    assert not np.allclose(first, meshops.smooth_stretch(vertices, np.random.default_rng(4)))

    def normals(v):
        n = np.cross(v[faces[:, 1]] - v[faces[:, 0]], v[faces[:, 2]] - v[faces[:, 0]])
        return n / np.linalg.norm(n, axis=1, keepdims=True)

    assert (np.einsum("ij,ij->i", normals(vertices), normals(first)) > 0.5).all()
    assert 0.5 < np.ptp(first, axis=0).max() / np.ptp(vertices, axis=0).max() < 1.5


@pytest.fixture()
def mesh_folder(tmp_path):
    trimesh.creation.icosphere(subdivisions=2).export(tmp_path / "ball.obj")
    trimesh.creation.capsule(height=1.5, radius=0.4, count=(12, 12)).export(tmp_path / "pill.ply")
    (tmp_path / "sub").mkdir()
    trimesh.creation.box(extents=(1.0, 0.6, 0.3)).export(tmp_path / "sub" / "brick.off")
    trimesh.creation.torus(1.0, 0.35).export(tmp_path / "sub" / "ring.stl")
    (tmp_path / "notes.txt").write_text("not a mesh")
    return tmp_path


def test_folder_listing_and_split_by_file(mesh_folder, tmp_path_factory):
    files = folder.list_meshes(mesh_folder)
    assert files == ("ball.obj", "pill.ply", "sub/brick.off", "sub/ring.stl")
    split = folder.split_files(files, seed=1)
    assert split == folder.split_files(files, seed=1)
    assert sorted(split["train"] + split["val"] + split["test"]) == list(files)
    assert len(split["val"]) == len(split["test"]) == 1
    with pytest.raises(InputError):
        folder.list_meshes(tmp_path_factory.mktemp("empty"))


def test_folder_shapes_are_seeded_clean_and_varied(mesh_folder):
    settings = folder.FolderSettings(vertex_range=(300, 500))
    first = folder.folder_shape(mesh_folder, "sub/ring.stl", 7, settings)
    again = folder.folder_shape(mesh_folder, "sub/ring.stl", 7, settings)
    other = folder.folder_shape(mesh_folder, "sub/ring.stl", 8, settings)
    np.testing.assert_array_equal(first[0], again[0])
    np.testing.assert_array_equal(first[1], again[1])
    assert first[0].shape != other[0].shape or not np.allclose(first[0], other[0])
    for vertices, faces in (first, other):
        report = meshops.manifold_report(vertices, faces)
        assert report.ok and report.euler == 0  # a torus stays a torus
        assert 250 <= len(vertices) <= 600


def test_folder_accepts_open_surfaces_and_refuses_degenerate_files(tmp_path):
    (tmp_path / "sheet.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nf 1 2 3\nf 2 4 3\n")
    vertices, faces = folder.folder_shape(
        tmp_path, "sheet.obj", 0, folder.FolderSettings((200, 300))
    )
    report = meshops.manifold_report(vertices, faces)
    assert not report.closed and report.manifold and report.oriented and report.components == 1
    (tmp_path / "line.obj").write_text("v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n")
    with pytest.raises(InputError):
        folder.folder_shape(tmp_path, "line.obj", 0)


def test_folder_errors_name_the_file_and_keep_their_problem_type(tmp_path):
    """A broken file or a PLY point cloud is refused with its path and its error class."""
    (tmp_path / "broken.obj").write_text("v 0 0 0\nv 1 0 0\nf 1 2 9\n")
    with pytest.raises(FaceIndexError, match=r"broken\.obj: "):
        folder.folder_shape(tmp_path, "broken.obj", 0)
    trimesh.PointCloud(np.random.default_rng(0).random((50, 3))).export(tmp_path / "scan.ply")
    assert "scan.ply" in folder.list_meshes(tmp_path)
    with pytest.raises(EmptyShapeError, match=r"scan\.ply: the file has no faces"):
        folder.folder_shape(tmp_path, "scan.ply", 0)


def test_largest_body_cuts_off_a_shell_pinched_at_one_vertex():
    body = trimesh.creation.icosphere(subdivisions=2)
    top = int(np.argmax(body.vertices[:, 2]))
    horn = trimesh.creation.icosphere(subdivisions=1, radius=0.2)
    lowest = int(np.argmin(horn.vertices[:, 2]))
    horn.vertices += body.vertices[top] - horn.vertices[lowest]
    index = np.arange(len(horn.vertices)) + len(body.vertices)
    index[lowest] = top  # the horn touches the body at that one vertex
    vertices = np.concatenate([body.vertices, horn.vertices])
    faces = np.concatenate([body.faces, index[horn.faces]])
    kept, kept_faces = meshops.largest_body(vertices, faces)
    assert len(kept_faces) == len(body.faces) and len(kept) == len(body.vertices)
    np.testing.assert_array_equal(vertices[kept], body.vertices)
    assert meshops.manifold_report(vertices[kept], kept_faces).ok
