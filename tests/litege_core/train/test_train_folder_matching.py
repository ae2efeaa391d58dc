"""``litege train matching --meshes DIR``: a folder of procedural quadrupeds sharing one
topology → a loadable matching bundle that ``litege match`` serves."""

import json

import numpy as np
import pytest
import torch

from litege_core.cli import main
from litege_core.datasets import GeodesicDataset
from litege_core.errors import InputError
from litege_core.io import save_shape
from litege_core.matching.bundle import load_matching_bundle, resolve_matching_bundle
from litege_core.shape import Shape
from litege_core.synth import families, generate_shape
from litege_core.train.matching_from_meshes import (
    FolderTemplateFactory,
    folder_matching_config,
    planned_steps,
)

TINY = """
[data]
views_per_shape = 2
val_view_pairs = 3
reject_angle = 3.2
[augment]
min_points = 200
max_points = 400
[basis]
n_components = 5
std_threshold = 0.05
grid_resolution = 25
grid_pitch = 0.07
fit_samples = 300
[network]
width = 16
[train]
view_pairs = 4
rows_per_pair = 3
targets_per_pair = 8
first_passes = 2
first_pass_steps = 3
steps = 4
validate_every = 2
[output]
weights_dtype = "float32"
"""


@pytest.fixture(scope="module")
def quadruped_folder(tmp_path_factory):
    """Six procedural quadrupeds (one template topology) as OBJ and PLY files."""
    folder = tmp_path_factory.mktemp("quadrupeds")
    names = families("quadruped")
    for i in range(6):
        shape = generate_shape("quadruped", names[i % len(names)], i)
        save_shape(
            Shape.from_arrays(shape.vertices, shape.faces),
            folder / f"q{i}.{('obj', 'ply')[i % 2]}",
        )
    return folder


def test_factory_keeps_the_topology_and_stretches(quadruped_folder):
    from litege_core.synth.folder import list_meshes

    files = list_meshes(quadruped_folder)
    factory = FolderTemplateFactory(str(quadruped_folder), files, "x")
    template, faces = factory.template()
    clean = factory.generate(files[1], 1_000_000)
    stretched = factory.generate(files[1], 3)
    assert template.shape == clean.shape == stretched.shape and faces.shape[1] == 3
    assert not np.allclose(clean, stretched)
    np.testing.assert_allclose(factory.generate(files[1], 3), stretched)  # deterministic
    assert planned_steps(None)[1] > planned_steps(60.0)[1] > 0


def test_folder_to_served_matching_bundle(quadruped_folder, tmp_path, capsys):
    config = tmp_path / "tiny.toml"
    config.write_text(TINY)
    out = tmp_path / "bundle"
    argv = ["train", "matching", "--meshes", str(quadruped_folder), "--out", str(out)]
    argv += ["--init", "quadrupeds", "--config", str(config), "--time-budget", "20"]
    argv += ["--shapes-per-mesh", "2", "--eval-shapes-per-mesh", "2", "--tnet-steps", "4"]
    assert main(argv) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["bundle"] == str(out) and summary["kind"] == "matching"
    assert {k: len(v) for k, v in summary["data"]["files"].items()} == {
        "train": 4,
        "val": 1,
        "test": 1,
    }
    dataset = GeodesicDataset(summary["data"]["dir"])
    assert dataset.shared_sources is not None
    assert dataset.manifest["counts"] == {"train": 8, "val": 2, "test": 2}
    bundle = load_matching_bundle(out)
    assert bundle.name == quadruped_folder.name
    card = (out / "MODEL_CARD.md").read_text()
    assert card.startswith(f"# {quadruped_folder.name}") and "fine-tuned on the" in card
    tuned = summary["data"]["tnet"]
    assert tuned["steps"] == 4 and 0.0 <= tuned["agreement_after"] <= 1.0
    shipped = load_matching_bundle(resolve_matching_bundle("quadrupeds")).tnet
    differs = [
        not torch.equal(a, b)
        for a, b in zip(
            bundle.tnet.state_dict().values(), shipped.state_dict().values(), strict=True
        )
    ]
    assert any(differs)  # the bundle serves the tuned T-Net

    x, y = sorted(quadruped_folder.iterdir())[:2]
    matches = tmp_path / "matches.npy"
    argv = ["match", str(x), str(y), "--bundle", str(out), "--queries", "0,1,2", "-o"]
    assert main([*argv, str(matches)]) == 0
    assert np.load(matches).shape[0] == 3


def test_generated_config_keeps_the_command_paths(tmp_path):
    config = folder_matching_config(
        tmp_path / "data",
        tmp_path / "run",
        tmp_path / "tnet.safetensors",
        name="n",
        train_seconds=120.0,
        overrides={"data": {"dataset": "elsewhere"}, "network": {"width": 32}},
    )
    assert config.data.dataset == str(tmp_path / "data")
    assert config.data.tnet == str(tmp_path / "tnet.safetensors")
    assert config.output.dir == str(tmp_path / "run") and config.network.width == 32


def _bend(vertices: np.ndarray) -> float:
    """Height over length of the capsule (straight: about 0.2)."""
    extent = np.ptp(vertices, axis=0)
    return float(extent[1] / extent[0])


def test_a_rig_folder_gives_posed_shapes_on_its_topology(tmp_path, rigged_gltf):
    from litege_core.synth.folder import list_meshes

    rigged_gltf(tmp_path / "capsule.gltf")
    files = list_meshes(tmp_path)
    factory = FolderTemplateFactory(str(tmp_path), files, "x", stretch_amplitude=0.0, poses=True)
    template, faces = factory.template()
    assert _bend(template) < 0.3 and faces.shape[1] == 3  # the rest pose
    shapes = [factory.generate("capsule.gltf", seed) for seed in range(6)]
    assert all(shape.shape == template.shape for shape in shapes)
    assert max(map(_bend, shapes)) > 2.0 * min(map(_bend, shapes))  # poses of its one clip
    np.testing.assert_allclose(factory.generate("capsule.gltf", 3), shapes[3])
    np.testing.assert_allclose(factory.generate("capsule.gltf", 1_000_000), template)
    assert factory.version != FolderTemplateFactory(str(tmp_path), files, "x").version


def test_poses_need_rigs_of_one_topology(tmp_path, rigged_gltf):
    from litege_core.train.from_meshes import rig_topology

    rigged_gltf(tmp_path / "a.gltf")
    rigged_gltf(tmp_path / "b.gltf")
    files, n_vertices, faces = rig_topology(tmp_path)
    assert files == ("a.gltf", "b.gltf") and faces.shape[1] == 3 and n_vertices > 100
    rigged_gltf(tmp_path / "still.gltf", animated=False)
    save_shape(Shape.from_arrays(*_box()), tmp_path / "box.obj")
    with pytest.raises(InputError, match=r"2 of 4 are not: box\.obj, still\.gltf"):
        rig_topology(tmp_path)


def _box() -> tuple[np.ndarray, np.ndarray]:
    import trimesh

    box = trimesh.creation.box()
    return np.asarray(box.vertices), np.asarray(box.faces)


def test_poses_of_one_rig_to_a_served_matching_bundle(tmp_path, capsys, rigged_gltf):
    folder = tmp_path / "rig"
    folder.mkdir()
    rigged_gltf(folder / "capsule.gltf")
    config = tmp_path / "tiny.toml"
    config.write_text(TINY)
    out = tmp_path / "bundle"
    argv = ["train", "matching", "--meshes", str(folder), "--out", str(out), "--poses"]
    argv += ["--init", "quadrupeds", "--config", str(config), "--time-budget", "20"]
    argv += ["--shapes-per-mesh", "6", "--eval-shapes-per-mesh", "2", "--tnet-steps", "4"]
    assert main(argv) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["data"]["poses"] and summary["data"]["files"] == {
        split: ["capsule.gltf"] for split in ("train", "val", "test")
    }
    dataset = GeodesicDataset(summary["data"]["dir"])
    assert dataset.manifest["counts"] == {"train": 6, "val": 2, "test": 2}
    train = dataset.load_split("train")["vertices"]
    bends = [_bend(vertices) for vertices in train]
    assert max(bends) > 2.0 * min(bends)  # the training shapes are poses
    card = (out / "MODEL_CARD.md").read_text()
    assert "poses drawn from each rig" in card and "every file in every split" in card
    matches = tmp_path / "matches.npy"
    rig = str(folder / "capsule.gltf")
    argv = ["match", rig, rig, "--bundle", str(out), "--queries", "0,1,2", "-o", str(matches)]
    assert main(argv) == 0
    assert np.load(matches).shape == (3,)


def test_files_stored_in_other_orientations_are_turned_onto_the_first(quadruped_folder, tmp_path):
    from litege_core.io import load_shape
    from litege_core.synth.folder import list_meshes
    from litege_core.variants import random_rotation

    files = list_meshes(quadruped_folder)
    for k, name in enumerate(files):  # the same shapes, each stored turned its own way
        shape = load_shape(quadruped_folder / name)
        turned = shape.vertices @ random_rotation(k).T
        save_shape(Shape.from_arrays(turned, shape.faces), tmp_path / name)
    upright = FolderTemplateFactory(str(quadruped_folder), files, "x")
    turned = FolderTemplateFactory(str(tmp_path), files, "x")
    first = random_rotation(0)  # the turned folder's frame: its first file's
    for name in files:
        expected = upright.load(name)[0] @ first.T
        np.testing.assert_allclose(turned.load(name)[0], expected, atol=0.02)
    np.testing.assert_allclose(turned.template()[0], upright.template()[0] @ first.T, atol=0.02)
