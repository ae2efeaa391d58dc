import numpy as np
import pytest
import torch

from litege_core.datasets import GeodesicDataset
from litege_core.descriptor import UdfPcaBasis
from litege_core.nets import TARGET_SCALE
from litege_core.train.config import AugmentConfig
from litege_core.train.data import (
    PairSampler,
    build_view_tables,
    coordinate_statistics,
    load_split_arrays,
    validation_pairs,
)


@pytest.fixture(scope="module")
def tables_and_arrays(toy_dataset, toy_basis_path):
    dataset = GeodesicDataset(toy_dataset)
    arrays = load_split_arrays(dataset, "train")
    tables = build_view_tables(
        arrays,
        dataset.faces,
        UdfPcaBasis.load(toy_basis_path),
        n_views=2,
        clean_samples=300,
        augment=AugmentConfig(min_points=200, max_points=600),
        seed=0,
    )
    return tables, arrays


def test_sampling_is_deterministic_per_seed(tables_and_arrays):
    tables, _ = tables_and_arrays
    a, b = PairSampler(tables, 4, 3, 5, seed=11), PairSampler(tables, 4, 3, 5, seed=11)
    for _ in range(3):
        first, second = a.sample(), b.sample()
        for x, y in zip(first, second, strict=True):
            assert torch.equal(x, y)
    other = PairSampler(tables, 4, 3, 5, seed=12).sample()
    assert not torch.equal(other.points, a.sample().points)
    # the generator state restores the stream exactly
    state = a.get_state().clone()
    expected = a.sample()
    a.set_state(state)
    assert torch.equal(a.sample().target, expected.target)


def test_batch_layout_and_targets_by_hand(tables_and_arrays):
    tables, arrays = tables_and_arrays
    sampler = PairSampler(tables, 5, 4, 6, seed=2)
    views, rows, targets = sampler.draw()
    sampler.set_state(torch.Generator().manual_seed(2).get_state())
    batch = sampler.sample()
    assert torch.equal(batch.views, views)
    assert batch.points.shape == (5, 10, 3) and batch.target.shape == (5, 4, 6)
    assert batch.descriptors.shape == (5, tables.descriptors.shape[1])
    assert len(set(views.tolist())) == 5
    assert all(len(set(r)) == 4 for r in rows.tolist())  # distinct source rows per view
    canonical = tables.vertices.numpy()
    for b, i, j in [(0, 0, 0), (2, 3, 5), (4, 1, 2)]:
        v = int(views[b])
        s = v // 2  # two views per shape
        row, target = int(rows[b, i]), int(targets[b, j])
        source_vertex = int(arrays["sources"][s, row])
        d_raw = float(arrays["distances"][s, row, target])
        scale = float(tables.scale[v])
        euclid = float(np.linalg.norm(canonical[v, source_vertex] - canonical[v, target]))
        expected = max(TARGET_SCALE * (scale * d_raw - euclid), 0.0)
        assert float(batch.target[b, i, j]) == pytest.approx(expected, rel=1e-5, abs=1e-6)
        assert float(batch.geodesic[b, i, j]) == pytest.approx(scale * d_raw, rel=1e-6)
        np.testing.assert_array_equal(batch.points[b, i].numpy(), canonical[v, source_vertex])
        np.testing.assert_array_equal(batch.points[b, 4 + j].numpy(), canonical[v, target])


def test_validation_pairs_are_fixed(tables_and_arrays):
    tables, _ = tables_and_arrays
    first, second = validation_pairs(tables, 3, 7, 5), validation_pairs(tables, 3, 7, 5)
    assert torch.equal(first.rows, second.rows) and torch.equal(first.targets, second.targets)
    assert first.rows.shape == (tables.n_views, 3) and first.n_pairs == tables.n_views * 21


def test_coordinate_statistics_match_numpy(tables_and_arrays):
    tables, _ = tables_and_arrays
    mean, std = coordinate_statistics(tables)
    points = tables.vertices.numpy().reshape(-1, 3).astype(np.float64)
    np.testing.assert_allclose(mean, points.mean(axis=0), atol=1e-10)
    np.testing.assert_allclose(std, points.std(axis=0), rtol=1e-10)
