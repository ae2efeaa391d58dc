"""Training the cloud graph's shortcut scorer (``litege_core.train.shortcuts``): the examples
drawn from kept edges, and a short run that learns to tell touching sheets apart."""

from __future__ import annotations

import numpy as np
import torch

from litege_core.engines.graph import knn_graph, knn_neighbours
from litege_core.evaluation.cloud_edges import kept_edges
from litege_core.learned.cloud_surface import local_surface
from litege_core.learned.shortcuts import (
    cloud_spacing,
    edge_inputs,
    neighbour_inputs,
    shortcut_probabilities,
)
from litege_core.metrics import ranking_auc
from litege_core.train.shortcuts import (
    ScorerExamples,
    ShortcutScorer,
    scorer_examples,
    train_shortcut_scorer,
)
from tests.litege_core.learned.test_shortcuts import _two_sheets


def test_examples_keep_every_shortcut_and_a_share_of_the_rest(toy_fusion) -> None:
    _, predictor, shape = toy_fusion
    clouds = [kept_edges(predictor, shape, "cloud_200", seed=s) for s in (0, 1)]
    for cloud in clouds:  # the toy blob's rows are Euclidean: label a few edges by hand
        cloud.shortcut[:] = False
        cloud.shortcut[:5] = True
    examples = scorer_examples(clouds, negatives=0.5, seed=0)
    n_points = sum(c.points.shape[0] for c in clouds)
    assert examples.inputs.shape == (n_points, 16, 3)
    assert int(examples.labels.sum()) == 10
    drawn = [round(0.5 * int((~c.shortcut).sum())) for c in clouds]
    assert examples.labels.shape[0] == 10 + sum(drawn)
    # the second cloud's ends index its own rows, after the first cloud's
    first = clouds[0].points.shape[0]
    second = 5 + drawn[0]
    assert int(examples.i[:second].max()) < first <= int(examples.i[second:].min())
    again = scorer_examples(clouds, negatives=0.5, seed=0)
    torch.testing.assert_close(again.i, examples.i)


def test_trained_scorer_cuts_the_edges_between_touching_sheets() -> None:
    """Trained a few hundred steps on two touching sheets, the scorer ranks the edges between
    them above the edges within a sheet."""
    points = _two_sheets(n=14, gap=0.05)
    lengths, nearest = knn_neighbours(points, 24)
    flatness, normals = local_surface(points, nearest=nearest)
    graph = knn_graph(points, 10, (lengths, nearest)).tocoo()
    i, j = graph.row.astype(np.int64), graph.col.astype(np.int64)
    half = points.shape[0] // 2
    labels = ((i < half) != (j < half)).astype(np.float32)
    spacing = cloud_spacing(lengths)
    side_i, side_j, features = edge_inputs(points, normals, flatness, spacing, i, j)
    inputs = neighbour_inputs(points, nearest[:, 1:17], normals, spacing, np.arange(len(points)))
    examples = ScorerExamples(
        *(torch.from_numpy(a) for a in (inputs, i, j, side_i, side_j, features, labels)),
        negatives=1.0,
    )
    trained = train_shortcut_scorer(examples, steps=300, width=8, batch=128, log_every=0)
    scores = shortcut_probabilities(
        trained.weights(), points, nearest[:, 1:], spacing, normals, flatness, i, j
    )
    assert ranking_auc(scores, labels.astype(bool)) > 0.9


def test_the_numpy_scorer_computes_what_the_torch_module_trains() -> None:
    points = _two_sheets(n=10)
    lengths, nearest = knn_neighbours(points, 24)
    flatness, normals = local_surface(points, nearest=nearest)
    graph = knn_graph(points, 8, (lengths, nearest)).tocoo()
    i, j = graph.row.astype(np.int64), graph.col.astype(np.int64)
    spacing = cloud_spacing(lengths)
    torch.manual_seed(1)
    module = ShortcutScorer(width=8, neighbours=12).eval()
    weights = module.weights()
    rows = np.arange(len(points))
    inputs = neighbour_inputs(points, nearest[:, 1:13], normals, spacing, rows)
    side_i, side_j, features = edge_inputs(points, normals, flatness, spacing, i, j)
    with torch.no_grad():
        embedded = module.embed(torch.from_numpy(inputs))
        logits = module.logits(
            embedded, *(torch.from_numpy(a) for a in (i, j, side_i, side_j, features))
        )
    np.testing.assert_allclose(weights.embed(inputs), embedded.numpy(), rtol=1e-4, atol=1e-5)
    expected = torch.sigmoid(logits).numpy()
    scores = shortcut_probabilities(
        weights, points, nearest[:, 1:], spacing, normals, flatness, i, j
    )
    np.testing.assert_allclose(scores, expected, rtol=1e-4, atol=1e-6)
