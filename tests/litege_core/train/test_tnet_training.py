"""T-Net training: config, batches, loop, determinism, weights file, report, CLI."""

import argparse
import json
import math
from pathlib import Path

import numpy as np
import pytest
import torch
import trimesh
from scipy.spatial.transform import Rotation

import litege_core.train.tnet as tnet_module
import litege_core.train.tnet.evaluation as tnet_evaluation
import litege_core.train.tnet.training as tnet_training
from litege_core.cli.train import add_train_parser
from litege_core.errors import ArtifactError, InputError
from litege_core.nets import TNet, state_to_tensors
from litege_core.nets.tnet import CUBE_ROTATIONS
from litege_core.sampling import sample_surface
from litege_core.train.tnet import (
    PREDICT_MAX_POINTS,
    BatchLoader,
    TNetTrainConfig,
    alignment_report,
    angle_statistics,
    canonical_shape_set,
    cosine_lr,
    generate_shape_set,
    load_tnet,
    load_tnet_config,
    predict_rotation,
    read_tnet_metadata,
    run_tnet_training,
    sample_batch,
    save_tnet,
    train_step,
    train_tnet,
    validation_set,
)
from litege_core.train.tnet.shapes import collection_shape_set, training_shape_sets
from litege_core.validate import triangle_areas

REPO = Path(__file__).resolve().parents[3]


def _toy_mesh(seed: int) -> tuple[np.ndarray, np.ndarray]:
    """An asymmetric blob: a stretched, bent icosphere (no rotational symmetry)."""
    sphere = trimesh.creation.icosphere(subdivisions=1)
    v = np.asarray(sphere.vertices) * [2.0, 1.0, 0.5]
    rng = np.random.default_rng(seed)
    v[:, 1] += 0.3 * v[:, 0] ** 2 + 0.2 * np.clip(v[:, 0], 0, None) * rng.uniform(0.8, 1.2)
    return v * rng.uniform(0.5, 2.0), np.asarray(sphere.faces)


@pytest.fixture(scope="module")
def toy_shapes():
    train = canonical_shape_set([_toy_mesh(s) for s in range(4)])
    val = canonical_shape_set([_toy_mesh(100 + s) for s in range(2)])
    return train, val


TINY = {
    "data": {"n_train": 4, "n_val": 2},
    "augment": {"min_points": 32, "max_points": 64},
    "network": {"conv_widths": [8, 16], "fc_widths": [8]},
    "train": {"batch_size": 4, "steps": 6, "val_every": 3, "val_points": 48, "log_every": 2},
    "report": {"samples": 64},
}


def tiny_config(tmp_path: Path, **overrides) -> TNetTrainConfig:
    config = TNetTrainConfig.from_dict({**TINY, "output": {"dir": str(tmp_path / "run")}})
    return config.replace(**overrides) if overrides else config


# --------------------------------------------------------------------------- config


def test_shipped_config_loads_and_round_trips() -> None:
    config = load_tnet_config(REPO / "configs" / "tnet-quadrupeds.toml")
    assert config.data.category == "quadruped"
    assert config.network.conv_widths == (64, 128, 256) and config.network.prealign == "pca"
    assert config.train.lr == 1e-3 and config.train.eta_min == 1e-5
    assert config.report.rotation_seed == 20 and config.report.failure_threshold == 0.66
    again = TNetTrainConfig.from_dict(config.to_dict())
    assert again == config and again.content_hash() == config.content_hash()
    assert config.replace(train={"steps": 5}).train.steps == 5


@pytest.mark.parametrize(
    "data",
    [
        {"nope": {}},
        {"train": {"stepz": 3}},
        {"train": {"steps": "10"}},
        {"train": {"steps": 0}},
        {"train": {"batch_size": 1}},
        {"train": {"lr": 1e-5, "eta_min": 1e-3}},
        {"train": {"val_every": True}},
        {"augment": {"min_points": 600, "max_points": 500}},
        {"augment": {"broken_probability": 1.5}},
        {"augment": {"scale_min": 0.0}},
        {"augment": {"axis_scale": 1.0}},
        {"network": {"conv_widths": [64, "128"]}},
        {"network": {"conv_widths": []}},
        {"network": {"fc_widths": [0]}},
        {"network": {"conv_widths": 64}},
        {"network": {"prealign": "svd"}},
        {"data": {"n_train": 0}},
        {"data": {"n_extra_train": 4}},
        {"data": {"extra_category": "folder", "n_extra_train": 4}},
        {"data": {"extra_category": "makehuman", "n_extra_val": -1}},
        {"data": {"extra_category": "makehuman", "n_extra_train": 4, "extra_bend": 0.5}},
        {"data": {"extra_category": "rigged", "n_extra_train": 4, "extra_bend": 1.5}},
        {"data": {"steep_share": -0.1}},
        {"data": {"steep_share": 1.5}},
        {"data": {"category": "biped", "steep_share": 0.3}},
        {"report": {"broken_fraction": 1.0}},
        {"output": {"dir": ""}},
        {"data": []},
    ],
)
def test_config_validation_errors(data: dict) -> None:
    with pytest.raises(InputError):
        TNetTrainConfig.from_dict(data)


def test_config_file_errors(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="does not exist"):
        load_tnet_config(tmp_path / "missing.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("[train\nsteps = 3\n")
    with pytest.raises(InputError, match="not valid TOML"):
        load_tnet_config(bad)
    with pytest.raises(InputError):
        TNetTrainConfig().replace(nope={"x": 1})


def test_cosine_schedule_endpoints() -> None:
    opt = TNetTrainConfig().train
    assert cosine_lr(0, opt) == pytest.approx(opt.lr)
    assert cosine_lr(opt.steps, opt) == pytest.approx(opt.eta_min)
    assert cosine_lr(opt.steps // 2, opt) == pytest.approx((opt.lr + opt.eta_min) / 2)


# --------------------------------------------------------------------------- shapes / batches


def test_canonical_shapes_are_centred_unit_area(toy_shapes) -> None:
    train, _ = toy_shapes
    for v, f in zip(train.vertices, train.faces, strict=True):
        assert triangle_areas(v, f).sum() == pytest.approx(1.0)
        assert np.abs(v.mean(axis=0)).max() < 0.2  # centred on surface samples, not vertices


def test_generated_shapes_follow_the_dataset_convention_and_cache(tmp_path) -> None:
    first = generate_shape_set("quadruped", "val", 1, cache_dir=tmp_path)
    shapes = generate_shape_set("quadruped", "val", 2, cache_dir=tmp_path)  # extends the cache
    assert shapes.keys == [("cat", 1_000_000), ("dog", 1_000_001)]
    assert triangle_areas(shapes.vertices[1], shapes.faces[1]).sum() == pytest.approx(1.0)
    np.testing.assert_array_equal(shapes.vertices[0], first.vertices[0])
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        f"tnet-shapes-quadruped-val-{n}-synth-template-v1.npz" for n in (1, 2)
    ]
    again = generate_shape_set("quadruped", "val", 2, cache_dir=tmp_path)  # read back
    sliced = generate_shape_set("quadruped", "val", 1, cache_dir=tmp_path)
    for cached in (again, sliced):
        assert cached.keys == shapes.keys[: len(cached)]
        for a, b in zip(cached.vertices, shapes.vertices, strict=False):
            np.testing.assert_array_equal(a, b)
        np.testing.assert_array_equal(cached.faces[0], shapes.faces[0])


def test_steep_shapes_are_posed_and_cached_apart(tmp_path) -> None:
    from litege_core.synth import generate_shape
    from litege_core.synth.poses import steep_pose

    seed = next(s for s in range(1_000_000, 1_000_100) if steep_pose("quadruped", s, 0.5))
    n_shapes = seed - 1_000_000 + 1
    drawn = generate_shape_set("quadruped", "val", n_shapes, cache_dir=tmp_path)
    steep = generate_shape_set("quadruped", "val", n_shapes, cache_dir=tmp_path, steep_share=0.5)
    family = steep.keys[-1][0]
    posed = generate_shape("quadruped", family, seed, steep_pose("quadruped", seed, 0.5))
    centred = steep.vertices[-1] - steep.vertices[-1].mean(axis=0)
    expected = posed.vertices - posed.vertices.mean(axis=0)
    scale = np.linalg.norm(centred) / np.linalg.norm(expected)
    np.testing.assert_allclose(centred, expected * scale, atol=1e-9)  # same shape, same frame
    assert not np.allclose(steep.vertices[-1], drawn.vertices[-1])
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        f"tnet-shapes-quadruped-val-{n_shapes}-synth-template-v1+steep0.5r3.npz",
        f"tnet-shapes-quadruped-val-{n_shapes}-synth-template-v1.npz",
    ]


class _ToyCollection:
    """A stand-in collection factory: toy meshes of a size that depends on the seed."""

    category = "makehuman"

    def __init__(self, root: str, steep_share: float = 0.0) -> None:
        self.root = root
        self.version = "toy-1" + (f"+steep{steep_share:g}" if steep_share else "")

    def generate_mesh(self, family: str, seed: int) -> tuple[np.ndarray, np.ndarray]:
        assert family == "makehuman"
        sphere = trimesh.creation.icosphere(subdivisions=1 + seed % 2)
        return np.asarray(sphere.vertices) * [2.0, 1.0, 0.5] + seed, np.asarray(sphere.faces)


@pytest.fixture
def toy_collection(monkeypatch):
    import litege_core.datasets.factories as factories

    monkeypatch.setattr(
        factories,
        "factory_for",
        lambda source, root=None, pose=None, steep_share=0.0: _ToyCollection(root, steep_share),
    )


def test_collection_shapes_are_canonical_and_cached_ragged(toy_collection, tmp_path) -> None:
    first = collection_shape_set("makehuman", "train", 1, "assets", tmp_path)
    shapes = collection_shape_set("makehuman", "train", 3, "assets", tmp_path)  # extends the cache
    assert shapes.keys == [("makehuman", 0), ("makehuman", 1), ("makehuman", 2)]
    assert [len(v) for v in shapes.vertices] == [42, 162, 42]  # ragged: sizes differ per shape
    for v, f in zip(shapes.vertices, shapes.faces, strict=True):
        assert triangle_areas(v, f).sum() == pytest.approx(1.0)
        assert np.abs(v.mean(axis=0)).max() < 0.2  # the seed's offset is gone
    np.testing.assert_array_equal(first.vertices[0], shapes.vertices[0])
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        f"tnet-shapes-makehuman-train-{n}-toy-1.npz" for n in (1, 3)
    ]
    steep = collection_shape_set("makehuman", "train", 2, "assets", tmp_path, steep_share=0.4)
    assert (tmp_path / "tnet-shapes-makehuman-train-2-toy-1+steep0.4.npz").is_file()  # its own
    assert len(steep.vertices) == 2
    (tmp_path / "tnet-shapes-makehuman-train-2-toy-1+steep0.4.npz").unlink()
    again = collection_shape_set("makehuman", "train", 2, "assets", tmp_path)  # sliced from 3
    assert again.keys == shapes.keys[:2]
    for a, b, fa, fb in zip(
        again.vertices, shapes.vertices, again.faces, shapes.faces, strict=False
    ):
        np.testing.assert_array_equal(a, b)
        np.testing.assert_array_equal(fa, fb)
    assert len(list(tmp_path.iterdir())) == 2  # nothing generated, nothing written


def test_training_sets_append_the_extra_collection(toy_collection, tmp_path) -> None:
    config = TNetTrainConfig.from_dict(
        {
            "data": {
                "category": "quadruped",
                "n_train": 2,
                "n_val": 1,
                "extra_category": "makehuman",
                "n_extra_train": 2,
                "n_extra_val": 1,
                "cache_dir": str(tmp_path),
            }
        }
    )
    train, val = training_shape_sets(config.data)
    assert train.keys == [("cat", 0), ("dog", 1), ("makehuman", 0), ("makehuman", 1)]
    assert val.keys == [("cat", 1_000_000), ("makehuman", 1_000_000)]
    assert len(train.faces[0]) != len(train.faces[2])  # procedural and collection meshes mixed
    batch = sample_batch(train, config, step=0, batch_size=8)  # ragged sets sample as before
    assert batch.canonical.shape[0] == 8


def test_batches_are_rotated_canonical_clouds_and_seeded(toy_shapes, tmp_path) -> None:
    train, _ = toy_shapes
    config = tiny_config(tmp_path)
    batch = sample_batch(train, config, step=3)
    B, N, _ = batch.canonical.shape
    assert B == 4 and 32 <= N <= 64 and batch.R_gt.shape == (4, 3, 3)
    torch.testing.assert_close(batch.rotated, batch.canonical @ batch.R_gt.transpose(1, 2))
    torch.testing.assert_close(
        batch.R_gt.transpose(1, 2) @ batch.R_gt, torch.eye(3).expand(4, 3, 3), atol=1e-5, rtol=0
    )
    assert batch.canonical.mean(dim=1).abs().max() < 1e-5  # each cloud centred
    assert batch.frame_turns is None
    again = sample_batch(train, config, step=3)
    assert all(torch.equal(a, b) for a, b in zip(batch[:3], again[:3], strict=True))
    other = sample_batch(train, config, step=4)
    assert not torch.equal(batch.R_gt, other.R_gt)
    stretched = sample_batch(train, config.replace(augment={"axis_scale": 0.5}), step=3)
    assert torch.equal(stretched.R_gt, batch.R_gt)  # same draws before the stretch
    assert not torch.equal(stretched.canonical, batch.canonical)
    torch.testing.assert_close(
        stretched.rotated, stretched.canonical @ stretched.R_gt.transpose(1, 2)
    )


def test_validation_set_is_fixed(toy_shapes, tmp_path) -> None:
    _, val = toy_shapes
    config = tiny_config(tmp_path)
    first, second = validation_set(val, config), validation_set(val, config)
    assert set(first.batches) == {"mesh", "cloud500", "broken"} and first.n_items == 6
    assert first.batches["cloud500"].canonical.shape[1] == 500
    for mode, batch in first.batches.items():
        assert all(
            torch.equal(a, b) for a, b in zip(batch[:3], second.batches[mode][:3], strict=True)
        )


# --------------------------------------------------------------------------- training


def test_loss_decreases_on_a_fixed_batch(toy_shapes, tmp_path) -> None:
    train, _ = toy_shapes
    config = tiny_config(tmp_path, train={"batch_size": 8})
    torch.manual_seed(0)
    net = TNet((16, 32), (16,)).train()
    optimizer = torch.optim.Adam(net.parameters(), lr=1e-2)
    batch = sample_batch(train, config, step=0)
    losses = [train_step(net, optimizer, batch, 2.0)["loss"] for _ in range(60)]
    assert all(math.isfinite(x) for x in losses)
    assert np.mean(losses[-5:]) < 0.5 * losses[0]


def test_training_is_deterministic(toy_shapes, tmp_path) -> None:
    train, val = toy_shapes
    config = tiny_config(tmp_path)
    first = train_tnet(config, train_shapes=train, val_shapes=val, make_report=False)
    second = train_tnet(config, train_shapes=train, val_shapes=val, make_report=False)
    a, b = state_to_tensors(first.net), state_to_tensors(second.net)
    assert all(torch.equal(a[k], b[k]) for k in a)
    assert first.best_val == second.best_val and first.best_step == second.best_step
    other = train_tnet(
        config.replace(train={"seed": 1}), train_shapes=train, val_shapes=val, make_report=False
    )
    c = state_to_tensors(other.net)
    assert not all(torch.equal(a[k], c[k]) for k in a)
    assert [h["step"] for h in first.history] == [3, 6]
    assert not first.net.training


def test_run_writes_weights_report_and_log(toy_shapes, tmp_path) -> None:
    train, val = toy_shapes
    config = tiny_config(tmp_path)
    report = run_tnet_training(config, train_shapes=train, val_shapes=val)
    run = tmp_path / "run"
    assert {p.name for p in run.iterdir()} == {"tnet.safetensors", "report.json", "train.log"}
    on_disk = json.loads((run / "report.json").read_text())
    assert on_disk == json.loads(json.dumps(report))
    assert on_disk["network"] == {"conv_widths": [8, 16], "fc_widths": [8], "prealign": "none"}
    assert on_disk["training"]["best_step"] in (3, 6)
    alignment = on_disk["alignment"]
    assert alignment["failed_train_indices"] == alignment["train"]["failures"]
    for name, n in (("train", 4), ("val", 2), ("val_cloud500", 2), ("val_broken", 2)):
        stats = alignment[name]
        keys = {"n", "mean", "std", "median", "max", "n_failures", "failures", "threshold"}
        assert keys <= set(stats) and stats["n"] == n
        assert 0.0 <= stats["median"] <= stats["max"] <= math.pi
        assert stats["n_failures"] == len(stats["failures"])
    assert len(alignment["train"]["failed_keys"]) == alignment["train"]["n_failures"]
    log = (run / "train.log").read_text()
    assert "val step 6" in log and "val_broken: mean" in log

    net = load_tnet(run / "tnet.safetensors")
    assert not net.training and net.config() == on_disk["network"]
    meta = read_tnet_metadata(run / "tnet.safetensors")
    assert meta["training"]["config"]["train"]["steps"] == 6
    assert meta["training"]["best_val"] == on_disk["training"]["best_val"]


def test_checkpoint_round_trip(tmp_path) -> None:
    torch.manual_seed(0)
    net = TNet((8, 16), (8,), prealign="pca").train()
    net(torch.randn(4, 30, 3))  # BatchNorm statistics move
    net.eval()
    path = tmp_path / "w" / "tnet.safetensors"
    save_tnet(net, path, {"note": "x"})
    loaded = load_tnet(path, "cpu")
    expected, got = state_to_tensors(net), state_to_tensors(loaded)
    assert set(expected) == set(got) and all(torch.equal(expected[k], got[k]) for k in expected)
    cloud = torch.randn(2, 40, 3)
    with torch.no_grad():
        torch.testing.assert_close(loaded(cloud), net(cloud), rtol=0, atol=0)
    assert read_tnet_metadata(path)["training"] == {"note": "x"}
    assert loaded.prealign == "pca"
    with torch.no_grad():
        torch.testing.assert_close(loaded.rotation(cloud), net.rotation(cloud), rtol=0, atol=0)


def test_init_starts_from_a_weights_file_or_a_matching_bundle(toy_shapes, tmp_path) -> None:
    train, val = toy_shapes
    torch.manual_seed(3)
    source = TNet((8, 16), (8,)).eval()
    save_tnet(source, tmp_path / "start.safetensors")
    expected = state_to_tensors(source)
    net = TNet((8, 16), (8,))
    tnet_module.start_from(net, tmp_path / "start.safetensors")
    assert all(torch.equal(state_to_tensors(net)[k], v) for k, v in expected.items())

    # a run with init validates the started network first: with a zero learning rate the
    # weights (BatchNorm statistics aside) stay the source's
    config = tiny_config(
        tmp_path, train={"init": str(tmp_path / "start.safetensors"), "lr": 1e-12, "eta_min": 1e-12}
    )
    result = train_tnet(config, train_shapes=train, val_shapes=val, make_report=False)
    trained = state_to_tensors(result.net)
    weights = [k for k in expected if k.endswith("weight") and expected[k].ndim > 1]
    assert weights and all(torch.allclose(trained[k], expected[k], atol=1e-6) for k in weights)
    cold = train_tnet(tiny_config(tmp_path), train_shapes=train, val_shapes=val, make_report=False)
    assert not all(torch.equal(state_to_tensors(cold.net)[k], expected[k]) for k in weights)

    bundle_tnet = TNet((64, 128, 256), (256, 128), prealign="pca")
    tnet_module.start_from(bundle_tnet, "quadrupeds")  # the shipped matching bundle's T-Net
    from litege_core.matching import MatchingModel

    shipped = state_to_tensors(MatchingModel.load("quadrupeds").bundle.tnet)
    got = state_to_tensors(bundle_tnet)
    assert all(torch.allclose(got[k], shipped[k].to(got[k].dtype)) for k in shipped)


def test_init_refuses_other_widths_and_unknown_names(tmp_path) -> None:
    save_tnet(TNet((8, 16), (8,)), tmp_path / "start.safetensors")
    with pytest.raises(InputError, match="set \\[network\\] to match"):
        tnet_module.start_from(TNet((8, 32), (8,)), tmp_path / "start.safetensors")
    with pytest.raises(InputError, match="set \\[network\\] to match"):
        tnet_module.start_from(TNet((8, 16), (8,), prealign="pca"), tmp_path / "start.safetensors")
    with pytest.raises(InputError, match="unknown matching model"):
        tnet_module.start_from(TNet((8, 16), (8,)), tmp_path / "missing.safetensors")


def test_load_tnet_refuses_foreign_files(tmp_path) -> None:
    from safetensors.torch import save_file

    foreign = tmp_path / "foreign.safetensors"
    save_file({"x": torch.zeros(2)}, str(foreign))
    with pytest.raises(ArtifactError):
        load_tnet(foreign)
    garbage = tmp_path / "garbage.safetensors"
    garbage.write_bytes(b"not a safetensors file")
    with pytest.raises(ArtifactError):
        load_tnet(garbage)


# --------------------------------------------------------------------------- inference helpers


def test_predict_rotation(toy_shapes) -> None:
    torch.manual_seed(0)
    net = TNet((8, 16), (8,)).train()
    train, _ = toy_shapes
    rng = np.random.default_rng(0)
    cloud = sample_surface(train.vertices[0], train.faces[0], 3000, rng).points
    R = predict_rotation(net, cloud)
    assert R.shape == (3, 3) and R.dtype == np.float64
    np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-5)
    assert net.training  # mode restored
    np.testing.assert_array_equal(predict_rotation(net, cloud), R)  # deterministic subsample
    np.testing.assert_allclose(
        predict_rotation(net, cloud + np.array([0.3, -1.0, 2.0])), R, atol=1e-5
    )
    # Equal to the eval-mode network on the documented subset, centred.
    keep = np.sort(np.random.default_rng(0).choice(3000, PREDICT_MAX_POINTS, replace=False))
    subset = cloud[keep] - cloud[keep].mean(axis=0)
    net.eval()
    with torch.no_grad():
        direct = net.rotation(torch.as_tensor(subset, dtype=torch.float32)[None])[0]
    np.testing.assert_allclose(R, direct.double().numpy(), atol=1e-6)
    small = cloud[:500]
    assert predict_rotation(net, small).shape == (3, 3)


def test_angle_statistics_and_failures() -> None:
    stats = angle_statistics([0.1, 0.7, 0.2, 2.0], threshold=0.66)
    assert stats["n"] == 4 and stats["failures"] == [1, 3] and stats["n_failures"] == 2
    assert stats["max"] == 2.0 and stats["median"] == pytest.approx(0.45)
    assert stats["mean"] == pytest.approx(0.75)


def test_report_against_a_ground_truth_oracle(toy_shapes, monkeypatch) -> None:
    """With a predictor that returns the reference rotations the report sees zero error, and
    the clouds it feeds are the rotated shapes (their spread matches ``verts @ R_gtᵀ``)."""
    train, val = toy_shapes
    settings = TNetTrainConfig().report
    rots = {
        n: Rotation.random(
            n, random_state=np.random.default_rng(settings.rotation_seed)
        ).as_matrix()
        for n in (4, 2)
    }
    # Call order of alignment_report: train (mesh), then val as mesh, cloud500, broken.
    expected = [(train, i, rots[4][i]) for i in range(4)]
    expected += [(val, i, rots[2][i]) for _ in range(3) for i in range(2)]
    calls = iter(expected)

    def oracle(net, cloud):
        shapes, i, R = next(calls)
        # Aligning the cloud with R brings it to the canonical orientation: same principal
        # axes as the canonical mesh vertices (up to sign), so the axis cosines are ~1.
        aligned = (cloud - cloud.mean(axis=0)) @ R
        axes = np.linalg.eigh(np.cov(aligned.T))[1]
        verts = shapes.vertices[i]
        ref = np.linalg.eigh(np.cov((verts - verts.mean(axis=0)).T))[1]
        assert np.abs(np.abs(np.sum(axes * ref, axis=0)) - 1.0).max() < 0.1
        return R

    monkeypatch.setattr(tnet_evaluation, "predict_rotation", oracle)
    report = alignment_report(TNet((8,), ()), train, val, settings)
    for name in ("train", "val", "val_cloud500", "val_broken"):
        assert report[name]["max"] < 1e-6 and report[name]["failures"] == []
    assert next(calls, None) is None


# --------------------------------------------------------------------------- CLI


def test_parser_registers_train_tnet_and_keeps_geodesic() -> None:
    parser = argparse.ArgumentParser(prog="litege")
    add_train_parser(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(["train", "tnet", "--config", "c.toml", "--out", "o"])
    assert (args.config, args.out, args.train_command) == ("c.toml", "o", "tnet")
    assert callable(args.handler)
    args = parser.parse_args(["train", "geodesic", "--config", "g.toml"])
    assert args.train_command == "geodesic" and callable(args.handler)
    with pytest.raises(SystemExit):
        parser.parse_args(["train", "tnet"])


def test_frame_turns_are_drawn_per_item_and_used_in_training(toy_shapes, tmp_path) -> None:
    train, val = toy_shapes
    config = tiny_config(
        tmp_path, augment={"frame_turns": True}, network={"prealign": "pca"}, train={"steps": 4}
    )
    batch = sample_batch(train, config, step=0)
    turns = batch.frame_turns
    assert turns is not None and turns.shape == (4, 3, 3)
    assert all(bool((CUBE_ROTATIONS.float() == t).all(dim=(1, 2)).any()) for t in turns)
    again = sample_batch(train, config, step=0)
    assert torch.equal(again.frame_turns, turns)
    result = train_tnet(config, train_shapes=train, val_shapes=val, make_report=False)
    assert result.net.prealign == "pca" and math.isfinite(result.best_val["mean"])


# --------------------------------------------------------------------------- parallel runs


def test_parallel_shape_generation_gives_the_serial_shapes() -> None:
    serial = generate_shape_set("quadruped", "val", 3)
    parallel = generate_shape_set("quadruped", "val", 3, workers=2)
    assert parallel.keys == serial.keys
    for a, b in zip(parallel.vertices, serial.vertices, strict=True):
        np.testing.assert_array_equal(a, b)


def test_batch_loader_processes_serve_the_sampled_batches_in_order(toy_shapes, tmp_path) -> None:
    train, _ = toy_shapes
    config = tiny_config(tmp_path, augment={"frame_turns": True}, network={"prealign": "pca"})
    with BatchLoader(train, config, workers=2) as loader:
        for step in range(6):  # more steps than the batches first put in flight (2 × workers)
            served, sampled = loader.batch(step), sample_batch(train, config, step)
            assert all(torch.equal(a, b) for a, b in zip(served, sampled, strict=True))
        with pytest.raises(InputError, match="in order"):
            loader.batch(9)
    with BatchLoader(train, config, workers=0) as inline:  # no processes: sampled on demand
        assert torch.equal(inline.batch(5).R_gt, sample_batch(train, config, 5).R_gt)


def test_training_with_loader_processes_is_the_same_run(toy_shapes, tmp_path) -> None:
    train, val = toy_shapes
    config = tiny_config(tmp_path)
    inline = train_tnet(config, train_shapes=train, val_shapes=val, make_report=False)
    forked = train_tnet(
        config.replace(train={"loader_workers": 2}),
        train_shapes=train,
        val_shapes=val,
        make_report=False,
    )
    a, b = state_to_tensors(inline.net), state_to_tensors(forked.net)
    assert all(torch.equal(a[k], b[k]) for k in a)
    assert forked.best_val == inline.best_val and forked.steps == inline.steps == 6


def test_time_budget_plans_the_steps_that_fit() -> None:
    opt = TNetTrainConfig.from_dict({"train": {"steps": 10_000, "time_budget_minutes": 1.0}}).train
    # 100 steps in 6 s: 54 s left at ~16.7 steps/s → 900 more
    assert tnet_training._planned_steps(opt, 100, 6.0) == 1000
    assert tnet_training._planned_steps(opt, 100, 0.01) == 10_000  # capped at train.steps
    assert tnet_training._planned_steps(opt, 100, 90.0) == 100  # already over: stop now


def test_time_budget_run_records_the_steps_it_ran(toy_shapes, tmp_path, monkeypatch) -> None:
    train, val = toy_shapes
    monkeypatch.setattr(tnet_training, "PLAN_AFTER_STEPS", 2)
    monkeypatch.setattr(tnet_training, "_planned_steps", lambda opt, done, elapsed: 4)
    config = tiny_config(tmp_path, train={"steps": 50, "time_budget_minutes": 5.0})
    result = train_tnet(config, train_shapes=train, val_shapes=val, make_report=False)
    assert result.steps == 4
    assert [h["step"] for h in result.history] == [3, 4]  # val_every 3, then the last step
    assert cosine_lr(4, config.train, result.steps) == pytest.approx(config.train.eta_min)


def test_cli_overrides_workers_and_time_budget(monkeypatch, tmp_path) -> None:
    captured = {}

    def fake_run(config, out=None):
        captured["config"] = config
        return {
            "weights": "w",
            "training": {"best_step": 1, "best_val": {}, "steps_per_second": 1.0, "steps_run": 1},
            "alignment": {},
        }

    monkeypatch.setattr(tnet_module, "run_tnet_training", fake_run)
    parser = argparse.ArgumentParser(prog="litege")
    add_train_parser(parser.add_subparsers(dest="command", required=True))
    config_path = REPO / "configs" / "tnet-quadrupeds.toml"
    command = ["train", "tnet", "--config", str(config_path), "--workers", "3"]
    args = parser.parse_args([*command, "--time-budget", "2.5", "--init", "quadrupeds"])
    assert args.handler(args) == 0
    config = captured["config"]
    assert (config.data.workers, config.train.loader_workers) == (3, 3)
    assert config.train.time_budget_minutes == 2.5
    assert config.train.init == "quadrupeds"
