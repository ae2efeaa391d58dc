"""Matching training on the toy dataset: tables, pairs, passes, bundle export."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from litege_core.datasets import GeodesicDataset
from litege_core.errors import InputError
from litege_core.matching import MatchingModel, MatchingPipeline
from litege_core.nets import TNet
from litege_core.shape import Shape
from litege_core.train.config import AugmentConfig
from litege_core.train.matching import MatchingTrainConfig, train_matching
from litege_core.train.matching_data import build_matching_tables, sample_batch
from litege_core.train.tnet import save_tnet

TINY_TNET = {"conv_widths": (8, 16, 32), "fc_widths": (16, 8)}


@pytest.fixture(scope="module")
def tnet_path(tmp_path_factory):
    torch.manual_seed(0)
    path = tmp_path_factory.mktemp("tnet") / "tnet.safetensors"
    save_tnet(TNet(**TINY_TNET).eval(), path)
    return path


def _config(toy_dataset, tnet_path, tmp_path, **train) -> MatchingTrainConfig:
    return MatchingTrainConfig.from_dict(
        {
            "data": {
                "dataset": str(toy_dataset),
                "tnet": str(tnet_path),
                "views_per_shape": 2,
                "val_view_pairs": 3,
                "reject_angle": 3.2,
            },
            "augment": {"min_points": 200, "max_points": 400},
            "basis": {
                "path": str(tmp_path / "basis.safetensors"),
                "n_components": 5,
                "std_threshold": 0.05,
                "grid_resolution": 25,
                "grid_pitch": 0.07,
                "fit_samples": 300,
            },
            "network": {"width": 16},
            "train": {
                "view_pairs": 4,
                "rows_per_pair": 3,
                "targets_per_pair": 8,
                "first_passes": 2,
                "first_pass_steps": 4,
                "steps": 6,
                "validate_every": 3,
                **train,
            },
            "output": {
                "dir": str(tmp_path / "run"),
                "name": "toy",
                "category": "toy",
                "weights_dtype": "float32",
            },
        }
    )


def test_tables_hold_unit_area_targets_of_shared_sources(toy_dataset, tnet_path):
    from litege_core.train.tnet import load_tnet

    dataset = GeodesicDataset(toy_dataset)
    arrays = dataset.load_split("train")
    basis = MatchingModel.tiny_random(0).bundle.basis
    tables = build_matching_tables(
        arrays,
        np.asarray(dataset.faces),
        6,
        basis,
        load_tnet(tnet_path),
        MatchingPipeline(),
        n_views=2,
        augment=AugmentConfig(min_points=200, max_points=400),
        seed=0,
        reject_angle=3.2,
    )
    assert tables.n_views == 16 and tables.distances.shape == (8, 6, 162)
    area = arrays["area"][0]
    np.testing.assert_allclose(
        tables.distances[0].numpy(), arrays["distances"][0, :6] / np.sqrt(area), rtol=1e-3
    )
    # the clean view's vertices are in a unit-area frame
    clean = Shape.from_arrays(tables.vertices[0].double().numpy(), dataset.faces)
    assert clean.area == pytest.approx(1.0, rel=1e-3)
    generator = torch.Generator().manual_seed(0)
    batch = sample_batch(tables, 5, 3, 4, 1.42, generator)
    assert batch.src.shape == (60, 3) and batch.target.shape == (60,)
    assert (batch.target >= 0).all()


def test_rejection_filter_drops_misaligned_views(toy_dataset, tnet_path):
    from litege_core.train.tnet import load_tnet

    dataset = GeodesicDataset(toy_dataset)
    arrays = dataset.load_split("train")
    basis = MatchingModel.tiny_random(0).bundle.basis
    args = (arrays, np.asarray(dataset.faces), 6, basis, load_tnet(tnet_path), MatchingPipeline())
    kwargs = dict(n_views=2, augment=AugmentConfig(min_points=200, max_points=400), seed=0)
    everything = build_matching_tables(*args, reject_angle=3.2, **kwargs)
    strict = build_matching_tables(*args, reject_angle=float(everything.angle.median()), **kwargs)
    assert strict.n_views < everything.n_views
    assert float(strict.angle.max()) <= float(everything.angle.median())
    with pytest.raises(InputError, match="rejected"):
        build_matching_tables(*args, reject_angle=0.0, **kwargs)
    jitter = AugmentConfig(min_points=200, max_points=400, frame_jitter_degrees=5.0)
    with pytest.raises(InputError, match="frame_jitter_degrees"):  # T-Net frames: no jitter
        build_matching_tables(*args, n_views=2, augment=jitter, seed=0)


def test_training_exports_a_bundle_that_matches(toy_dataset, tnet_path, tmp_path):
    manifest = train_matching(_config(toy_dataset, tnet_path, tmp_path))
    training = manifest["training"]
    assert len(training["first_passes"]) == 2 and training["chosen_first_pass"] in (0, 1)
    assert np.isfinite(manifest["metrics"]["val_match_error_x100"])
    model = MatchingModel.load(tmp_path / "run" / "bundle")
    dataset = GeodesicDataset(toy_dataset)
    verts = dataset.load_split("val")["vertices"]
    x, y = model.prepare_many([Shape.from_arrays(v, dataset.faces) for v in verts[:2]])
    result = model.match(x, y)
    assert result.indices.shape == (162,)


def test_training_is_deterministic(toy_dataset, tnet_path, tmp_path):
    a = train_matching(_config(toy_dataset, tnet_path, tmp_path / "a", first_passes=1))
    b = train_matching(_config(toy_dataset, tnet_path, tmp_path / "b", first_passes=1))
    assert a["files"]["matching-0.safetensors"] == b["files"]["matching-0.safetensors"]


def test_training_continues_a_bundle(toy_dataset, tnet_path, tmp_path):
    from litege_core.matching.bundle import load_matching_bundle
    from litege_core.nets import state_to_tensors

    train_matching(_config(toy_dataset, tnet_path, tmp_path / "a", first_passes=1))
    start = load_matching_bundle(tmp_path / "a" / "run" / "bundle")
    # with no steps, the continued bundle is the start: same T-Net, pipeline, basis and network
    same = train_matching(
        _config(toy_dataset, "unused", tmp_path / "b", steps=0, init=str(start.path))
    )
    continued = load_matching_bundle(tmp_path / "b" / "run" / "bundle")
    assert continued.basis.content_hash == start.basis.content_hash
    assert continued.pipeline == start.pipeline
    for a, b in ((continued.tnet, start.tnet), (continued.networks[0], start.networks[0])):
        got, want = state_to_tensors(a), state_to_tensors(b)
        assert all(torch.equal(got[k], want[k]) for k in want)
    training = same["training"]
    assert training["init"] == {"bundle": str(start.path), "content_hash": start.content_hash}
    assert len(training["first_passes"]) == 1 and training["chosen_first_pass"] == 0
    # the continued bundle judges frames with the network it started from
    (judge,) = continued.judge_networks
    got, want = state_to_tensors(judge), state_to_tensors(start.networks[0])
    assert all(torch.equal(got[k], want[k]) for k in want)
    # with steps, it trains on from there (the basis file of [basis] is neither read nor fitted)
    moved = train_matching(
        _config(toy_dataset, "unused", tmp_path / "c", steps=6, lr=1e-3, init=str(start.path))
    )
    assert moved["training"]["chosen_first_pass"] == 0
    assert moved["files"]["judge-0.safetensors"] == same["files"]["judge-0.safetensors"]
    assert moved["files"]["matching-0.safetensors"] != same["files"]["matching-0.safetensors"]
    assert not (tmp_path / "c" / "basis.safetensors").exists()
    shipped = MatchingModel.load("quadrupeds").bundle  # its T-Net was swapped in: that stays said
    config = _config(toy_dataset, "unused", tmp_path / "s", steps=0, init="quadrupeds")
    kept = train_matching(config.replace(network={"width": 200}))
    assert kept["training"]["tnet_swap"] == shipped.manifest["training"]["tnet_swap"]
    narrow = _config(toy_dataset, "unused", tmp_path / "d", init=str(start.path))
    with pytest.raises(InputError, match=r"set network\.width"):
        train_matching(narrow.replace(network={"width": 8}))
    with pytest.raises(InputError, match="unknown matching model"):
        train_matching(_config(toy_dataset, "unused", tmp_path / "e", init="no-such-model"))


def test_config_errors_are_input_errors(toy_dataset, tnet_path, tmp_path):
    with pytest.raises(InputError):
        _config(toy_dataset, tnet_path, tmp_path, lr=1e-5, eta_min=1e-3)
    with pytest.raises(InputError):
        MatchingTrainConfig.from_dict({"nonsense": {}})
    with pytest.raises(InputError):
        MatchingTrainConfig.from_dict({"train": {"steps": -1}})
    with pytest.raises(InputError):
        MatchingTrainConfig.from_dict({"train": {"bogus": 1}})
