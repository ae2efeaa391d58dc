"""Training tables and batches from a collection dataset (own triangulation per shape), and
from a collection merged with a template dataset."""

import numpy as np
import pytest
import torch
import trimesh

from litege_core.datasets import DatasetSpec, GeodesicDataset, build_dataset
from litege_core.descriptor import UdfPcaBasis
from litege_core.nets import TARGET_SCALE
from litege_core.train.config import AugmentConfig
from litege_core.train.data import (
    PairSampler,
    build_view_tables,
    coordinate_statistics,
    load_split_arrays,
    load_training_arrays,
    shape_meshes,
    validation_pairs,
)

from .conftest import edge_dijkstra


class BlobFactory:
    """Icospheres of 42 / 162 vertices, stretched by a seeded factor."""

    category = "blobs"
    version = "blobs-train-1"

    def generate_mesh(self, family, seed):
        sphere = trimesh.creation.icosphere(subdivisions={"small": 1, "large": 2}[family])
        rng = np.random.default_rng(seed)
        scale = [rng.uniform(1.2, 1.8), rng.uniform(0.9, 1.1), 0.8]
        return np.asarray(sphere.vertices) * scale, np.asarray(sphere.faces)


@pytest.fixture(scope="module")
def blob_dataset(tmp_path_factory):
    directory = tmp_path_factory.mktemp("blobs")
    spec = DatasetSpec(
        name="blobs",
        category="blobs",
        families=("small", "large"),
        n_shapes={"train": 6, "val": 2, "test": 0},
        n_shared_sources=6,
        n_extra_sources=3,
        shard_size=4,
        kind="collection",
    )
    build_dataset(spec, directory, BlobFactory(), distance_fn=edge_dijkstra, progress=False)
    return directory


@pytest.fixture(scope="module")
def blob_tables(blob_dataset, toy_basis_path):
    dataset = GeodesicDataset(blob_dataset)
    arrays = load_split_arrays(dataset, "train")
    tables = build_view_tables(
        arrays,
        dataset.faces,  # None: every shape carries its own faces
        UdfPcaBasis.load(toy_basis_path),
        n_views=2,
        clean_samples=300,
        augment=AugmentConfig(min_points=200, max_points=600),
        seed=0,
    )
    return tables, arrays


def test_tables_keep_each_shapes_vertices_and_zero_padding(blob_tables):
    tables, _ = blob_tables
    assert tables.is_padded and tables.n_vertices == 162 and tables.n_shapes == 6
    np.testing.assert_array_equal(tables.vertex_counts.numpy(), [42, 162] * 3)
    counts = tables.view_vertex_counts().numpy()
    vertices = tables.vertices.numpy()
    for view, count in enumerate(counts):
        assert (vertices[view, count:] == 0).all()
        assert np.abs(vertices[view, :count]).sum(axis=1).min() > 0
    mean, std = coordinate_statistics(tables)
    valid = np.concatenate([vertices[v, :c] for v, c in enumerate(counts)]).astype(np.float64)
    np.testing.assert_allclose(mean, valid.mean(axis=0), atol=1e-9)
    np.testing.assert_allclose(std, valid.std(axis=0), rtol=1e-9)


def test_targets_stay_on_their_shape_and_match_the_rows(blob_tables):
    tables, arrays = blob_tables
    sampler = PairSampler(tables, 6, 4, 50, seed=5)
    for _ in range(5):
        views, rows, targets = sampler.draw()
        limit = tables.view_vertex_counts()[views]
        assert (targets < limit[:, None]).all() and (targets >= 0).all()
    small_views = torch.nonzero(tables.view_vertex_counts() == 42).ravel()
    assert small_views.numel() == 6
    state = sampler.get_state().clone()
    views, rows, targets = sampler.draw()
    sampler.set_state(state)
    batch = sampler.sample()  # the same draw, gathered
    assert batch.target.shape == (6, 4, 50)
    canonical = tables.vertices.numpy()
    for b, i, j in [(0, 0, 0), (3, 2, 17), (5, 3, 49)]:
        v = int(views[b])
        s = v // 2
        source_vertex = int(arrays["sources"][s, int(rows[b, i])])
        target = int(targets[b, j])
        d_raw = float(arrays["distances"][s, int(rows[b, i]), target])
        scale = float(tables.scale[v])
        euclid = float(np.linalg.norm(canonical[v, source_vertex] - canonical[v, target]))
        expected = max(TARGET_SCALE * (scale * d_raw - euclid), 0.0)
        assert float(batch.target[b, i, j]) == pytest.approx(expected, rel=1e-5, abs=1e-6)
    # seeded: the same seed draws the same batches
    first, second = PairSampler(tables, 4, 3, 7, seed=9), PairSampler(tables, 4, 3, 7, seed=9)
    assert torch.equal(first.sample().target, second.sample().target)


def test_validation_targets_stay_on_their_shape(blob_tables):
    tables, _ = blob_tables
    pairs = validation_pairs(tables, 4, 300, seed=1)
    assert (pairs.targets < tables.view_vertex_counts()[:, None]).all()
    again = validation_pairs(tables, 4, 300, seed=1)
    assert torch.equal(pairs.targets, again.targets)


def test_merging_a_template_and_a_collection_dataset(toy_dataset, blob_dataset, toy_basis_path):
    arrays, faces = load_training_arrays([toy_dataset, blob_dataset], "train")
    assert faces is None and arrays["vertices"].shape == (8 + 6, 162, 3)
    assert arrays["sources"].shape[1] == 9 and arrays["faces"].shape[0] == 14
    np.testing.assert_array_equal(arrays["n_vertices"][:8], 162)
    assert len(set(arrays["seed"].tolist())) == 14  # the second dataset's seeds are offset
    meshes = list(shape_meshes(arrays))
    assert [len(v) for v, _ in meshes[8:]] == [42, 162] * 3
    template = GeodesicDataset(toy_dataset)
    np.testing.assert_array_equal(meshes[0][1], template.faces)
    tables = build_view_tables(
        arrays,
        faces,
        UdfPcaBasis.load(toy_basis_path),
        n_views=1,
        clean_samples=300,
        augment=AugmentConfig(min_points=200, max_points=600),
        seed=0,
    )
    assert tables.n_shapes == 14
    # a single template dataset loads exactly as before
    alone, alone_faces = load_training_arrays(toy_dataset, "train")
    np.testing.assert_array_equal(alone_faces, template.faces)
    assert set(alone) == {"vertices", "sources", "distances", "area", "seed", "family"}
