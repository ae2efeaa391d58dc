"""Orientation training (litege_core.train.orientation): labels, items, a short run, files."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import trimesh

from litege_core.errors import InputError
from litege_core.nets.tnet import CUBE_ROTATIONS
from litege_core.train.orientation import (
    OrientationTrainConfig,
    candidate_angles,
    evaluate,
    load_orientation,
    nearest_turns,
    run_orientation_training,
    sample_items,
    train_orientation,
    without_lying,
)
from litege_core.train.tnet import canonical_shape_set
from litege_core.variants import small_rotation

REPO = Path(__file__).resolve().parents[3]


def _toy_mesh(seed: int) -> tuple[np.ndarray, np.ndarray]:
    """An animal-like blob with a distinct head end and up side (no cube symmetry)."""
    sphere = trimesh.creation.icosphere(subdivisions=2)
    v = np.asarray(sphere.vertices) * [0.5, 0.8, 2.0]
    rng = np.random.default_rng(seed)
    v[:, 1] += 0.5 * np.clip(v[:, 2], 0, None) ** 2 * rng.uniform(0.8, 1.2)  # a raised head
    v[:, 0] *= 1.0 + 0.3 * (v[:, 2] > 0)  # a wider front
    return v * rng.uniform(0.5, 2.0), np.asarray(sphere.faces)


@pytest.fixture(scope="module")
def toy_shapes():
    return (
        canonical_shape_set([_toy_mesh(s) for s in range(6)]),
        canonical_shape_set([_toy_mesh(100 + s) for s in range(2)]),
    )


TINY = {
    "augment": {"min_points": 200, "max_points": 300, "broken_probability": 0.0},
    "network": {"grid": 8, "conv_widths": [8, 16], "fc_width": 32},
    "train": {"batch_size": 24, "steps": 150, "val_items": 96, "val_every": 50, "lr": 3e-3},
}


def tiny_config(tmp_path: Path, **tables: dict) -> OrientationTrainConfig:
    config = OrientationTrainConfig.from_dict({**TINY, "output": {"dir": str(tmp_path)}})
    return config.replace(**tables) if tables else config


def test_labels_are_the_turn_back_to_the_true_frame() -> None:
    rng = np.random.default_rng(0)
    cube = CUBE_ROTATIONS.numpy()
    turns = rng.integers(0, 24, 50)
    bases = np.stack([small_rotation(0.6, rng) @ cube[t].T for t in turns])
    assert np.array_equal(nearest_turns(bases), turns)
    assert np.all(candidate_angles(bases, turns) <= 0.6 + 1e-9)
    assert np.all(candidate_angles(bases, (turns + 1) % 24) > 0.9)


def test_items_are_clouds_in_their_base_frames(toy_shapes, tmp_path) -> None:
    config = tiny_config(tmp_path, train={"pca_probability": 0.0})
    clouds, bases = sample_items(toy_shapes[0], 8, config, np.random.default_rng(1))
    assert clouds.shape[0] == 8 and 200 <= clouds.shape[1] <= 300
    # back in the true frame (base⁻¹) the clouds are long along z, as the canonical shapes
    canonical = np.einsum("bnj,bij->bni", clouds.double().numpy(), bases)
    spread = canonical.std(axis=1).mean(axis=0)
    assert spread[2] > 1.5 * spread[1] and spread[2] > 1.5 * spread[0]
    again = sample_items(toy_shapes[0], 8, config, np.random.default_rng(1))
    assert np.array_equal(again[1], bases)


def test_a_short_run_learns_the_turns_and_writes_its_weights(toy_shapes, tmp_path) -> None:
    config = tiny_config(tmp_path)
    untrained = train_orientation(
        config.replace(train={"steps": 1}), train_shapes=toy_shapes[0], val_shapes=toy_shapes[1]
    )
    weights = tmp_path / "w.safetensors"
    result = train_orientation(
        config, train_shapes=toy_shapes[0], val_shapes=toy_shapes[1], weights_path=weights
    )
    assert result.best["accuracy"] > 0.5 > untrained.best["accuracy"] + 0.2
    assert result.best["failures"] < untrained.best["failures"]
    loaded = load_orientation(weights)
    clouds, bases = sample_items(toy_shapes[1], 32, config, np.random.default_rng(5))
    assert evaluate(loaded, clouds, bases) == evaluate(result.net, clouds, bases)


def test_config_checks_and_the_shipped_config() -> None:
    with pytest.raises(InputError):
        OrientationTrainConfig.from_dict({"train": {"jitter": 1.0}})
    with pytest.raises(InputError):
        OrientationTrainConfig.from_dict({"train": {"pca_probability": 2.0}})
    config = OrientationTrainConfig.load(REPO / "configs" / "orientation-quadrupeds.toml")
    assert config.data.extra_category == "rigged" and config.data.extra_bend == 0.7


def test_run_writes_weights_and_log(toy_shapes, tmp_path, monkeypatch) -> None:
    import litege_core.train.orientation as module

    monkeypatch.setattr(module, "training_shape_sets", lambda data: toy_shapes)
    summary = run_orientation_training(tiny_config(tmp_path, train={"steps": 4, "val_every": 2}))
    assert Path(summary["weights"]).is_file() and summary["steps"] == 4
    assert "val step 4" in (tmp_path / "train.log").read_text()


def test_cli_refuses_a_bad_config(tmp_path) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text("[train]\njitter = 2.0\n")
    run = subprocess.run(
        [sys.executable, "-m", "litege_core.cli", "train", "orientation", "--config", str(bad)],
        capture_output=True,
        text=True,
        cwd=REPO,
    )
    assert run.returncode != 0 and "jitter" in run.stderr
    assert "Traceback" not in run.stderr


def test_lying_procedural_shapes_are_left_out() -> None:
    from litege_core.synth import families, generate_shape
    from litege_core.train.tnet import ShapeSet

    names = families("quadruped")
    keys = [(names[k % len(names)], 2_000_100 + k) for k in range(6)] + [("Wolf", 3)]
    poses = [generate_shape("quadruped", f, s).pose for f, s in keys[:6]]
    assert "lying" in poses and poses.count("lying") < 6
    dummy = [np.zeros((3, 3))] * len(keys)
    kept = without_lying(ShapeSet(dummy, dummy, keys), "quadruped")
    expected = [key for key, pose in zip(keys, [*poses, "rigged"], strict=True) if pose != "lying"]
    assert kept.keys == expected
    # a lying seed posed steep stays in
    from litege_core.synth.poses import steep_pose

    share = 0.5
    steep = [steep_pose("quadruped", seed, share) for _, seed in keys[:6]]
    poses = [mode or pose for mode, pose in zip(steep, poses, strict=True)]
    kept = without_lying(ShapeSet(dummy, dummy, keys), "quadruped", share)
    expected = [key for key, pose in zip(keys, [*poses, "rigged"], strict=True) if pose != "lying"]
    assert kept.keys == expected


def test_foreign_files_are_artifact_errors(tmp_path) -> None:
    from safetensors.torch import save_file

    from litege_core.errors import ArtifactError
    from litege_core.nets import TNet, state_to_tensors

    garbage = tmp_path / "garbage.safetensors"
    garbage.write_bytes(b"not a safetensors file")
    tnet = tmp_path / "tnet.safetensors"
    save_file(state_to_tensors(TNet(conv_widths=(4,), fc_widths=(4,))), str(tnet))
    for path in (garbage, tnet, tmp_path / "missing.safetensors"):
        with pytest.raises(ArtifactError):
            load_orientation(path)
