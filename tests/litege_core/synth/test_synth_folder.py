"""Folder collections: rigged, animated glTF files are posed by their own clips."""

import base64
import json
from pathlib import Path

import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from litege_core.datasets import GeodesicDataset, build_collection_dataset, shape_mesh
from litege_core.synth.folder import FolderSettings, folder_shape, list_meshes, rigged_model

SETTINGS = FolderSettings(vertex_range=(400, 500), stretch_probability=0.0)


def _rigged_capsule(path: Path, animated: bool = True) -> Path:
    """A closed capsule along x (x in [0, 2.6]) skinned to two joints: joint 0 at the origin,
    joint 1 at x = 1.3 (child of joint 0), weights blended over 0.8 < x < 1.8. Its one clip
    turns joint 1 about z from 0 to 90 degrees over one second: the far half bends up."""
    capsule = trimesh.creation.capsule(height=2.0, radius=0.3, count=[16, 16])
    capsule.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [0, 1, 0]))
    positions = (capsule.vertices - [capsule.vertices[:, 0].min(), 0.0, 0.0]).astype(np.float32)
    faces = capsule.faces.astype(np.uint32)
    w1 = np.clip((positions[:, 0] - 0.8) / 1.0, 0.0, 1.0)
    joints = np.tile(np.array([0, 1, 0, 0], np.uint8), (len(positions), 1))
    weights = np.zeros((len(positions), 4), np.float32)
    weights[:, 0], weights[:, 1] = 1.0 - w1, w1
    inverse_bind = np.stack([np.eye(4), np.eye(4)]).astype(np.float32)
    inverse_bind[1, 0, 3] = -1.3
    times = np.array([0.0, 1.0], np.float32)
    turns = Rotation.from_rotvec([[0, 0, 0], [0, 0, np.pi / 2]]).as_quat().astype(np.float32)
    blobs = [
        positions.tobytes(),
        faces.tobytes(),
        joints.tobytes(),
        weights.tobytes(),
        inverse_bind.transpose(0, 2, 1).copy().tobytes(),  # column-major
        times.tobytes(),
        turns.tobytes(),
    ]
    views, offset = [], 0
    for blob in blobs:
        views.append({"buffer": 0, "byteOffset": offset, "byteLength": len(blob)})
        offset += len(blob)
    n = len(positions)
    document = {
        "asset": {"version": "2.0"},
        "scenes": [{"nodes": [0, 2]}],
        "nodes": [
            {"name": "root", "children": [1]},
            {"name": "tip", "translation": [1.3, 0.0, 0.0]},
            {"name": "capsule", "mesh": 0, "skin": 0},
        ],
        "meshes": [
            {
                "primitives": [
                    {"attributes": {"POSITION": 0, "JOINTS_0": 2, "WEIGHTS_0": 3}, "indices": 1}
                ]
            }
        ],
        "skins": [{"joints": [0, 1], "inverseBindMatrices": 4}],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": n, "type": "VEC3"},
            {"bufferView": 1, "componentType": 5125, "count": faces.size, "type": "SCALAR"},
            {"bufferView": 2, "componentType": 5121, "count": n, "type": "VEC4"},
            {"bufferView": 3, "componentType": 5126, "count": n, "type": "VEC4"},
            {"bufferView": 4, "componentType": 5126, "count": 2, "type": "MAT4"},
            {"bufferView": 5, "componentType": 5126, "count": 2, "type": "SCALAR"},
            {"bufferView": 6, "componentType": 5126, "count": 2, "type": "VEC4"},
        ],
        "bufferViews": views,
        "buffers": [
            {
                "byteLength": offset,
                "uri": "data:application/octet-stream;base64,"
                + base64.b64encode(b"".join(blobs)).decode(),
            }
        ],
    }
    if animated:
        document["animations"] = [
            {
                "name": "lift",
                "channels": [{"sampler": 0, "target": {"node": 1, "path": "rotation"}}],
                "samplers": [{"input": 5, "output": 6, "interpolation": "LINEAR"}],
            }
        ]
    path.write_text(json.dumps(document))
    return path


def _height_over_length(vertices: np.ndarray) -> float:
    extent = np.ptp(vertices, axis=0)
    return float(extent[1] / extent[0])


def test_a_rigged_file_takes_a_pose_of_its_clip_per_seed(tmp_path):
    _rigged_capsule(tmp_path / "capsule.gltf")
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


def test_stored_pose_without_poses_or_without_a_clip(tmp_path):
    _rigged_capsule(tmp_path / "capsule.gltf")
    _rigged_capsule(tmp_path / "still.gltf", animated=False)
    assert list_meshes(tmp_path) == ("capsule.gltf", "still.gltf")
    assert rigged_model(str(tmp_path / "still.gltf")) is None
    static = FolderSettings(vertex_range=(400, 500), stretch_probability=0.0, poses=False)
    for name, settings in (("capsule.gltf", static), ("still.gltf", SETTINGS)):
        bends = [
            _height_over_length(folder_shape(tmp_path, name, seed, settings)[0])
            for seed in range(3)
        ]
        assert max(bends) < 0.3  # the straight capsule: 0.6 across, 2.6 long


def test_the_settings_name_the_poses():
    assert FolderSettings().describe() != FolderSettings(poses=False).describe()


@pytest.mark.parametrize("suffix", ["glb", "obj"])
def test_only_gltf_files_are_rigs(tmp_path, suffix):
    path = tmp_path / f"box.{suffix}"
    trimesh.creation.box().export(path)
    assert rigged_model(str(path)) is None


def test_a_collection_built_from_rigs_holds_their_poses(tmp_path):
    meshes = tmp_path / "rigs"
    meshes.mkdir()
    for i in range(3):  # one file per split
        _rigged_capsule(meshes / f"capsule{i}.gltf")
    manifest = build_collection_dataset(
        meshes,
        tmp_path / "data",
        shapes_per_mesh=4,
        eval_shapes_per_mesh=1,
        n_sources=4,
        n_extra_sources=2,
        settings=FolderSettings(vertex_range=(150, 200), stretch_probability=0.0),
        progress=False,
    )
    assert manifest["generator"]["version"].endswith(",r1")
    train = GeodesicDataset(tmp_path / "data").load_split("train")
    bends = [_height_over_length(shape_mesh(train, i)[0]) for i in range(4)]
    assert max(bends) > 2.0 * min(bends)
