"""T-Net evaluation: angle statistics and the alignment report against an oracle."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import litege_core.train.tnet.evaluation as tnet_evaluation
from litege_core.nets import TNet
from litege_core.train.tnet import (
    TNetTrainConfig,
    alignment_report,
    angle_statistics,
)


def test_angle_statistics_and_failures() -> None:
    stats = angle_statistics([0.1, 0.7, 0.2, 2.0], threshold=0.66)
    assert stats["n"] == 4 and stats["failures"] == [1, 3] and stats["n_failures"] == 2
    assert stats["max"] == 2.0 and stats["median"] == pytest.approx(0.45)
    assert stats["mean"] == pytest.approx(0.75)


def test_report_against_a_ground_truth_oracle(toy_shapes, monkeypatch) -> None:
    """With a predictor that returns the reference rotations the report sees zero error, and
    the clouds it feeds are the rotated shapes (their spread matches ``verts @ R_gtᵀ``)."""
    train, val = toy_shapes
    settings = TNetTrainConfig().report
    rots = {
        n: Rotation.random(
            n, random_state=np.random.default_rng(settings.rotation_seed)
        ).as_matrix()
        for n in (4, 2)
    }
    # Call order of alignment_report: train (mesh), then val as mesh, cloud500, broken.
    expected = [(train, i, rots[4][i]) for i in range(4)]
    expected += [(val, i, rots[2][i]) for _ in range(3) for i in range(2)]
    calls = iter(expected)

    def oracle(net, cloud):
        shapes, i, R = next(calls)
        # Aligning the cloud with R brings it to the canonical orientation: same principal
        # axes as the canonical mesh vertices (up to sign), so the axis cosines are ~1.
        aligned = (cloud - cloud.mean(axis=0)) @ R
        axes = np.linalg.eigh(np.cov(aligned.T))[1]
        verts = shapes.vertices[i]
        ref = np.linalg.eigh(np.cov((verts - verts.mean(axis=0)).T))[1]
        assert np.abs(np.abs(np.sum(axes * ref, axis=0)) - 1.0).max() < 0.1
        return R

    monkeypatch.setattr(tnet_evaluation, "predict_rotation", oracle)
    report = alignment_report(TNet((8,), ()), train, val, settings)
    for name in ("train", "val", "val_cloud500", "val_broken"):
        assert report[name]["max"] < 1e-6 and report[name]["failures"] == []
    assert next(calls, None) is None
