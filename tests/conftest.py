"""Shared fixtures: small deterministic shapes, and the optional real evaluation data."""

import base64
import json
import os
from pathlib import Path

import numpy as np
import pytest
import trimesh
from hypothesis import settings
from scipy.spatial.transform import Rotation

EVAL_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "eval-data"


@pytest.fixture(scope="session")
def sphere_mesh() -> tuple[np.ndarray, np.ndarray]:
    """A 642-vertex unit icosphere ``(vertices, faces)``."""
    mesh = trimesh.creation.icosphere(subdivisions=3)
    return np.asarray(mesh.vertices), np.asarray(mesh.faces)


@pytest.fixture(scope="session")
def eval_data() -> Path:
    """Path of ../shared/eval-data; tests using it skip when it is absent."""
    if not EVAL_DATA.is_dir():
        pytest.skip("../shared/eval-data not available")
    return EVAL_DATA


# CI runs must be reproducible: hypothesis draws the same examples every time there.
settings.register_profile("ci", derandomize=True, print_blob=True)
if os.environ.get("CI"):
    settings.load_profile("ci")


def make_blob(seed: int, subdivisions: int = 3):
    """An asymmetric bent ellipsoid (well-defined PCA frame) as a mesh ``Shape``."""
    from litege_core.shape import Shape

    rng = np.random.default_rng(seed)
    sphere = trimesh.creation.icosphere(subdivisions=subdivisions)
    vertices = np.asarray(sphere.vertices) * [1.6 + rng.uniform(-0.3, 0.3), 1.0, 0.6]
    vertices[:, 1] += 0.3 * vertices[:, 0] ** 2 * rng.uniform(0.5, 1.5)
    return Shape.from_arrays(vertices, sphere.faces)


@pytest.fixture(scope="session")
def blob():
    """Factory fixture: ``blob(seed, subdivisions=3)`` → a deformed-ellipsoid mesh Shape."""
    return make_blob


@pytest.fixture(scope="session")
def toy_predictor(tmp_path_factory):
    """A Predictor over a tiny bundle (4-component basis, untrained 32-wide net)."""
    import torch

    from litege_core.canonical import canonicalize_bbox
    from litege_core.descriptor import VoxelGrid, fit_basis
    from litege_core.learned import Predictor, load_bundle, save_bundle, shape_samples
    from litege_core.nets import GeodesicNet

    canonical = []
    for seed in range(6):
        shape = make_blob(seed, subdivisions=2)
        transform = canonicalize_bbox(shape_samples(shape, 500, seed))
        canonical.append((transform.apply(shape.vertices), np.asarray(shape.faces)))
    basis = fit_basis(
        canonical,
        grid=VoxelGrid(resolution=21, pitch=0.1),
        std_threshold=0.05,
        n_components=4,
        n_udf_samples=300,
        seed=0,
    )
    torch.manual_seed(0)
    directory = tmp_path_factory.mktemp("toy-bundle")
    save_bundle(
        directory,
        name="toy",
        category="toy",
        basis=basis,
        network=GeodesicNet(width=32, descriptor_dim=4).eval(),
    )
    return Predictor(load_bundle(directory))


@pytest.fixture(scope="session")
def toy_bundle_dir_with_ood(tmp_path_factory, toy_predictor):
    """The toy bundle saved again with residual statistics (an OOD z-score: what graph fusion
    needs); returns its directory."""
    from litege_core.learned import save_bundle

    source = toy_predictor.bundle
    directory = tmp_path_factory.mktemp("toy-ood") / "toy"
    save_bundle(
        directory,
        name="toy",
        category="toy",
        basis=source.basis,
        network=source.network,
        training={"residual_mean": 0.5, "residual_std": 0.25},
    )
    return directory


@pytest.fixture
def toy_fusion(toy_bundle_dir_with_ood, blob):
    """The toy bundle with a fusion calibration of its own (no veto bias, gate 0) and the toy
    blob as an evaluation shape (any positive rows: Euclidean distances from two sources):
    ``(bundle, predictor, shape)`` for the fusion diagnoses."""
    from litege_core.evaluation.geodesic import EvalShape
    from litege_core.learned import Predictor, load_bundle
    from litege_core.learned.fusion_calibration import FusionCalibration

    bundle = load_bundle(toy_bundle_dir_with_ood)
    calibration = FusionCalibration(
        k=8,
        prune_ratio=1.6,
        bias_log10_points=(2.0, 3.0),
        bias=(1.0, 1.0),
        gate=(0.0, 0.0, 0.0, 0.0),
        mesh_bias=1.0,
        bundle_hash=bundle.content_hash,
    )
    mesh = blob(2)
    vertices, faces = np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces)
    sources = np.array([0, 5])
    gt = np.linalg.norm(vertices[sources][:, None] - vertices[None], axis=-1)
    shape = EvalShape("blob", "test", vertices, faces, sources, gt)
    return bundle, Predictor(bundle, fusion=calibration), shape


@pytest.fixture
def shipped_toy_scorer(tmp_path, monkeypatch) -> str:
    """A scorer stood in for the shipped one that calls the chords longer than 1.2 × the
    cloud's spacing shortcuts (logit = chord / spacing − 1.2); returns its weights' sha256."""
    from litege_core.learned import shortcuts
    from litege_core.learned.shortcuts import save_shortcut_scorer

    width = 8
    state = {
        "point.0.weight": np.zeros((width, 3)), "point.0.bias": np.zeros(width),
        "point.2.weight": np.zeros((2 * width, width)), "point.2.bias": np.zeros(2 * width),
        "ends.weight": np.zeros((2 * width, 2 * width)),
        "edge.weight": np.zeros((2 * width, 6)), "edge.bias": np.zeros(2 * width),
        "head.1.weight": np.full((width, 2 * width), 1.0 / (2 * width)),
        "head.1.bias": np.zeros(width),
        "head.3.weight": np.full((1, width), 1.0 / width), "head.3.bias": np.full(1, -1.2),
    }  # fmt: skip
    state["edge.weight"][:, 0] = 1.0  # every hidden unit: the chord over the spacing
    config = save_shortcut_scorer(tmp_path / "scorer", state, neighbours=8)
    monkeypatch.setattr(shortcuts, "SHIPPED_SCORER_DIR", tmp_path / "scorer")
    return str(config["weights_sha256"])


def write_rigged_capsule(path: Path, animated: bool = True) -> Path:
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


@pytest.fixture(scope="session")
def rigged_gltf():
    """``rigged_gltf(path, animated=True)``: writes :func:`write_rigged_capsule` there."""
    return write_rigged_capsule
