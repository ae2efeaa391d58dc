"""scripts/frame_report.py: the candidate frames of its oracle column."""

from __future__ import annotations

import dataclasses

import numpy as np
import torch

import litege_core.matching.frame as frame_module
from litege_core.matching import MatchingModel
from litege_core.nets.orientation import OrientationNet
from litege_core.shape import Shape
from litege_core.synth import families, generate_shape


class _PrefersCandidate(OrientationNet):
    def __init__(self, best: int) -> None:
        super().__init__(grid=8, conv_widths=(2,), fc_width=2)
        self.best = best

    def canonical_log_probability(self, points):
        out = torch.full((points.shape[0],), -3.0)
        out[self.best] = -0.1
        return out


def test_candidates_are_the_frames_judged_frames_choose_from(frame_report, monkeypatch):
    tiny = MatchingModel.tiny_random(0)
    model = MatchingModel(dataclasses.replace(tiny.bundle, orientation=_PrefersCandidate(7)))
    generated = generate_shape("quadruped", families("quadruped")[0], 2_000_000)
    shape = Shape.from_arrays(generated.vertices, generated.faces)
    prepared = model.prepare(shape, frames="tnet")
    tnet_frame = prepared.transform.rotation
    agreeing = np.tile(np.eye(3), (1, 24, 1, 1))
    monkeypatch.setattr(frame_module, "tnet_turn_runs", lambda tnet, c: agreeing)
    only = frame_report.candidate_rotations(model, prepared)
    assert len(only) == 1 and np.allclose(only[0], tnet_frame)

    split = agreeing.copy()
    split[0, 5] = np.diag([1.0, -1.0, -1.0])
    monkeypatch.setattr(frame_module, "tnet_turn_runs", lambda tnet, c: split)
    many = frame_report.candidate_rotations(model, prepared)
    assert len(many) == 25 and np.allclose(many[0], tnet_frame)
    for rotation in many:
        np.testing.assert_allclose(rotation @ rotation.T, np.eye(3), atol=1e-9)
        assert np.isclose(np.linalg.det(rotation), 1.0)
    judged = model.prepare(shape, frames="judged")  # keeps candidate 7: principal-axis frame 6
    assert judged.frame == "pca6"
    np.testing.assert_allclose(judged.transform.rotation, many[7], atol=1e-4)


def _random_rotation(seed: int) -> np.ndarray:
    q, r = np.linalg.qr(np.random.default_rng(seed).normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


def test_mirror_residuals_match_a_brute_force_reference(frame_report):
    from scipy.spatial import cKDTree

    points = np.random.default_rng(0).normal(size=(60, 3))
    normals = frame_report.hemisphere(20)
    fast = frame_report.mirror_residuals(points, cKDTree(points), normals)
    for normal, value in zip(normals, fast, strict=True):
        mirrored = points - 2.0 * np.outer(points @ normal, normal)
        nearest = np.linalg.norm(mirrored[:, None] - points[None], axis=2).min(axis=1)
        kept = int(frame_report.SYMMETRY_TRIM * len(points))
        assert np.isclose(value, np.sort(nearest)[:kept].mean())


def test_the_best_symmetry_plane_of_a_mirror_symmetric_cloud_is_found(frame_report):
    rng = np.random.default_rng(1)
    half = rng.normal(size=(400, 3)) * [1.0, 0.6, 2.0] + [0.7, 0.0, 0.0]
    symmetric = np.concatenate([half, half * [-1.0, 1.0, 1.0]])  # mirror plane x = 0
    rotation = _random_rotation(2)
    normals = frame_report.symmetry_normals(symmetric @ rotation.T + [0.3, -1.0, 2.0])
    assert normals.shape == (frame_report.SAGITTAL_PLANES, 3)
    assert abs(normals[0] @ rotation[:, 0]) > np.cos(0.02)  # the rotated x axis, either sign
    assert np.allclose(np.linalg.norm(normals, axis=1), 1.0)


def test_sagittal_rotations_cover_every_frame_with_that_left_right_axis(frame_report):
    target = _random_rotation(3)
    rotations = frame_report.sagittal_rotations(target[0])
    assert rotations.shape == (2 * frame_report.SAGITTAL_TURNS, 3, 3)
    for rotation in rotations:
        np.testing.assert_allclose(rotation @ rotation.T, np.eye(3), atol=1e-12)
        assert np.isclose(np.linalg.det(rotation), 1.0)
        assert np.isclose(abs(rotation[0] @ target[0]), 1.0)
    half_step = np.pi / frame_report.SAGITTAL_TURNS
    for wanted in (target, np.diag([-1.0, 1.0, -1.0]) @ target):  # and its head-to-tail turn
        nearest = min(frame_report.angle(r, wanted) for r in rotations)
        assert nearest <= half_step + 1e-9


def test_sagittal_candidates_hold_the_true_frame_of_a_symmetric_animal(frame_report):
    model = MatchingModel.tiny_random(0)
    generated = generate_shape(
        "quadruped", families("quadruped")[0], 0, mean_shape=True, rest_pose=True
    )
    rotation = _random_rotation(4)
    shape = Shape.from_arrays(np.asarray(generated.vertices) @ rotation.T, generated.faces)
    prepared = model.prepare(shape, frames="tnet")
    normals = frame_report.plane_normals(prepared)
    candidates = frame_report.sagittal_candidates(prepared, normals)
    assert len(candidates) == 1 + 2 * 24 * frame_report.SAGITTAL_PLANES
    np.testing.assert_allclose(candidates[0], prepared.transform.rotation)  # the T-Net's first
    best = min(frame_report.angle(r @ rotation, np.eye(3)) for r in candidates)
    assert best <= np.pi / frame_report.SAGITTAL_TURNS + 0.05  # a turn step and the plane fit
    model.frame_judge = _JudgePrefers(17)
    kept = frame_report.judge_over(model, shape, prepared, candidates)
    np.testing.assert_allclose(kept, candidates[17], atol=1e-6)


def test_snapping_lays_the_left_right_axis_on_the_nearest_plane_and_keeps_the_rest(frame_report):
    truth = _random_rotation(5)
    normals = np.array([truth[1], -truth[0], truth[2]])  # the true plane's normal, sign flipped
    tilt = np.array([[1.0, 0.0, 0.0], [0.0, np.cos(0.5), -np.sin(0.5)], [0.0, np.sin(0.5), 0.0]])
    tilt[2, 2] = np.cos(0.5)  # a turn about the left-right axis: the plane cannot see it
    roll = np.array([[np.cos(0.4), -np.sin(0.4), 0.0], [np.sin(0.4), np.cos(0.4), 0.0], [0, 0, 1]])
    start = tilt @ roll @ truth  # the left-right axis 0.4 rad off the plane's normal
    result = frame_report.snapped(start, normals)
    np.testing.assert_allclose(result @ result.T, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(result[0], truth[0], atol=1e-12)
    # only the roll is undone: the result is the tilt alone
    np.testing.assert_allclose(result, tilt @ truth, atol=1e-12)
    np.testing.assert_allclose(frame_report.snapped(truth, normals), truth, atol=1e-12)


class _JudgePrefers:
    """A frame judge stub: candidate ``best`` of every call scores lowest."""

    def __init__(self, best: int) -> None:
        self.best = best

    def target_points(self, points):
        return points[:8]

    def scores(self, clouds, points):
        out = np.ones(len(clouds))
        out[self.best] = 0.1
        return out


def test_check_rows_split_the_failures_by_the_frame_check(frame_report):
    found = [
        frame_report.Found(np.eye(3), "tnet", check)
        for check in ("agreed", "agreed", "split", "split", "split")
    ]
    errors = [0.1, 1.0, 2.0, 3.0, 0.2]
    rows = frame_report.check_rows("TOSCA", "judged", errors, found)
    assert rows == [
        "| TOSCA, T-Net runs agreed | judged | 2 | 0.55 | 0.55 | 50.0 |",
        "| TOSCA, T-Net runs split | judged | 3 | 2.00 | 1.73 | 66.7 |",
    ]
    unchecked = [f._replace(check="unchecked") for f in found]
    assert frame_report.check_rows("TOSCA", "tnet", errors, unchecked) == []
    assert frame_report.switched_count([*found[:2], found[2]._replace(name="pca4")]) == 1
