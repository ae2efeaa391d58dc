"""Matching training on the toy dataset: tables, pairs, passes, bundle export."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
import torch
import trimesh

from litege_core.datasets import DatasetSpec, GeodesicDataset, build_dataset
from litege_core.engines import compute_distances
from litege_core.errors import InputError
from litege_core.matching import MatchingModel, MatchingPipeline
from litege_core.nets import TNet
from litege_core.shape import Shape
from litege_core.train.config import AugmentConfig
from litege_core.train.matching import (
    MatchingTrainConfig,
    species_datasets,
    species_tables,
    train_matching,
)
from litege_core.train.matching_data import (
    build_matching_tables,
    concatenate_tables,
    sample_batch,
    view_pairs,
)
from litege_core.train.tnet import save_tnet

TINY_TNET = {"conv_widths": (8, 16, 32), "fc_widths": (16, 8)}


@pytest.fixture(scope="module")
def tnet_path(tmp_path_factory):
    torch.manual_seed(0)
    path = tmp_path_factory.mktemp("tnet") / "tnet.safetensors"
    save_tnet(TNet(**TINY_TNET).eval(), path)
    return path


class CoarseSphereFactory:
    """A second toy "species": another triangulation (42 vertices), squashed by seed."""

    category = "toy-coarse"
    version = "toy-coarse-1"

    def template(self):
        sphere = trimesh.creation.icosphere(subdivisions=1)
        return np.asarray(sphere.vertices), np.asarray(sphere.faces)

    def generate(self, family, seed):
        rng = np.random.default_rng(seed)
        return self.template()[0] * [rng.uniform(1.5, 2.0), 1.0, rng.uniform(0.6, 0.9)]


def edge_dijkstra(vertices, faces, sources):
    shape = Shape.from_arrays(vertices, faces)
    return compute_distances(shape, sources, method="edge_dijkstra").distances


@pytest.fixture(scope="module")
def species_root(tmp_path_factory, toy_dataset):
    """Two species datasets: the toy spheres (162 vertices, 6 shared sources) and coarse
    spheres (42 vertices, 4 shared sources)."""
    root = tmp_path_factory.mktemp("species")
    shutil.copytree(toy_dataset, root / "round")
    spec = DatasetSpec(
        name="coarse",
        category="toy-coarse",
        families=("coarse",),
        n_shapes={"train": 4, "val": 0, "test": 0},
        n_shared_sources=4,
        n_extra_sources=0,
        shard_size=4,
    )
    build_dataset(
        spec, root / "coarse", CoarseSphereFactory(), distance_fn=edge_dijkstra, progress=False
    )
    return root


def _config(toy_dataset, tnet_path, tmp_path, species="", **train) -> MatchingTrainConfig:
    return MatchingTrainConfig.from_dict(
        {
            "data": {
                "dataset": str(toy_dataset),
                "species": str(species),
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
    turns = AugmentConfig(min_points=200, max_points=400, axis_turn_probability=0.5)
    with pytest.raises(InputError, match="axis_turn_probability"):
        build_matching_tables(*args, n_views=2, augment=turns, seed=0)


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
        _config(toy_dataset, "unused", tmp_path / "c", steps=12, lr=1e-3, init=str(start.path))
    )
    assert moved["training"]["chosen_first_pass"] == 0
    assert moved["files"]["judge-0.safetensors"] == same["files"]["judge-0.safetensors"]
    start_error = moved["training"]["first_passes"][0]["match_error_x100"]
    history = moved["training"]["history"]
    assert [h["step"] for h in history] == [3, 6, 9, 12]
    assert history[0]["match_error_x100"] != start_error  # the network moved from the start
    # the export is the best network seen: the start itself unless a validation beat it
    best = min([start_error, *(h["match_error_x100"] for h in history)])
    assert moved["metrics"]["val_match_error_x100"] == pytest.approx(best)
    kept_start = moved["files"]["matching-0.safetensors"] == same["files"]["matching-0.safetensors"]
    assert kept_start == (best == start_error)
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


def test_joined_tables_pad_and_draw_every_pair_within_one_dataset(
    toy_dataset, tnet_path, species_root, tmp_path
):
    from litege_core.train.tnet import load_tnet

    assert [p.name for p in species_datasets(species_root)] == ["coarse", "round"]
    config = _config(toy_dataset, tnet_path, tmp_path, species=species_root)
    common = dict(
        basis=MatchingModel.tiny_random(0).bundle.basis,
        tnet=load_tnet(tnet_path),
        pipeline=MatchingPipeline(),
        augment=config.augment,
        reject_angle=3.2,
        device="cpu",
    )
    (coarse_path, coarse, n_coarse), (round_path, sphere, n_round) = species_tables(config, common)
    assert (coarse_path, n_coarse, round_path, n_round) == (
        species_root / "coarse",
        4,
        species_root / "round",
        8,
    )
    joined = concatenate_tables([sphere, coarse])
    assert joined.n_views == sphere.n_views + coarse.n_views == 24
    assert joined.vertices.shape == (24, 162, 3) and joined.distances.shape == (12, 4, 162)
    assert joined.n_vertices.tolist() == [162] * 8 + [42] * 4
    # the coarse shapes keep their own rows and zero padding beyond their 42 vertices
    torch.testing.assert_close(joined.distances[8:, :, :42], coarse.distances)
    assert not joined.distances[8:, :, 42:].any() and not joined.vertices[16:, 42:].any()
    generator = torch.Generator().manual_seed(0)
    pairs = view_pairs(joined, 400, generator)
    in_coarse = pairs >= sphere.n_views
    assert torch.equal(in_coarse[:, 0], in_coarse[:, 1]) and in_coarse.any() and (~in_coarse).any()
    assert (joined.shape[pairs[:, 0]] != joined.shape[pairs[:, 1]]).all()
    # no target or coordinate ever comes from the padding
    for _ in range(20):
        batch = sample_batch(joined, 8, 3, 8, 1.0, generator)
        assert (batch.src.abs().sum(1) > 0).all() and (batch.dst.abs().sum(1) > 0).all()
        assert (batch.target >= 0).all()
    with pytest.raises(InputError, match="holds no dataset"):
        species_datasets(tmp_path / "empty")


def test_training_draws_on_species_datasets(toy_dataset, tnet_path, species_root, tmp_path):
    manifest = train_matching(
        _config(toy_dataset, tnet_path, tmp_path, species=species_root, first_passes=1)
    )
    species = manifest["training"]["species"]
    assert species == {"coarse": {"views": 8, "shapes": 4}, "round": {"views": 16, "shapes": 8}}
    assert manifest["training"]["train_views"] == 16 + 24
    provenance = manifest["training"]["dataset"]["datasets"]  # every dataset, for the card
    assert [Path(d["path"]).name for d in provenance] == [toy_dataset.name, "coarse", "round"]
    assert [d["category"] for d in provenance] == ["toy", "toy-coarse", "toy"]
    assert np.isfinite(manifest["metrics"]["val_match_error_x100"])


def test_the_card_credits_posed_template_data():
    from litege_core.learned.cards import _training_data

    parts = [
        {"name": "quadruped-matching-4", "category": "quadruped", "solver": "heat"},
        {"name": "rigged-matching/Wolf", "category": "rigged-template", "solver": "heat"},
    ]
    lines = "\n".join(_training_data({"datasets": parts}, "", None))
    assert "one fixed remeshed triangulation" in lines and "@tomkranis (CC BY 4.0)" in lines


def test_config_errors_are_input_errors(toy_dataset, tnet_path, tmp_path):
    with pytest.raises(InputError):
        _config(toy_dataset, tnet_path, tmp_path, lr=1e-5, eta_min=1e-3)
    with pytest.raises(InputError):
        MatchingTrainConfig.from_dict({"nonsense": {}})
    with pytest.raises(InputError):
        MatchingTrainConfig.from_dict({"train": {"steps": -1}})
    with pytest.raises(InputError):
        MatchingTrainConfig.from_dict({"train": {"bogus": 1}})


def test_misalignment_is_measured_from_the_frame_offset():
    from litege_core.train.matching_data import misalignment
    from litege_core.variants import random_rotation

    view, offset = random_rotation(1), random_rotation(2)
    undone = offset @ view.T  # a T-Net frame that lands every view on the offset frame
    assert misalignment(undone, view) > 0.1
    assert misalignment(undone, view, offset) < 1e-6
    assert misalignment(view.T, view) < 1e-6  # no offset: the stored frame is canonical


def test_the_frame_offset_of_a_collection_stored_in_another_convention():
    """Procedural quadrupeds stored turned by Q (a user's convention): the shipped T-Net still
    brings them to its canonical frame, which lies at Qᵀ in the stored frame."""
    from litege_core.synth import families, generate_shape
    from litege_core.train.matching_data import misalignment, stored_frame_offset
    from litege_core.variants import random_rotation

    names = families("quadruped")
    shapes = [generate_shape("quadruped", names[k % len(names)], 2_000_000 + k) for k in range(8)]
    stored_turn = random_rotation(7)
    arrays = {
        "vertices": np.stack([s.vertices @ stored_turn.T for s in shapes]),
        "seed": np.arange(8),
    }
    model = MatchingModel.load("quadrupeds")
    faces = np.asarray(shapes[0].faces)
    offset, share = stored_frame_offset(arrays, faces, model.bundle.tnet, model.pipeline, seed=0)
    assert misalignment(offset, stored_turn) < 0.3 and share >= 0.75  # offset ≈ Qᵀ
    plain = {**arrays, "vertices": np.stack([s.vertices for s in shapes])}
    offset, _ = stored_frame_offset(plain, faces, model.bundle.tnet, model.pipeline, seed=0)
    assert misalignment(offset, np.eye(3)) < 0.3  # stored canonical: about the identity
