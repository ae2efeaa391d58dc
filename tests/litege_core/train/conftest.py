"""Shared fixtures of the training tests: a toy geodesic dataset and a tiny basis."""

from pathlib import Path

import numpy as np
import pytest
import torch
import trimesh

from litege_core.datasets import DatasetSpec, GeodesicDataset, build_dataset
from litege_core.engines import compute_distances
from litege_core.shape import Shape
from litege_core.train.basis import fit_training_basis
from litege_core.train.config import BasisConfig, TrainConfig

SPHERE = trimesh.creation.icosphere(subdivisions=2)  # 162 vertices
TOY_BASIS = {
    "n_components": 6,
    "std_threshold": 0.1,
    "grid_resolution": 25,
    "grid_pitch": 0.07,
    "fit_samples": 400,
}


class EllipsoidFactory:
    """Toy family: the icosphere scaled anisotropically by a seeded factor per family."""

    category = "toy"
    version = "toy-train-1"

    def template(self):
        return np.asarray(SPHERE.vertices), np.asarray(SPHERE.faces)

    def generate(self, family, seed):
        rng = np.random.default_rng(seed)
        base = {"round": 1.0, "long": 2.0}[family]
        scale = [base * rng.uniform(0.8, 1.2), rng.uniform(0.9, 1.1), 0.8]
        return np.asarray(SPHERE.vertices) * scale


def edge_dijkstra(vertices, faces, sources):
    """Cheap stand-in for the exact solver: the library's edge-graph Dijkstra rows."""
    shape = Shape.from_arrays(vertices, faces)
    return compute_distances(shape, sources, method="edge_dijkstra").distances


@pytest.fixture(autouse=True)
def _restore_torch_threads():
    """Training configs may set torch's (process-global) thread count: restore it."""
    threads = torch.get_num_threads()
    yield
    torch.set_num_threads(threads)


@pytest.fixture(scope="session")
def toy_dataset(tmp_path_factory) -> Path:
    """A built toy dataset: 8 train, 3 val shapes, 9 source rows, 162 vertices."""
    directory = tmp_path_factory.mktemp("toy-dataset")
    spec = DatasetSpec(
        name="toy",
        category="toy",
        families=("round", "long"),
        n_shapes={"train": 8, "val": 3, "test": 0},
        n_shared_sources=6,
        n_extra_sources=3,
        shard_size=4,
    )
    build_dataset(spec, directory, EllipsoidFactory(), distance_fn=edge_dijkstra, progress=False)
    return directory


@pytest.fixture(scope="session")
def toy_basis_path(toy_dataset, tmp_path_factory) -> Path:
    """A tiny basis fitted on the toy train split, saved to a file."""
    dataset = GeodesicDataset(toy_dataset)
    basis = fit_training_basis(
        BasisConfig(**TOY_BASIS), dataset.load_split("train"), dataset.faces, "toy", seed=0
    )
    path = tmp_path_factory.mktemp("toy-basis") / "basis.safetensors"
    basis.save(path)
    return path


def _toy_config(dataset: Path, run_dir: Path, basis_path: Path | None, **overrides) -> TrainConfig:
    """A fast config on the toy dataset; ``overrides`` are ``{table: {key: value}}``."""
    data = {
        "data": {
            "dataset": str(dataset),
            "views_per_shape": 3,
            "clean_samples": 400,
            "val_sources": 4,
            "val_targets": 32,
        },
        "augment": {"min_points": 200, "max_points": 800},
        "basis": {**TOY_BASIS, "path": str(basis_path) if basis_path else ""},
        "network": {"width": 16},
        "train": {
            "batch_views": 4,
            "sources_per_view": 4,
            "targets_per_view": 8,
            "steps_per_epoch": 5,
            "epochs": 2,
            "patience": 0,
            "seed": 3,
            "device": "cpu",
            "threads": 1,  # tiny matrices: one thread avoids barrier costs on busy cores
        },
        "output": {"dir": str(run_dir), "name": "toy", "category": "toy"},
    }
    for table, values in overrides.items():
        data[table] = {**data[table], **values}
    return TrainConfig.from_dict(data)


@pytest.fixture()
def make_config(toy_dataset, toy_basis_path, tmp_path):
    """``make_config(name="run", fitted_basis=False, **overrides)`` → a toy TrainConfig whose
    run directory is ``tmp_path / name``."""

    def make(name: str = "run", fitted_basis: bool = False, **overrides) -> TrainConfig:
        basis = None if fitted_basis else toy_basis_path
        return _toy_config(toy_dataset, tmp_path / name, basis, **overrides)

    return make
