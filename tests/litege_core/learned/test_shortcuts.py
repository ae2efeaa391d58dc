"""The learned shortcut scorer of a cloud graph: its inputs, the batched scores against the
one-edge-at-a-time reference, its symmetries, the cut, and the scorer file."""

from __future__ import annotations

import json

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from litege_core.engines.graph import knn_graph, knn_neighbours
from litege_core.errors import ArtifactError, InputError
from litege_core.learned.cloud_surface import local_surface
from litege_core.learned.shortcuts import (
    SCORER_CONFIG,
    SCORER_WEIGHTS,
    SHIPPED_SCORER_DIR,
    ScorerWeights,
    cloud_spacing,
    cut_shortcuts,
    load_shortcut_scorer,
    neighbour_inputs,
    save_shortcut_scorer,
    shortcut_probabilities,
    shortcut_probabilities_reference,
)
from tests.litege_core.learned.conftest import scorer_state


def _two_sheets(n: int = 12, gap: float = 0.06, seed: int = 0) -> np.ndarray:
    """Two parallel jittered grids ``gap`` apart in z (parts that touch): ``(2 n², 3)``."""
    rng = np.random.default_rng(seed)
    x, y = np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n))
    sheet = np.column_stack([x.ravel(), y.ravel(), np.zeros(n * n)])
    sheet[:, :2] += rng.normal(0, 0.01, (n * n, 2))
    other = sheet + np.array([0.0, 0.0, gap])
    return np.concatenate([sheet, other])


@pytest.fixture
def cloud():
    points = _two_sheets()
    lengths, nearest = knn_neighbours(points, 24)
    flatness, normals = local_surface(points, nearest=nearest)
    return points, (lengths, nearest), normals, flatness


@pytest.fixture
def scorer() -> ScorerWeights:
    return ScorerWeights.from_state(scorer_state(width=8), neighbours=6)


def test_neighbour_inputs_read_the_tangent_frame(cloud) -> None:
    points, (lengths, nearest), normals, _ = cloud
    spacing = cloud_spacing(lengths)
    rows = np.array([0, 5, 200])
    inputs = neighbour_inputs(points, nearest[:, 1:7], normals, spacing, rows)
    assert inputs.shape == (3, 6, 3) and inputs.dtype == np.float32
    offsets = (points[nearest[rows, 1:7]] - points[rows, None]) / spacing
    np.testing.assert_allclose(
        inputs[..., 0] ** 2 + inputs[..., 1] ** 2, (offsets**2).sum(-1), rtol=1e-4
    )
    assert np.all(inputs[..., 2] <= 1.0 + 1e-6) and np.all(inputs[..., 0] >= 0)


def test_batched_scores_match_the_reference_and_are_symmetric(cloud, scorer) -> None:
    points, (lengths, nearest), normals, flatness = cloud
    graph = knn_graph(points, 8, (lengths, nearest)).tocoo()
    i, j = graph.row.astype(np.int64), graph.col.astype(np.int64)
    spacing = cloud_spacing(lengths)
    args = (points, nearest[:, 1:], spacing, normals, flatness)
    fast = shortcut_probabilities(scorer, *args, i, j)
    assert fast.shape == i.shape and np.all((fast > 0) & (fast < 1))
    which = np.arange(0, i.size, 7)
    slow = shortcut_probabilities_reference(scorer, *args, i[which], j[which])
    np.testing.assert_allclose(fast[which], slow, rtol=1e-4, atol=1e-6)
    assert which.size < points.shape[0] <= i.size  # a few edges embed only their ends
    few = shortcut_probabilities(scorer, *args, i[which], j[which])
    np.testing.assert_allclose(few, fast[which], rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(shortcut_probabilities(scorer, *args, j, i), fast, atol=1e-6)
    flipped = shortcut_probabilities(
        scorer, points, nearest[:, 1:], spacing, -normals, flatness, i, j
    )
    np.testing.assert_allclose(flipped, fast, atol=1e-6)  # the normal's sign is read both ways
    moved = points @ np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]).T * 3.0
    turned_normals = normals @ np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]).T
    again = shortcut_probabilities(
        scorer, moved, nearest[:, 1:], spacing * 3.0, turned_normals, flatness, i, j
    )
    np.testing.assert_allclose(again, fast, atol=1e-5)  # turned and scaled: the same scores


def test_cut_drops_the_edges_scored_above_the_threshold(cloud, scorer) -> None:
    points, neighbours, normals, flatness = cloud
    graph = knn_graph(points, 8, neighbours)
    rows = np.repeat(np.arange(graph.shape[0]), np.diff(graph.indptr))
    scores = shortcut_probabilities(
        scorer, points, neighbours[1][:, 1:], cloud_spacing(neighbours[0]), normals, flatness,
        rows, graph.indices.astype(np.int64),
    )  # fmt: skip
    threshold = float(np.median(scores))
    cut = cut_shortcuts(graph, points, neighbours, normals, flatness, threshold, scorer)
    assert isinstance(cut, sp.csr_array) and cut.shape == graph.shape
    kept = set(zip(np.repeat(np.arange(cut.shape[0]), np.diff(cut.indptr)).tolist(),
                   cut.indices.tolist(), strict=True))  # fmt: skip
    below = {(a, b) for a, b, s in zip(rows.tolist(), graph.indices.tolist(), scores,
                                       strict=True) if s <= threshold}  # fmt: skip
    assert below <= kept and len(kept) < graph.nnz  # every edge below the threshold stays
    # the edges above it that stay rejoin what the cut split: a forest, one edge per merge
    strict = sp.csr_array(
        (np.ones(len(below)), tuple(np.array(sorted(below)).T)), shape=graph.shape
    )
    split = connected_components(strict, directed=False)[0]
    whole = connected_components(graph, directed=False)[0]
    assert connected_components(cut, directed=False)[0] == whole
    assert split > whole and len(kept) - len(below) == split - whole
    assert cut_shortcuts(graph, points, neighbours, normals, flatness, 1.0, scorer) is graph
    few = (neighbours[0][:, :5], neighbours[1][:, :5])  # searched again where too few
    again = cut_shortcuts(graph, points, few, normals, flatness, threshold, scorer)
    assert again.nnz == cut.nnz


def test_scorer_file_round_trip_and_checks(tmp_path) -> None:
    state = scorer_state(width=8)
    config = save_shortcut_scorer(tmp_path, state, neighbours=6, training={"steps": 0})
    assert config["scorer"] == {"width": 8, "neighbours": 6}
    loaded = load_shortcut_scorer(tmp_path, sha256=config["weights_sha256"])
    assert loaded.neighbours == 6 and loaded.width == 8
    np.testing.assert_array_equal(loaded.point_2, state["point.2.weight"])
    np.testing.assert_array_equal(loaded.head_2_bias, state["head.3.bias"])
    with pytest.raises(InputError, match="fit the fusion again"):
        load_shortcut_scorer(tmp_path, sha256="0" * 64)
    with pytest.raises(InputError, match="no shortcut scorer"):
        load_shortcut_scorer(tmp_path / "missing")
    with pytest.raises(InputError, match="not finite"):
        save_shortcut_scorer(tmp_path / "nan", {**state, "edge.bias": state["edge.bias"] * np.nan})
    with pytest.raises(ArtifactError, match="ends"):
        ScorerWeights.from_state({**state, "ends.weight": np.zeros((3, 3), np.float32)})
    with pytest.raises(ArtifactError, match="inconsistent"):
        ScorerWeights.from_state({k: v for k, v in state.items() if k != "edge.weight"})
    damaged = tmp_path / "damaged"
    save_shortcut_scorer(damaged, state)
    data = json.loads((damaged / SCORER_CONFIG).read_text())
    data["weights_sha256"] = "f" * 64
    (damaged / SCORER_CONFIG).write_text(json.dumps(data))
    with pytest.raises(ArtifactError, match="does not match"):
        load_shortcut_scorer(damaged)


def test_the_shipped_scorer_loads() -> None:
    if not (SHIPPED_SCORER_DIR / SCORER_WEIGHTS).is_file():
        pytest.skip("no shortcut scorer shipped")
    scorer = load_shortcut_scorer()
    assert isinstance(scorer, ScorerWeights) and not scorer.point_2.flags.writeable
