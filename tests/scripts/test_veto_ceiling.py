"""scripts/veto_ceiling.py: the mean-normal cut, the best blend, the extra ratios."""

from __future__ import annotations

import numpy as np
import pytest

from tests.scripts.conftest import load_script


@pytest.fixture(scope="module")
def veto_ceiling():
    return load_script("veto_ceiling")


def test_the_mean_normal_cut_flags_chords_between_sheets_only(veto_ceiling) -> None:
    points = np.array([[0.0, 0, 0], [0.1, 0, 0], [0.0, 0, 0.05], [0.1, 0.0, 0.0]])
    normals = np.array([[0.0, 0, 1], [0.0, 0, -1], [0.0, 0, 1], [0.0, 0.6, 0.8]])
    cut = veto_ceiling.facing_cut(points, normals, 0.5)
    # along the sheet (normals opposite in sign but the same line): kept; across: cut
    assert cut(np.array([0, 0]), np.array([1, 2])).tolist() == [False, True]
    # a tilted pair on an arc: the chord is perpendicular to the mean normal only roughly
    assert not cut(np.array([0]), np.array([3]))[0]


def test_best_weight_error_finds_the_blend_that_cancels_opposite_errors(veto_ceiling) -> None:
    gt = np.array([[10.0, 20.0, 30.0]])
    network, graph = gt * 0.9, gt * 1.1  # −10 % and +10 %: the half-half blend is exact
    assert veto_ceiling.best_weight_error(network, graph, gt) == pytest.approx(0.0, abs=1e-9)
    # one estimator exact: its own weight wins; both short: the less short one alone
    assert veto_ceiling.best_weight_error(gt, graph, gt) == pytest.approx(0.0, abs=1e-9)
    assert veto_ceiling.best_weight_error(network, gt * 0.8, gt) == pytest.approx(10.0)


def test_extra_oracle_and_veto_ratios_reproduce_the_base_variants(
    veto_ceiling, toy_fusion, monkeypatch
) -> None:
    """``oracle R`` at the oracle's own ratio is the oracle, ``net veto R`` at the calibration's
    ratio is the shipped graph."""
    from litege_core.learned import Predictor

    bundle, predictor, shape = toy_fusion
    network_only = Predictor(bundle, fusion="none")
    monkeypatch.setattr(veto_ceiling, "EXTRA_RATIOS", [3.0])
    monkeypatch.setattr(veto_ceiling, "PRUNE_RATIOS", [1.6, 1.05])
    out, _ = veto_ceiling.evaluate_shape(predictor, network_only, shape, "cloud_200", 3.0)
    assert out["oracle 3.0"] == pytest.approx(out["oracle"])
    assert out["net veto 1.6"] == pytest.approx(out["shipped"])
    assert set(out) >= {"net veto 1.05", "no veto", "network"}
