"""scripts/eval_paths.py: the classical path lengths it compares LiteGE's paths with."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from tests.scripts.conftest import load_script


@pytest.fixture(scope="module")
def eval_paths():
    return load_script("eval_paths")


def test_polyline_length(eval_paths) -> None:
    points = np.array([[0.0, 0.0, 0.0], [3.0, 4.0, 0.0], [3.0, 4.0, 2.0]])
    assert eval_paths.polyline_length(points) == pytest.approx(7.0)
    assert eval_paths.polyline_length(points[:1]) == 0.0


def test_edge_flip_lengths_are_the_sphere_geodesics(eval_paths) -> None:
    pytest.importorskip("potpourri3d")
    sphere = trimesh.creation.icosphere(subdivisions=4)
    vertices, faces = np.asarray(sphere.vertices), np.asarray(sphere.faces)
    sources, targets = np.array([0, 5, 7]), np.array([100, 5, 600])
    lengths, seconds = eval_paths.edge_flip_lengths(vertices, faces, sources, targets)
    great_circle = np.arccos(np.clip(np.sum(vertices[sources] * vertices[targets], 1), -1, 1))
    assert lengths[1] == 0.0  # a point to itself
    np.testing.assert_allclose(lengths, great_circle, rtol=0.02, atol=1e-12)
    assert seconds >= 0.0


def test_knn_path_lengths_are_the_graph_distances(eval_paths) -> None:
    # points along a line: the 10-NN graph's shortest path is the straight distance
    points = np.column_stack([np.linspace(0.0, 1.0, 50), np.zeros(50), np.zeros(50)])
    lengths, _ = eval_paths.knn_path_lengths(points, np.array([0, 10]), np.array([49, 10]))
    np.testing.assert_allclose(lengths, [1.0, 0.0], atol=1e-12)
