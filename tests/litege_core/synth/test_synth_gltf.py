"""glTF reading and linear blend skinning on a hand-built two-joint rig (and on the real
rigged animals when the train-data directory is present)."""

import base64
import json
import os
import struct
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from litege_core.errors import ShapeFileError
from litege_core.synth import gltf

TRAIN_DATA = Path(
    os.environ.get("LITEGE_TRAIN_DATA")
    or Path(__file__).resolve().parents[4] / "shared" / "train-data"
)


def _quat(axis, degrees):
    """(x, y, z, w) quaternion of a rotation."""
    return Rotation.from_rotvec(np.asarray(axis, float) * np.radians(degrees)).as_quat()


def _chain_document(animated_degrees: float = 90.0) -> tuple[dict, bytes, dict]:
    """A strip of 8 vertices along x (0..3) skinned to a 2-joint chain: joint 0 at the origin,
    joint 1 at x = 2 (child of joint 0). Vertices at x < 1 follow joint 0 only, at x > 2.5
    joint 1 only, the ones between are blended. One clip rotates joint 1 about z from 0° to
    ``animated_degrees`` over one second."""
    xs = np.array([0.0, 0.5, 1.0, 1.5, 2.0, 2.5, 3.0, 3.0])
    ys = np.array([0.0, 0.1, 0.0, 0.1, 0.05, 0.1, 0.0, 0.2])
    positions = np.stack([xs, ys, np.zeros(8)], axis=1).astype(np.float32)
    faces = np.array([[0, 1, 2], [2, 1, 3], [2, 3, 4], [4, 3, 5], [4, 5, 6], [6, 5, 7]], np.uint16)
    w1 = np.clip((xs - 1.0) / 1.5, 0.0, 1.0)
    joints = np.zeros((8, 4), np.uint8)
    joints[:, 1] = 1
    weights = np.zeros((8, 4), np.uint8)  # normalized unsigned bytes
    weights[:, 1] = np.round(255 * w1).astype(np.uint8)
    weights[:, 0] = 255 - weights[:, 1]
    bind_world = [np.eye(4), np.eye(4)]
    bind_world[1][0, 3] = 2.0
    ibm = np.stack([np.linalg.inv(m) for m in bind_world]).astype(np.float32)
    ibm_column_major = ibm.transpose(0, 2, 1).copy()
    times = np.array([0.0, 1.0], np.float32)
    rotations = np.stack([_quat([0, 0, 1], 0.0), _quat([0, 0, 1], animated_degrees)]).astype(
        np.float32
    )
    blobs = [
        positions.tobytes(),
        faces.tobytes() + b"\0\0" * (faces.size % 2),
        joints.tobytes(),
        weights.tobytes(),
        ibm_column_major.tobytes(),
        times.tobytes(),
        rotations.tobytes(),
    ]
    views, offset = [], 0
    for blob in blobs:
        views.append({"buffer": 0, "byteOffset": offset, "byteLength": len(blob)})
        offset += len(blob)
    buffer = b"".join(blobs)
    accessors = [
        {"bufferView": 0, "componentType": 5126, "count": 8, "type": "VEC3"},
        {"bufferView": 1, "componentType": 5123, "count": faces.size, "type": "SCALAR"},
        {"bufferView": 2, "componentType": 5121, "count": 8, "type": "VEC4"},
        {"bufferView": 3, "componentType": 5121, "count": 8, "type": "VEC4", "normalized": True},
        {"bufferView": 4, "componentType": 5126, "count": 2, "type": "MAT4"},
        {"bufferView": 5, "componentType": 5126, "count": 2, "type": "SCALAR"},
        {"bufferView": 6, "componentType": 5126, "count": 2, "type": "VEC4"},
    ]
    data = {
        "asset": {"version": "2.0"},
        "scenes": [{"nodes": [0, 2]}],
        "nodes": [
            {"name": "j0", "children": [1]},
            {"name": "j1", "translation": [2.0, 0.0, 0.0]},
            {"name": "strip", "mesh": 0, "skin": 0},
        ],
        "meshes": [
            {
                "primitives": [
                    {
                        "attributes": {"POSITION": 0, "JOINTS_0": 2, "WEIGHTS_0": 3},
                        "indices": 1,
                    }
                ]
            }
        ],
        "skins": [{"joints": [0, 1], "inverseBindMatrices": 4}],
        "animations": [
            {
                "name": "bend",
                "channels": [{"sampler": 0, "target": {"node": 1, "path": "rotation"}}],
                "samplers": [{"input": 5, "output": 6, "interpolation": "LINEAR"}],
            }
        ],
        "accessors": accessors,
        "bufferViews": views,
        "buffers": [{"byteLength": len(buffer)}],
    }
    return data, buffer, {"positions": positions, "w1": weights[:, 1] / 255.0}


def _write_gltf(path: Path, data: dict, buffer: bytes) -> Path:
    data = json.loads(json.dumps(data))
    data["buffers"][0]["uri"] = (
        "data:application/octet-stream;base64," + base64.b64encode(buffer).decode()
    )
    path.write_text(json.dumps(data))
    return path


def _write_glb(path: Path, data: dict, buffer: bytes) -> Path:
    text = json.dumps(data).encode()
    text += b" " * (-len(text) % 4)
    binary = buffer + b"\0" * (-len(buffer) % 4)
    chunks = struct.pack("<II", len(text), 0x4E4F534A) + text
    chunks += struct.pack("<II", len(binary), 0x004E4942) + binary
    path.write_bytes(struct.pack("<III", 0x46546C67, 2, 12 + len(chunks)) + chunks)
    return path


@pytest.fixture()
def chain(tmp_path):
    data, buffer, expected = _chain_document()
    return _write_gltf(tmp_path / "chain.gltf", data, buffer), expected


def test_gltf_and_glb_read_the_same_arrays(chain, tmp_path):
    path, expected = chain
    data, buffer, _ = _chain_document()
    for source in (path, _write_glb(tmp_path / "chain.glb", data, buffer)):
        mesh = gltf.skinned_mesh(gltf.read_gltf(source))
        np.testing.assert_array_equal(mesh.vertices, expected["positions"])
        assert mesh.faces.shape == (6, 3) and mesh.faces.max() == 7
        np.testing.assert_allclose(mesh.weights[:, 1], expected["w1"], atol=1e-12)
        np.testing.assert_allclose(mesh.weights.sum(axis=1), 1.0)
        np.testing.assert_allclose(mesh.inverse_bind[1][:3, 3], [-2.0, 0.0, 0.0])


def test_rest_pose_reproduces_the_bind_pose(chain):
    doc = gltf.read_gltf(chain[0])
    tree, mesh = gltf.node_tree(doc), gltf.skinned_mesh(doc)
    matrices = gltf.skin_matrices(tree, mesh, tree.local_matrices())
    np.testing.assert_allclose(matrices, np.broadcast_to(np.eye(4), matrices.shape), atol=1e-6)
    posed = gltf.linear_blend_skinning(mesh.vertices, mesh.joints, mesh.weights, matrices)
    np.testing.assert_allclose(posed, mesh.vertices, atol=1e-6)


def test_a_joint_rotation_moves_only_its_weighted_vertices(chain):
    doc = gltf.read_gltf(chain[0])
    tree, mesh = gltf.node_tree(doc), gltf.skinned_mesh(doc)
    rotation = tree.rotation.copy()
    rotation[1] = _quat([0, 0, 1], 90.0)
    matrices = gltf.skin_matrices(tree, mesh, tree.local_matrices(rotation=rotation))
    posed = gltf.linear_blend_skinning(mesh.vertices, mesh.joints, mesh.weights, matrices)
    w1 = mesh.weights[:, 1]
    moved = np.linalg.norm(posed - mesh.vertices, axis=1) > 1e-9
    np.testing.assert_array_equal(moved, w1 > 0)
    # fully weighted vertices turn rigidly by 90° about joint 1 at (2, 0, 0)
    full = w1 == 1.0
    assert full.sum() == 3
    relative = mesh.vertices[full] - [2.0, 0.0, 0.0]
    pivot = np.array([2.0, 0.0, 0.0])
    expected = np.stack([-relative[:, 1], relative[:, 0], relative[:, 2]], axis=1) + pivot
    np.testing.assert_allclose(posed[full], expected, atol=1e-6)


def test_animation_sampling_interpolates_and_clamps(chain):
    doc = gltf.read_gltf(chain[0])
    tree, (clip,) = gltf.node_tree(doc), gltf.clips(doc)
    assert clip.name == "bend" and clip.duration == pytest.approx(1.0)
    for t, degrees in ((0.5, 45.0), (-1.0, 0.0), (2.0, 90.0)):
        _, rotation, _ = gltf.sample_pose(tree, clip, t)
        angle = np.degrees(Rotation.from_quat(rotation[1]).magnitude())
        assert angle == pytest.approx(degrees, abs=1e-4)


def test_broken_files_raise_shape_file_errors(tmp_path):
    (tmp_path / "bad.gltf").write_text("{not json")
    with pytest.raises(ShapeFileError):
        gltf.read_gltf(tmp_path / "bad.gltf")
    data, buffer, _ = _chain_document()
    del data["nodes"][2]["skin"]
    with pytest.raises(ShapeFileError, match="skinned"):
        gltf.skinned_mesh(gltf.read_gltf(_write_gltf(tmp_path / "x.gltf", data, buffer)))


@pytest.mark.skipif(not TRAIN_DATA.is_dir(), reason="train-data not available")
@pytest.mark.parametrize(
    ("relative", "tolerance"),
    [("khronos-fox/Fox.glb", 1e-6), ("quaternius-uaa/Horse.gltf", 3e-3)],
)
def test_real_rigs_rest_pose_matches_their_bind_pose(relative, tolerance):
    doc = gltf.read_gltf(TRAIN_DATA / relative)
    tree, mesh = gltf.node_tree(doc), gltf.skinned_mesh(doc)
    world = tree.global_matrices(tree.local_matrices())
    bind = gltf.linear_blend_skinning(
        mesh.vertices, mesh.joints, mesh.weights, world[mesh.joint_nodes] @ mesh.inverse_bind
    )
    size = np.ptp(mesh.vertices, axis=0).max()
    assert np.abs(bind - mesh.vertices).max() <= tolerance * size
    assert len(gltf.clips(doc)) >= 3
