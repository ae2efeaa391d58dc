"""scripts/shortcut_edges.py: the orientation of the normals, one shape's kept edges."""

from __future__ import annotations

import numpy as np
import pytest

from tests.scripts.conftest import load_script


@pytest.fixture(scope="module")
def shortcut_edges():
    return load_script("shortcut_edges")


def test_normals_of_a_sphere_are_oriented_one_way(shortcut_edges) -> None:
    from litege_core.engines.graph import knn_neighbours

    rng = np.random.default_rng(0)
    points = rng.normal(size=(800, 3))
    points /= np.linalg.norm(points, axis=1, keepdims=True)
    normals = points * rng.choice([-1.0, 1.0], size=(800, 1))  # unoriented: random signs
    signs = shortcut_edges.oriented_signs(points, normals, knn_neighbours(points, 16)[1][:, 1:])
    outward = np.einsum("ij,ij->i", signs[:, None] * normals, points)
    assert np.all(outward > 0) or np.all(outward < 0)


def test_one_shapes_kept_edges_and_their_errors(shortcut_edges, toy_fusion) -> None:
    _, predictor, shape = toy_fusion
    result = shortcut_edges.shape_edges(predictor, shape, "cloud_200", 3.0, frustration=True)
    n_edges = result.shortcut.size
    assert n_edges > 200 and result.features.shape == (n_edges, len(shortcut_edges.FEATURES))
    assert result.frustrated is not None and result.frustrated.shape == (n_edges,)
    assert set(result.errors) == {"shipped", "oracle", "frustration"}
    assert all(np.isfinite(v) and v >= 0 for v in result.errors.values())
    assert result.counts.sum() == 2 * result.shortcut.sum()
    assert np.all(result.features[:, 0] > 0)  # chords over the spacing


def test_beyond_the_ood_limit_the_graph_keeps_every_candidate_edge(
    shortcut_edges, toy_fusion
) -> None:
    import dataclasses

    from litege_core.learned import Predictor

    bundle, predictor, shape = toy_fusion
    strict = dataclasses.replace(predictor.fusion, prune_ratio=1.0)  # the veto cuts a lot
    vetoed = shortcut_edges.shape_edges(
        Predictor(bundle, fusion=strict), shape, "cloud_200", 3.0, frustration=False
    )
    off = dataclasses.replace(strict, veto_max_z=-1e9)  # every shape beyond the limit
    unvetoed = shortcut_edges.shape_edges(
        Predictor(bundle, fusion=off), shape, "cloud_200", 3.0, frustration=False
    )
    assert unvetoed.shortcut.size > vetoed.shortcut.size
    assert unvetoed.frustrated is None and set(unvetoed.errors) == {"shipped", "oracle"}
