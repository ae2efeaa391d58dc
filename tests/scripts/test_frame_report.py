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
    tnet_frame = model.prepare(shape, frames="tnet").transform.rotation
    agreeing = np.tile(np.eye(3), (1, 24, 1, 1))
    monkeypatch.setattr(frame_module, "tnet_turn_runs", lambda tnet, c: agreeing)
    only = frame_report.candidate_rotations(model, shape)
    assert len(only) == 1 and np.allclose(only[0], tnet_frame)

    split = agreeing.copy()
    split[0, 5] = np.diag([1.0, -1.0, -1.0])
    monkeypatch.setattr(frame_module, "tnet_turn_runs", lambda tnet, c: split)
    many = frame_report.candidate_rotations(model, shape)
    assert len(many) == 25 and np.allclose(many[0], tnet_frame)
    for rotation in many:
        np.testing.assert_allclose(rotation @ rotation.T, np.eye(3), atol=1e-9)
        assert np.isclose(np.linalg.det(rotation), 1.0)
    judged = model.prepare(shape, frames="judged")  # keeps candidate 7: principal-axis frame 6
    assert judged.frame == "pca6"
    np.testing.assert_allclose(judged.transform.rotation, many[7], atol=1e-4)
