"""Clouds drawn from an evaluation mesh and the true geodesics of their edges."""

from __future__ import annotations

import numpy as np
import pytest

from litege_core.evaluation.cloud_edges import (
    CloudInput,
    cloud_input,
    oracle_edges,
    relative_error,
)
from litege_core.evaluation.geodesic import EvalShape


def _strip(x0: float, x1: float, y: float, z: float, n: int = 21) -> tuple[np.ndarray, np.ndarray]:
    """A flat strip of ``2 n`` vertices along x at height ``z`` (two rows, ``y`` and ``y + 0.1``)
    and its triangles."""
    x = np.linspace(x0, x1, n)
    vertices = np.concatenate(
        [
            np.column_stack([x, np.full(n, y), np.full(n, z)]),
            np.column_stack([x, np.full(n, y + 0.1), np.full(n, z)]),
        ]
    )
    faces = [(i, i + 1, n + i) for i in range(n - 1)] + [
        (i + 1, n + i + 1, n + i) for i in range(n - 1)
    ]
    return vertices, np.asarray(faces)


def test_route_geodesics_follow_the_surface_around_a_fold() -> None:
    # two strips 0.02 apart in z, joined along x = 1 by a vertical strip: a hairpin
    low, low_faces = _strip(0.0, 1.0, 0.0, 0.0)
    high, high_faces = _strip(0.0, 1.0, 0.0, 0.02)
    n = low.shape[0]
    # stitch the far ends: vertices 20, 41 of the low strip to 20, 41 of the high one
    stitch = np.array([[20, 41, n + 20], [41, n + 41, n + 20]])
    vertices = np.concatenate([low, high])
    faces = np.concatenate([low_faces, high_faces + n, stitch])
    shape = EvalShape(
        "hairpin", "test", vertices, faces, np.array([0]), np.zeros((1, len(vertices)))
    )
    # cloud points: the low strip's vertex 0 and the high strip's vertex 0 (above it), on
    # triangles that hold them
    points = vertices[[0, n]]
    point_faces = np.array([0, len(low_faces)])
    cloud = CloudInput(points, point_faces, np.array([0]), np.zeros((1, 2)), points)
    truth = oracle_edges(shape, cloud, reach=10.0)
    geodesic = truth(np.array([0]), np.array([1]))[0]
    assert geodesic == pytest.approx(2.02, abs=0.05)  # out to x = 1, up, and back
    assert truth(np.array([0]), np.array([0]))[0] == pytest.approx(0.0)
    # beyond the reach the route is not measured: infinite
    assert np.isinf(oracle_edges(shape, cloud, reach=0.5)(np.array([0]), np.array([1]))[0])


def test_a_cloud_keeps_the_sources_first_and_their_rows(blob) -> None:
    mesh = blob(2)
    vertices, faces = np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces)
    sources = np.array([0, 7])
    gt = np.linalg.norm(vertices[sources][:, None] - vertices[None], axis=-1)
    shape = EvalShape("blob", "test", vertices, faces, sources, gt)
    cloud = cloud_input(shape, "cloud_300", seed=0)
    assert cloud.points.shape == (300, 3) and cloud.gt.shape == (2, 300)
    np.testing.assert_array_equal(cloud.points[:2], vertices[sources])
    np.testing.assert_array_equal(cloud.sources, [0, 1])
    assert (faces[cloud.faces[:2]] == sources[:, None]).any(axis=1).all()  # on their triangles
    noisy = cloud_input(shape, "noise_0.01", seed=0)
    assert noisy.points.shape == (2000, 3)
    clean = cloud_input(shape, "cloud_2000", seed=0)
    np.testing.assert_array_equal(noisy.faces, clean.faces)  # the same samples, moved
    np.testing.assert_array_equal(noisy.clean, clean.points)  # and kept as they were
    assert cloud.clean is cloud.points  # no noise: the points themselves
    assert 0.005 < np.std(noisy.points - clean.points) < 0.02


def test_relative_error_is_scaled_to_a_mean_of_100() -> None:
    gt = np.array([[10.0, 30.0]])
    assert relative_error(gt * 1.1, gt) == pytest.approx(10.0)
    assert relative_error(gt + 2.0, gt) == pytest.approx(10.0)


def test_the_lower_bound_sits_between_the_chord_and_the_route(blob) -> None:
    mesh = blob(2)
    vertices, faces = np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces)
    sources = np.array([0])
    gt = np.linalg.norm(vertices[sources][:, None] - vertices[None], axis=-1)
    shape = EvalShape("blob", "test", vertices, faces, sources, gt)
    cloud = cloud_input(shape, "cloud_300", seed=0)
    i, j = np.repeat(np.arange(30), 10), np.tile(np.arange(100, 110), 30)
    upper = oracle_edges(shape, cloud, reach=10.0)(i, j)
    lower = oracle_edges(shape, cloud, reach=10.0, bound="lower")(i, j)
    chords = np.linalg.norm(cloud.points[i] - cloud.points[j], axis=1)
    assert np.all(lower >= chords - 1e-12) and np.all(lower <= upper + 1e-6)
    assert np.mean(lower > 1.05 * chords) > 0.5  # far pairs on a curved blob: real detours
    with pytest.raises(ValueError):
        oracle_edges(shape, cloud, reach=1.0, bound="middle")


def test_the_cut_table_reports_recall_precision_and_the_graph_error(toy_fusion) -> None:
    from litege_core.evaluation.cloud_edges import kept_edges, shortcut_cut_table

    _, predictor, shape = toy_fusion
    edges = kept_edges(predictor, shape, "cloud_200")
    edges.shortcut[:] = False
    edges.shortcut[:4] = True
    scores = np.where(edges.shortcut, 0.9, 0.1)  # a perfect scorer
    table = shortcut_cut_table("toy", [edges], [scores], (0.5, 1.0))
    assert table.startswith("**toy**: 1 shapes, 4 shortcuts") and "AUC: scorer 1.000" in table
    assert "| 0.5 | " in table and "| 1.00 | 1.00 |" in table  # recall and precision 1
    assert "| 1 | 0.00 % | 0.00 | 0.00 |" in table  # nothing scores above 1: nothing cut
    uncut = edges.graph_error()
    assert f"graph error {uncut:.2f} uncut" in table
