import json

import numpy as np
import pytest
import torch

from litege_core.errors import InputError
from litege_core.learned import load_bundle
from litege_core.train import trainer as trainer_module
from litege_core.train.pipeline import prepare_run, train_geodesic
from litege_core.train.trainer import LAST, ValidationReport, cosine_lr, evaluate, read_checkpoint


def test_cosine_schedule(make_config):
    config = make_config(train={"epochs": 4, "steps_per_epoch": 10})
    assert cosine_lr(0, config) == pytest.approx(1e-2)
    assert cosine_lr(20, config) == pytest.approx(0.5 * (1e-2 + 1e-4))
    assert cosine_lr(40, config) == pytest.approx(1e-4)
    per_epoch = config.replace(train={"schedule": "epoch"})
    assert cosine_lr(19, per_epoch) == cosine_lr(10, per_epoch) > cosine_lr(20, per_epoch)


def test_exact_resume_equals_uninterrupted_run(make_config):
    straight = train_geodesic(make_config("straight"), export_bundle=False)
    config = make_config("interrupted")
    first = train_geodesic(config, max_epochs=1)
    assert first.state.epoch == 1 and first.manifest is None
    resumed = train_geodesic(
        config, resume=config.run_dir / "checkpoints" / LAST, export_bundle=False
    )
    assert resumed.state.epoch == 2 and resumed.state.step == straight.state.step == 10
    a = straight.prepared.network.state_dict()
    b = resumed.prepared.network.state_dict()
    assert a.keys() == b.keys()
    for key in a:
        assert torch.equal(a[key], b[key]), key
    losses = [h["loss"] for h in straight.state.history]
    assert [h["loss"] for h in resumed.state.history] == losses


def test_resume_refuses_a_different_config(make_config):
    config = make_config("a")
    train_geodesic(config, max_epochs=1)
    changed = make_config("a", train={"seed": 4})
    with pytest.raises(InputError, match=r"train\.seed"):
        train_geodesic(changed, resume=config.run_dir / "checkpoints" / LAST)


def test_early_stopping_after_patience(make_config, monkeypatch):
    errors = iter([5.0, 4.0, 4.5, 4.2, 3.0, 1.0])

    def fake_evaluate(net, pairs):
        value = next(errors)
        return ValidationReport(value, value, value, {}, 1.0, 1)

    monkeypatch.setattr(trainer_module, "evaluate", fake_evaluate)
    config = make_config(train={"epochs": 6, "steps_per_epoch": 1, "patience": 2})
    prepared = prepare_run(config)
    state = prepared.trainer.fit()
    assert state.stopped_early and state.epoch == 4
    assert state.best_epoch == 2 and state.best_error == 4.0
    assert [h["best"] for h in state.history] == [True, True, False, False]


def test_training_reduces_validation_error_and_exports_a_bundle(make_config):
    config = make_config(
        "smoke",
        fitted_basis=True,
        train={"epochs": 3, "steps_per_epoch": 40, "batch_views": 8},
        output={"weights_dtype": "float16"},
    )
    prepared = prepare_run(config)
    before = evaluate(prepared.network, prepared.validation).mean
    result = train_geodesic(config)
    after = result.state.best_error
    assert after < 0.8 * before, (before, after)
    assert (config.run_dir / "basis.safetensors").exists()  # fitted, saved next to the run
    manifest = result.manifest
    bundle = load_bundle(config.run_dir / "bundle")
    assert bundle.content_hash == manifest["content_hash"] and bundle.name == "toy"
    training = bundle.manifest["training"]
    assert training["steps"] == 120 and training["best_epoch"] >= 1
    assert training["residual_std"] > 0 and len(training["history"]) == 3
    assert training["dataset"]["counts"] == {"train": 8, "val": 3, "test": 0}
    assert bundle.manifest["metrics"]["val_mean_error"] == pytest.approx(after, rel=1e-2)
    weights = read_checkpoint(config.run_dir / "checkpoints" / "best.safetensors")[0]
    torch.testing.assert_close(bundle.network.coord_std, weights["coord_std"])
    assert (config.run_dir / "train.log").read_text().count("epoch ") >= 3
    json.dumps(bundle.manifest)  # JSON-safe
    # the run directory's fitted basis is not silently reused with other fit settings
    with pytest.raises(InputError, match="fitted with other settings"):
        prepare_run(config.replace(basis={"std_threshold": 0.2}))


def test_train_then_evaluate_end_to_end(make_config, toy_dataset):
    """A tiny run, exported, reloaded bit-exactly, then evaluated with the real protocol."""
    from litege_core.evaluation.geodesic import evaluate as evaluate_protocol
    from litege_core.evaluation.geodesic import synthetic_eval_shapes
    from litege_core.learned import Predictor

    config = make_config(
        "e2e", fitted_basis=True, train={"epochs": 2, "steps_per_epoch": 40, "batch_views": 8}
    )
    train_geodesic(config)
    first, second = (load_bundle(config.run_dir / "bundle") for _ in range(2))
    for key, value in first.network.state_dict().items():
        assert torch.equal(value, second.network.state_dict()[key]), key
    shapes = synthetic_eval_shapes(toy_dataset, limit=3, split="val")
    results = evaluate_protocol(shapes, Predictor(first), settings=("mesh", "cloud_300"))
    litege = {r.setting: r for r in results if r.method == "LiteGE"}
    assert set(litege) == {"mesh", "cloud_300"}
    # Units or frames mixed up anywhere in the chain give errors of order 100.
    assert all(np.isfinite(r.mean) and r.mean < 40 for r in litege.values()), litege


def test_warm_start_continues_from_the_init_bundle(make_config):
    """A run started from a bundle begins with that bundle's network and basis: before any
    step its validation error equals the bundle's, and a short run does not lose it."""
    base = make_config(
        "base", fitted_basis=True, train={"epochs": 2, "steps_per_epoch": 30, "batch_views": 8}
    )
    first = train_geodesic(base)
    bundle_dir = base.run_dir / "bundle"
    init = load_bundle(bundle_dir)
    config = make_config("warm", train={"epochs": 1, "steps_per_epoch": 10, "batch_views": 8})
    prepared = prepare_run(config, init=bundle_dir)
    assert prepared.basis.content_hash == init.basis.content_hash
    assert prepared.basis_source.startswith("init bundle toy")
    start = evaluate(prepared.network, prepared.validation).mean
    reference = evaluate(init.network.float(), prepared.validation).mean
    assert start == pytest.approx(reference, rel=1e-4)
    assert start < 0.9 * evaluate_fresh(make_config, "fresh")
    warm = train_geodesic(config, init=bundle_dir)
    # a fresh 1e-2 learning rate disturbs the init here: the baseline (epoch 0) stays the best
    assert warm.state.best_error <= first.state.best_error * (1 + 1e-4)
    exported = load_bundle(config.run_dir / "bundle")
    assert evaluate(exported.network.float(), prepared.validation).mean <= start * 1.01
    assert warm.manifest["training"]["init_bundle"] == init.content_hash


def evaluate_fresh(make_config, name: str) -> float:
    prepared = prepare_run(make_config(name, fitted_basis=True))
    return evaluate(prepared.network, prepared.validation).mean


def test_warm_start_refuses_an_unknown_init(make_config):
    with pytest.raises(InputError, match="neither a bundle directory nor a shipped model"):
        prepare_run(make_config("bad"), init="no-such-model")


class _BlobCollection:
    """Toy collection: icospheres of 1 or 2 subdivisions (own triangulations), stretched."""

    category = "blobs"
    version = "blobs-train-1"

    def generate_mesh(self, family, seed):
        import trimesh

        sphere = trimesh.creation.icosphere(subdivisions={"small": 1, "large": 2}[family])
        stretch = np.random.default_rng(seed).uniform(0.7, 1.3, size=3) * [2.0, 1.0, 0.8]
        return np.asarray(sphere.vertices) * stretch, np.asarray(sphere.faces)


def test_training_on_a_template_and_a_collection_dataset_together(make_config, tmp_path):
    """A collection dataset (each shape its own triangulation) trains beside a template one:
    ``data.extra_datasets`` merges them, the basis is fitted on both, and the run exports."""
    from litege_core.datasets import DatasetSpec, build_dataset
    from litege_core.engines import compute_distances
    from litege_core.shape import Shape

    def edge_rows(vertices, faces, sources):
        shape = Shape.from_arrays(vertices, faces)
        return compute_distances(shape, sources, method="edge_dijkstra").distances

    spec = DatasetSpec(
        name="blobs",
        category="blobs",
        families=("small", "large"),
        n_shapes={"train": 6, "val": 2, "test": 0},
        n_shared_sources=6,
        n_extra_sources=3,
        shard_size=3,
        kind="collection",
    )
    collection = tmp_path / "blobs"
    build_dataset(spec, collection, _BlobCollection(), distance_fn=edge_rows, progress=False)
    config = make_config("mixed", fitted_basis=True, data={"extra_datasets": [str(collection)]})
    prepared = prepare_run(config)
    assert prepared.train.n_shapes == 8 + 6
    assert len(prepared.fingerprint["datasets"]) == 2
    result = train_geodesic(config)
    assert result.manifest["training"]["n_train_shapes"] == 14
    assert np.isfinite(result.state.best_error)
