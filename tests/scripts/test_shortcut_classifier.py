"""scripts/shortcut_classifier.py: edge patches in the edge's own frame, the frame's symmetries,
a scorer that learns a separable rule, and its scores of one shape's kept edges."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from litege_core.evaluation.cloud_edges import kept_edges
from litege_core.metrics import ranking_auc
from tests.scripts.conftest import load_script


@pytest.fixture(scope="module")
def classifier():
    return load_script("shortcut_classifier")


@pytest.fixture
def edges(toy_fusion, classifier):
    _, predictor, shape = toy_fusion
    return kept_edges(predictor, shape, "cloud_200", neighbours=classifier.PATCH)


def test_patches_do_not_move_with_the_cloud(classifier, edges) -> None:
    """A patch is read in its edge's frame: turning and shifting the cloud changes it at most
    by the frame's own symmetries (the sign of the normal axis)."""
    import dataclasses

    from scipy.spatial.transform import Rotation

    which = np.arange(min(50, edges.chord.size))
    patches = classifier.edge_patches(edges, which)
    assert patches.shape == (which.size, 2 * classifier.PATCH, 4)
    assert patches.dtype == np.float32
    assert np.all(patches[:, : classifier.PATCH, 3] == 1.0)
    assert np.all(patches[:, classifier.PATCH :, 3] == -1.0)
    rotation = Rotation.from_euler("xyz", [0.3, -1.1, 2.0]).as_matrix()
    moved = dataclasses.replace(edges, points=edges.points @ rotation.T + 5.0)
    turned = classifier.edge_patches(moved, which)
    np.testing.assert_allclose(turned[:, :, 0], patches[:, :, 0], atol=1e-4)  # along the chord
    np.testing.assert_allclose(np.abs(turned[:, :, 1:3]), np.abs(patches[:, :, 1:3]), atol=1e-4)
    radius = np.linalg.norm(patches[:, :, :3], axis=2) * edges.spacing
    midpoints = 0.5 * (edges.points[edges.i[which]] + edges.points[edges.j[which]])
    patch = classifier.PATCH
    around = np.concatenate(
        [edges.nearest[edges.i[which], :patch], edges.nearest[edges.j[which], :patch]], 1
    )
    expected = np.linalg.norm(edges.points[around] - midpoints[:, None], axis=2)
    np.testing.assert_allclose(radius, expected, rtol=1e-4, atol=1e-6)  # distances kept


def test_the_frames_symmetries_are_half_turns(classifier) -> None:
    patches = torch.randn(400, 8, 4)
    out = classifier.turned(patches, torch.Generator().manual_seed(0))
    np.testing.assert_allclose(out[:, :, :3].norm(dim=2), patches[:, :, :3].norm(dim=2))
    changed = (out != patches).any(dim=2).any(dim=1)
    assert 0.5 < changed.float().mean() < 0.95  # three of four draws turn a patch
    determinant = torch.linalg.det(torch.linalg.lstsq(patches[0, :, :3], out[0, :, :3]).solution)
    assert determinant == pytest.approx(1.0, abs=1e-4)  # a rotation, never a mirror


def test_the_scorer_learns_a_separable_rule(classifier) -> None:
    """Shortcuts marked by a second sheet of points above the chord: the scorer ranks them."""
    rng = np.random.default_rng(0)
    count, points = 600, 2 * classifier.PATCH
    patches = rng.normal(size=(count, points, 4)).astype(np.float32)
    patches[:, :, 2] *= 0.05  # flat patches
    labels = rng.random(count) < 0.3
    patches[labels, ::2, 2] += 1.0  # half their points one spacing off the plane
    patches[:, :, 3] = np.repeat([1.0, -1.0], classifier.PATCH)
    features = rng.normal(size=(count, classifier.N_EXTRA)).astype(np.float32)
    model = classifier.train_scorer(
        torch.from_numpy(patches),
        torch.from_numpy(features),
        torch.from_numpy(labels.astype(np.float32)),
        steps=150,
        negatives=1.0,
        width=16,
        batch=128,
        log_every=0,
    )
    with torch.no_grad():
        logits = model(torch.from_numpy(patches), torch.from_numpy(features)).numpy()
    assert ranking_auc(logits, labels) > 0.95


def test_scores_of_one_shapes_kept_edges(classifier, edges) -> None:
    model = classifier.PatchScorer(width=8).eval()
    scores = classifier.shortcut_scores(model, edges, block=64)
    assert scores.shape == edges.chord.shape and np.all((scores >= 0) & (scores <= 1))
    blocked = classifier.shortcut_scores(model, edges, block=edges.chord.size)
    np.testing.assert_allclose(scores, blocked, rtol=1e-5, atol=1e-6)
