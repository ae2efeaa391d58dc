"""The graph fusion's calibration (issue 14): its checks, its gate, biases and limits, and the
``fusion.json`` sidecar beside a bundle."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from litege_core.errors import ArtifactError, InputError
from litege_core.learned.fusion_calibration import (
    FUSION_CONFIG,
    FusionCalibration,
    load_fusion,
    save_fusion,
)
from tests.litege_core.learned.conftest import toy_calibration as _calibration


@pytest.mark.parametrize(
    "changes",
    [
        {"k": 0},
        {"prune_ratio": 0.9},
        {"prune_ratio": float("nan")},
        {"bias_log10_points": (3.0, 2.5, 3.5)},
        {"bias": (1.0, 1.0)},
        {"bias": (1.0, -1.0, 1.0)},
        {"gate": (0.0, float("inf"), 0.0, 0.0)},
        {"gate": (0.0, 1.0, 0.0)},
        {"mesh_bias": 0.0},
        {"mesh_bias": float("nan")},
        {"veto_head": "tiny"},
        {"normal_cos": (0.7, 0.8)},
        {"normal_cos": (0.7, 0.0, 0.8)},
        {"normal_cos": (0.7, 1.2, 0.8)},
        {"mutual_k": -1},
        {"mutual_k": 1.5},
        {"veto_max_z": float("inf")},
        {"veto_max_z": float("nan")},
        {"mesh_noise_knots": (0.02, 0.1), "mesh_noise_bias": (1.01,)},
        {"mesh_noise_knots": (0.1, 0.02), "mesh_noise_bias": (1.01, 1.02)},
        {"mesh_noise_knots": (0.02, 0.1), "mesh_noise_bias": (1.01, 0.0)},
        {"mesh_noise_knots": (0.02, float("inf")), "mesh_noise_bias": (1.01, 1.02)},
        {"mesh_cloud_noise": 0.0},
        {"mesh_cloud_noise": float("nan")},
        {"mesh_smooth_noise": -0.1},
        {"mesh_smooth_noise": float("inf")},
        {"mesh_smooth_noise": 0.08, "mesh_cloud_noise": 0.3},
        {"shortcut_cut": (0.3, 0.3, 0.3)},  # no scorer named
        {"shortcut_cut": (0.3, 0.3), "shortcut_scorer": "s" * 64},
        {"shortcut_cut": (0.3, 0.0, 1.0), "shortcut_scorer": "s" * 64},
        {"shortcut_cut": (0.3, 1.5, 1.0), "shortcut_scorer": "s" * 64},
        {"shortcut_max_roughness": 0.0},
        {"shortcut_max_roughness": float("nan")},
    ],
)
def test_inconsistent_calibrations_are_refused(changes) -> None:
    with pytest.raises(ArtifactError):
        _calibration(**changes)


def test_bias_interpolates_in_log_points_and_clamps() -> None:
    calibration = _calibration()
    assert calibration.graph_bias(1000) == pytest.approx(1.01)
    assert calibration.graph_bias(10**3.25) == pytest.approx(1.015)
    assert calibration.graph_bias(50) == pytest.approx(0.98)
    assert calibration.graph_bias(10**6) == pytest.approx(1.02)


def test_normal_limit_interpolates_in_log_points_and_defaults_to_none() -> None:
    assert _calibration().normal_limit(1000) == 1.0
    calibration = _calibration(normal_cos=(0.9, 0.7, 0.6))
    assert calibration.normal_limit(1000) == pytest.approx(0.7)
    assert calibration.normal_limit(10**3.25) == pytest.approx(0.65)
    assert calibration.normal_limit(50) == pytest.approx(0.9)


def test_the_veto_runs_up_to_its_ood_limit() -> None:
    assert all(_calibration().vetoes(z) for z in (-3.0, 0.0, 50.0))  # no limit: every cloud
    limited = _calibration(veto_max_z=2.0)
    assert limited.vetoes(-1.0) and limited.vetoes(2.0)
    assert not limited.vetoes(2.01) and not limited.vetoes(float("nan"))


def test_shortcut_cut_interpolates_in_log_points_up_to_its_roughness_limit() -> None:
    calibration = _calibration()
    assert calibration.shortcut_limit(2000, 0.1) == 1.0  # no scorer: no cut
    knots = calibration.bias_log10_points
    cutting = dataclasses.replace(
        calibration, shortcut_cut=(1.0,) + (0.3,) * (len(knots) - 1), shortcut_scorer="s" * 64
    )
    assert cutting.shortcut_limit(10, 0.9) == 1.0  # below the first knot: its value
    assert cutting.shortcut_limit(10**6, 0.9) == pytest.approx(0.3)
    middle = 10 ** ((knots[0] + knots[1]) / 2)
    assert cutting.shortcut_limit(round(middle), 0.1) == pytest.approx(0.65, abs=0.01)
    limited = dataclasses.replace(cutting, shortcut_max_roughness=0.25)
    assert limited.shortcut_limit(10**6, 0.25) == pytest.approx(0.3)
    assert limited.shortcut_limit(10**6, 0.26) == 1.0


def test_network_weight_is_the_gate_sigmoid() -> None:
    calibration = _calibration()
    assert calibration.network_weight(0.0, 1000, 0.0) == pytest.approx(1 / (1 + np.exp(-0.5)))
    assert calibration.network_weight(0.0, 1000, 0.1) == pytest.approx(1 / (1 + np.exp(0.5)))
    # the gate here trusts the network less on unusual shapes, dense and rough clouds
    assert calibration.network_weight(3.0, 1000, 0.1) < calibration.network_weight(0.0, 1000, 0.1)
    assert calibration.network_weight(0.0, 5000, 0.1) < calibration.network_weight(0.0, 300, 0.1)
    assert 0.0 <= calibration.network_weight(1e9, 10**9, 0.1) < 1e-20
    # a mesh is its graph's alone, with its own bias, whatever its z, size and roughness
    for z, n in ((0.0, 300), (5.0, 10**5)):
        assert calibration.network_weight(z, n, 0.3, mesh=True) == 0.0
        assert calibration.graph_bias(n, mesh=True) == 1.04


def test_mesh_bias_follows_the_noise_knots() -> None:
    """Without knots a mesh's bias is ``mesh_bias`` at any noise; with them it is interpolated,
    the first knot's below them, the last segment extended (never down) beyond them; a cloud's
    bias ignores them."""
    plain = _calibration()
    assert plain.graph_bias(5000, mesh=True, noise=0.3) == 1.04
    knotted = _calibration(mesh_noise_knots=(0.02, 0.1, 0.2), mesh_noise_bias=(1.01, 1.02, 1.06))
    assert knotted.graph_bias(5000, mesh=True, noise=0.0) == pytest.approx(1.01)
    assert knotted.graph_bias(5000, mesh=True, noise=0.06) == pytest.approx(1.015)
    assert knotted.graph_bias(5000, mesh=True, noise=0.15) == pytest.approx(1.04)
    assert knotted.graph_bias(5000, mesh=True, noise=0.3) == pytest.approx(1.10)
    falling = _calibration(mesh_noise_knots=(0.02, 0.1), mesh_noise_bias=(1.02, 1.01))
    assert falling.graph_bias(5000, mesh=True, noise=0.5) == pytest.approx(1.01)
    assert knotted.graph_bias(1000, noise=0.3) == plain.graph_bias(1000) == pytest.approx(1.01)


def test_json_roundtrip_and_sidecar(tmp_path) -> None:
    calibration = _calibration("a" * 64)
    assert FusionCalibration.from_json(json.loads(json.dumps(calibration.to_json()))) == (
        calibration
    )
    # a format-4 file (a mesh gate, since dropped) reads as the same calibration
    older = {**calibration.to_json(), "format_version": 4, "mesh_gate": -5.5}
    assert FusionCalibration.from_json(older) == calibration
    assert "mesh_gate" not in calibration.to_json()
    # a format-5 file (no mutual_k) reads as the symmetric k-NN graph; mutual_k round-trips
    del older["mutual_k"]
    assert FusionCalibration.from_json({**older, "format_version": 5}).mutual_k == 0
    mutual = dataclasses.replace(calibration, mutual_k=24)
    assert FusionCalibration.from_json(json.loads(json.dumps(mutual.to_json()))) == mutual
    assert (calibration.reach, mutual.reach) == (calibration.k, 24)  # what the graph searches
    # a format-6 file (no veto_max_z) vetoes every cloud; veto_max_z round-trips
    del older["veto_max_z"]
    assert FusionCalibration.from_json({**older, "format_version": 6}).veto_max_z is None
    limited = dataclasses.replace(calibration, veto_max_z=4.5)
    assert FusionCalibration.from_json(json.loads(json.dumps(limited.to_json()))) == limited
    # a format-7 file (no mesh_arcs) reads as plain chords; mesh_arcs round-trips, as a boolean
    del older["mesh_arcs"]
    assert FusionCalibration.from_json({**older, "format_version": 7}).mesh_arcs is False
    arcs = dataclasses.replace(calibration, mesh_arcs=True)
    assert FusionCalibration.from_json(json.loads(json.dumps(arcs.to_json()))) == arcs
    with pytest.raises(ArtifactError):
        FusionCalibration.from_json({**arcs.to_json(), "mesh_arcs": 1})
    # a format-8 file (no noise knots) reads as one mesh bias; the knots round-trip
    del older["mesh_noise_knots"], older["mesh_noise_bias"]
    assert FusionCalibration.from_json({**older, "format_version": 8}) == calibration
    noisy = dataclasses.replace(
        calibration, mesh_noise_knots=(0.02, 0.1), mesh_noise_bias=(1.01, 1.03)
    )
    assert FusionCalibration.from_json(json.loads(json.dumps(noisy.to_json()))) == noisy
    assert FusionCalibration.from_json(noisy.to_json()).mesh_cloud_noise is None
    limited = dataclasses.replace(noisy, mesh_cloud_noise=0.45)
    assert FusionCalibration.from_json(json.loads(json.dumps(limited.to_json()))) == limited
    assert limited.answers_as_cloud(0.5) and not limited.answers_as_cloud(0.45)
    assert not noisy.answers_as_cloud(10.0)
    # a format-9 file (no smoothing limit) reads as meshes on their own vertices; it round-trips
    del older["mesh_smooth_noise"]
    assert FusionCalibration.from_json({**older, "format_version": 9}) == calibration
    smoothed = dataclasses.replace(noisy, mesh_smooth_noise=0.08)
    assert FusionCalibration.from_json(json.loads(json.dumps(smoothed.to_json()))) == smoothed
    # a format-10 file (no shortcut scorer) reads as no cut; a cut round-trips
    del older["shortcut_cut"], older["shortcut_scorer"], older["shortcut_max_roughness"]
    assert FusionCalibration.from_json({**older, "format_version": 10}) == calibration
    cutting = dataclasses.replace(
        smoothed, shortcut_cut=(1.0, 0.3, 0.2), shortcut_scorer="s" * 64,
        shortcut_max_roughness=0.25,
    )  # fmt: skip
    assert FusionCalibration.from_json(json.loads(json.dumps(cutting.to_json()))) == cutting
    path = save_fusion(tmp_path, calibration)
    assert path.name == FUSION_CONFIG
    loaded = load_fusion(tmp_path, "a" * 64, "toy")
    assert loaded == calibration and loaded.fitted_on == calibration.fitted_on


def test_missing_foreign_and_damaged_sidecars(tmp_path) -> None:
    with pytest.raises(InputError, match="no graph-fusion"):
        load_fusion(tmp_path, "a" * 64, "toy")
    with pytest.raises(InputError, match="no graph-fusion"):
        load_fusion(None, "a" * 64, "toy")
    save_fusion(tmp_path, _calibration("b" * 64))
    with pytest.raises(InputError, match="fitted for bundle"):
        load_fusion(tmp_path, "a" * 64, "toy")
    data = json.loads((tmp_path / FUSION_CONFIG).read_text())
    (tmp_path / FUSION_CONFIG).write_text(json.dumps({**data, "format_version": 99}))
    with pytest.raises(ArtifactError, match="format"):
        load_fusion(tmp_path, "b" * 64, "toy")
    (tmp_path / FUSION_CONFIG).write_text(json.dumps({**data, "bias": [1.0]}))
    with pytest.raises(ArtifactError):
        load_fusion(tmp_path, "b" * 64, "toy")
    (tmp_path / FUSION_CONFIG).write_text("{not json")
    with pytest.raises(ArtifactError, match="JSON"):
        load_fusion(tmp_path, "b" * 64, "toy")
