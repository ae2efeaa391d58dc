"""scripts/signed_error.py: the error split by geodesic / Euclidean ratio, and by class."""

from __future__ import annotations

import dataclasses

import numpy as np

from litege_core.evaluation.geodesic import EvalShape


class StraightLinePredictor:
    """Predicts the Euclidean distance: right on straight paths, short on winding ones."""

    def register(self, shape):
        return shape

    def distances(self, state, sources):
        points = state.points
        return np.linalg.norm(points[sources][:, None] - points[None], axis=2)


def strip_shape(name: str) -> EvalShape:
    """Points on a line with a 'geodesic' 1× the Euclidean distance up to x = 1, 2.5× past it."""
    x = np.linspace(0.0, 2.0, 21)
    vertices = np.stack([x, 0 * x, 0 * x], 1)
    faces = np.array([[0, 1, 2]])
    euclid = np.abs(x[[0, 10]][:, None] - x[None])
    gt = np.where(x[None] > 1.0, 2.5 * euclid, euclid)
    return EvalShape(name, "toy (real)", vertices, faces, np.array([0, 10]), gt)


def test_ratio_rows_put_the_shortfall_in_the_winding_bins(signed_error, monkeypatch) -> None:
    monkeypatch.setattr(
        signed_error.Shape, "from_arrays", lambda v, f: type("S", (), {"points": v})
    )
    rows = signed_error.ratio_rows(StraightLinePredictor(), [strip_shape("cat0")])
    shares = np.array([share for share, _, _ in rows])
    assert np.isclose(shares.sum(), 1.0)
    straight, winding = rows[0], rows[-1]  # ratio 1 and ratio 2.5
    assert straight[0] > 0 and np.isclose(straight[1], 0.0) and np.isclose(straight[2], 0.0)
    assert winding[0] > 0 and winding[1] < 0 and np.isclose(winding[2], -winding[1])
    assert all(np.isnan(signed) for share, signed, _ in rows[1:-1] if share == 0)


def test_by_class_splits_a_real_set_by_the_names_without_digits(signed_error) -> None:
    shapes = [strip_shape(name) for name in ("cat0", "cat10", "dog2")]
    split = signed_error.by_class("toy (real)", shapes)
    assert list(split) == ["toy (real)", "toy (real): cat (2)", "toy (real): dog (1)"]
    assert [s.name for s in split["toy (real): cat (2)"]] == ["cat0", "cat10"]
    assert list(signed_error.by_class("synthetic", shapes)) == ["synthetic"]


def test_fit_stretch_recovers_an_affine_detour_and_stretched_error_applies_it(signed_error) -> None:
    rng = np.random.default_rng(0)
    euclid = rng.uniform(1.0, 50.0, size=(3, 40))
    predicted = euclid + rng.uniform(0.0, 20.0, size=(3, 40))
    true = euclid + 2.0 + 1.5 * (predicted - euclid)
    pairs = [(euclid, predicted, true)]
    alpha, beta = signed_error.fit_stretch(pairs)
    assert np.isclose(alpha, 2.0) and np.isclose(beta, 1.5)
    assert np.isclose(signed_error.stretched_error(pairs, alpha, beta), 0.0)
    assert signed_error.stretched_error(pairs, 0.0, 1.0) > 1.0


def test_graph_row_reads_the_graph_as_the_fusion_does(signed_error) -> None:
    from litege_core.evaluation.fusion import FusionSample, probe_calibration

    truth = np.array([[0.0, 100.0, 200.0, 300.0]])  # GT mean 150
    network = np.array([[0.0, 90.0, 180.0, 300.0]])
    graph = np.array([[0.0, 100.0, 120.0, np.inf]]) * 1.1  # the graph's bias 1.1, one pair cut
    calibration = dataclasses.replace(probe_calibration("h" * 64, 8, 1.5), bias=(1.1,))
    sample = FusionSample("cat0", "toy", "cloud_300", False, 300, 0.0, 0.1, network, graph, truth)
    absolute, signed = signed_error.graph_row([sample, sample], calibration)
    # after the bias: errors 0, 0, −80 and the network's 0 where the graph is cut
    assert np.isclose(signed, -80.0 / 4 / 1.5) and np.isclose(absolute, 80.0 / 4 / 1.5)


def test_the_graph_table_reads_the_calibrations_own_graph(
    signed_error, blob, toy_bundle_dir_with_ood, tmp_path, capsys
) -> None:
    """``--graph-limits``: one row per setting, one cell per limit, on the calibration's
    mutual k-NN graph (the samples are keyed by its neighbour rule too)."""
    import argparse
    import shutil

    from litege_core.engines import compute_distances
    from litege_core.evaluation.fusion import probe_calibration
    from litege_core.evaluation.geodesic import unit_area
    from litege_core.learned import Predictor, load_bundle
    from litege_core.learned.fusion_calibration import save_fusion
    from litege_core.sampling import farthest_point_sampling
    from litege_core.shape import Shape

    directory = tmp_path / "toy"
    shutil.copytree(toy_bundle_dir_with_ood, directory)
    bundle = load_bundle(directory)
    save_fusion(directory, probe_calibration(bundle.content_hash, 8, 1.5, mutual_k=12))
    shape = blob(7, subdivisions=3)
    vertices, _ = unit_area(shape.vertices, shape.faces)
    sources = farthest_point_sampling(vertices, 3)
    gt = compute_distances(Shape.from_arrays(vertices, shape.faces), sources, "exact").distances
    shapes = [EvalShape("blob0", "toy", vertices, np.asarray(shape.faces), sources, gt)]
    args = argparse.Namespace(model=str(directory), graph_limits="1,0.5", settings="mesh,cloud_300")
    signed_error.print_graph_table(Predictor(load_bundle(directory)), {"toy": shapes}, args)
    table = capsys.readouterr().out
    row = next(line for line in table.splitlines() if line.startswith("| toy | cloud_300 |"))
    cells = row.strip("|").split("|")[2:]
    assert len(cells) == 2
    for cell in cells:  # "mean |error| / mean signed error"
        absolute, signed = (float(v) for v in cell.split("/"))
        assert absolute >= abs(signed) >= 0.0 and np.isfinite(absolute)
