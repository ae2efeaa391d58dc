"""Folder collections: rigged, animated glTF files posed by their own clips; files checked
up front; a shape no draw can remesh falls back to its file's reference shape."""

import numpy as np
import pytest
import trimesh

from litege_core.datasets import GeodesicDataset, build_collection_dataset, shape_mesh
from litege_core.errors import InputError
from litege_core.synth import folder
from litege_core.synth.folder import (
    FolderSettings,
    check_files,
    folder_shape,
    list_meshes,
    prepare_mesh,
    reference_shape,
    rigged_model,
)

SETTINGS = FolderSettings(vertex_range=(400, 500), stretch_probability=0.0, poses=True)


def _height_over_length(vertices: np.ndarray) -> float:
    extent = np.ptp(vertices, axis=0)
    return float(extent[1] / extent[0])


def test_a_rigged_file_takes_a_pose_of_its_clip_per_seed(tmp_path, rigged_gltf):
    rigged_gltf(tmp_path / "capsule.gltf")
    rig = rigged_model(str(tmp_path / "capsule.gltf"))
    assert rig is not None and [clip.name for clip in rig.clips] == ["lift"]
    shapes = [folder_shape(tmp_path, "capsule.gltf", seed, SETTINGS) for seed in range(6)]
    bends = [_height_over_length(vertices) for vertices, _ in shapes]
    assert max(bends) > 2.0 * min(bends)  # the far half lifted by different angles
    again = folder_shape(tmp_path, "capsule.gltf", 3, SETTINGS)
    np.testing.assert_array_equal(again[0], shapes[3][0])  # a pure function of the seed
    for vertices, faces in shapes:
        mesh = trimesh.Trimesh(vertices, faces, process=False)
        assert mesh.is_watertight and mesh.body_count == 1


def test_stored_pose_by_default_or_without_a_clip(tmp_path, rigged_gltf):
    rigged_gltf(tmp_path / "capsule.gltf")
    rigged_gltf(tmp_path / "still.gltf", animated=False)
    assert list_meshes(tmp_path) == ("capsule.gltf", "still.gltf")
    assert rigged_model(str(tmp_path / "still.gltf")) is None
    static = FolderSettings(vertex_range=(400, 500), stretch_probability=0.0)  # the default
    for name, settings in (("capsule.gltf", static), ("still.gltf", SETTINGS)):
        bends = [
            _height_over_length(folder_shape(tmp_path, name, seed, settings)[0])
            for seed in range(3)
        ]
        assert max(bends) < 0.3  # the straight capsule: 0.6 across, 2.6 long


def test_the_settings_name_the_poses():
    assert not FolderSettings().poses  # opt-in (BENCHMARKS.md "rig-poses")
    assert FolderSettings().describe() != FolderSettings(poses=True).describe()


@pytest.mark.parametrize("suffix", ["glb", "obj"])
def test_only_gltf_files_are_rigs(tmp_path, suffix):
    path = tmp_path / f"box.{suffix}"
    trimesh.creation.box().export(path)
    assert rigged_model(str(path)) is None


def test_a_collection_built_from_rigs_holds_their_poses(tmp_path, rigged_gltf):
    meshes = tmp_path / "rigs"
    meshes.mkdir()
    for i in range(3):  # one file per split
        rigged_gltf(meshes / f"capsule{i}.gltf")
    manifest = build_collection_dataset(
        meshes,
        tmp_path / "data",
        shapes_per_mesh=4,
        eval_shapes_per_mesh=1,
        n_sources=4,
        n_extra_sources=2,
        settings=FolderSettings(vertex_range=(150, 200), stretch_probability=0.0, poses=True),
        progress=False,
    )
    assert manifest["generator"]["version"].endswith(",r1")
    train = GeodesicDataset(tmp_path / "data").load_split("train")
    bends = [_height_over_length(shape_mesh(train, i)[0]) for i in range(4)]
    assert max(bends) > 2.0 * min(bends)


def test_a_shell_pinched_onto_the_body_is_dropped(tmp_path):
    body = trimesh.creation.icosphere(subdivisions=3)
    top = int(np.argmax(body.vertices[:, 2]))
    horn = trimesh.creation.icosphere(subdivisions=1, radius=0.2)
    horn.vertices += body.vertices[top] - horn.vertices[np.argmin(horn.vertices[:, 2])]
    # the horn's lowest vertex is the body's top vertex: one shell, pinched there
    lowest = int(np.argmin(horn.vertices[:, 2]))
    horn_index = np.arange(len(horn.vertices)) + len(body.vertices)
    horn_index[lowest] = top
    vertices = np.concatenate([body.vertices, horn.vertices])
    faces = np.concatenate([body.faces, horn_index[horn.faces]])
    trimesh.Trimesh(vertices, faces, process=False).export(tmp_path / "horned.obj")
    prepared = prepare_mesh(str(tmp_path / "horned.obj"))
    assert len(prepared.faces) == len(body.faces) and prepared.closed
    vertices, faces = folder_shape(tmp_path, "horned.obj", 0, SETTINGS)
    assert trimesh.Trimesh(vertices, faces, process=False).is_watertight


def test_unusable_files_are_named_together_before_any_shape(tmp_path, rigged_gltf):
    trimesh.creation.icosphere(subdivisions=2).export(tmp_path / "good.obj")
    rigged_gltf(tmp_path / "rig.gltf")
    trimesh.PointCloud(np.random.default_rng(0).normal(size=(50, 3))).export(tmp_path / "c.ply")
    (tmp_path / "broken.obj").write_text("v 0 0 0\nv 1 0 nan\nv 0 1 0\nf 1 2 3\n")
    files = list_meshes(tmp_path)
    with pytest.raises(InputError, match="2 of 4 mesh files cannot be used") as error:
        check_files(tmp_path, files)
    assert "broken.obj" in error.value.message and "c.ply" in error.value.message
    check_files(tmp_path, ("good.obj", "rig.gltf"))  # the good ones pass


def _flattened(vertices, rng, **_):
    """A 'stretch' that presses the surface flat: no remesh of it is a closed manifold."""
    return vertices * np.array([1.0, 1.0, 0.0])


def test_a_shape_whose_every_draw_fails_is_the_files_reference_shape(tmp_path, monkeypatch):
    trimesh.creation.icosphere(subdivisions=3).export(tmp_path / "ball.obj")
    settings = FolderSettings(vertex_range=(300, 400), stretch_probability=1.0)
    reference, reference_faces = reference_shape(tmp_path, "ball.obj", settings)
    assert not reference.flags.writeable and 250 <= len(reference) <= 450
    assert np.ptp(reference, axis=0).min() > 0.5  # the ball as stored, unstretched
    monkeypatch.setattr(folder, "smooth_stretch", _flattened)
    for seed in (0, 1):
        vertices, faces = folder_shape(tmp_path, "ball.obj", seed, settings)
        np.testing.assert_array_equal(vertices, reference)
        np.testing.assert_array_equal(faces, reference_faces)
        assert vertices.flags.writeable  # the caller's own copy
    unstretched = FolderSettings(vertex_range=(300, 400), stretch_probability=0.0)
    drawn = folder_shape(tmp_path, "ball.obj", 0, unstretched)[0]
    assert np.ptp(drawn, axis=0).min() > 0.5 and not np.array_equal(drawn, reference)


def test_a_rigs_reference_shape_is_its_rest_pose(tmp_path, rigged_gltf):
    rigged_gltf(tmp_path / "capsule.gltf")
    vertices, faces = reference_shape(tmp_path, "capsule.gltf", SETTINGS)
    assert _height_over_length(vertices) < 0.3  # the straight capsule
    assert trimesh.Trimesh(vertices, faces, process=False).is_watertight


def test_a_file_whose_reference_shape_cannot_be_remeshed_is_named_up_front(tmp_path, monkeypatch):
    trimesh.creation.icosphere(subdivisions=2).export(tmp_path / "good.obj")
    trimesh.creation.box().export(tmp_path / "torn.obj")
    remesh = folder.remesh

    def tearing(vertices, faces, n_target, **kwargs):  # the box (12 faces) comes out open
        new_vertices, new_faces = remesh(vertices, faces, n_target, **kwargs)
        return new_vertices, new_faces[1:] if len(faces) == 12 else new_faces

    monkeypatch.setattr(folder, "remesh", tearing)
    settings = FolderSettings(vertex_range=(300, 400))
    with pytest.raises(InputError, match="1 of 2 mesh files cannot be used") as error:
        check_files(tmp_path, ("good.obj", "torn.obj"), settings)
    assert "torn.obj: the remeshed surface is not a clean manifold" in error.value.message


def test_poses_of_few_files_get_enough_shapes_by_default():
    assert folder.shapes_per_file(1, True, (10, 2)) == (120, 8)  # folder.POSE_SPLIT_SHAPES
    assert folder.shapes_per_file(2, True, (10, 2)) == (60, 4)
    assert folder.shapes_per_file(2, True, (200, 9)) == (200, 9)  # never fewer than asked
    assert folder.shapes_per_file(3, True, (10, 2)) == (10, 2)  # split by file: per file
    assert folder.shapes_per_file(1, False, (10, 2)) == (10, 2)
    assert folder.shapes_per_file(1, True, (10, 2), (5, None)) == (5, 8)  # given counts win
    assert folder.shapes_per_file(3, False, (10, 2), (None, 0)) == (10, 0)
    shared = folder.pose_splits(("a.glb",), 0)
    assert shared == {s: ("a.glb",) for s in ("train", "val", "test")}
    assert folder.splits_share_files(shared)
    by_file = folder.pose_splits(("a.glb", "b.glb", "c.glb"), 0)
    assert not folder.splits_share_files(by_file)
