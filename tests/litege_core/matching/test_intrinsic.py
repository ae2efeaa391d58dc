"""litege_core.matching.intrinsic: the robust rotation fit and intrinsic frames of meshes."""

from __future__ import annotations

import numpy as np
import pytest

from litege_core.errors import InputError
from litege_core.matching import MatchingModel
from litege_core.matching.intrinsic import intrinsic_frame, intrinsic_frames, robust_rotation
from litege_core.shape import Shape
from litege_core.synth import families, generate_shape
from litege_core.variants import random_rotation


def _angle(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.arccos(np.clip((np.trace(a @ b.T) - 1.0) / 2.0, -1.0, 1.0)))


def _rotated(category: str, seed: int, rotation_seed: int) -> tuple[Shape, np.ndarray]:
    generated = generate_shape(category, families(category)[0], seed)
    truth = random_rotation(np.random.default_rng(rotation_seed))
    vertices = np.asarray(generated.vertices) @ truth.T
    return Shape.from_arrays(vertices, generated.faces), truth


def test_robust_rotation_recovers_a_rotation_despite_outliers():
    rng = np.random.default_rng(3)
    source = rng.normal(size=(400, 3)) * [3.0, 1.0, 0.5]
    truth = random_rotation(rng)
    target = source @ truth.T + [0.3, -1.0, 2.0]
    exact, residual = robust_rotation(source, target)
    assert _angle(exact, truth) < 1e-6 and residual < 1e-9
    target[:60] = rng.normal(size=(60, 3)) * 3.0  # 15 % of the pairs wrong
    rotation, _ = robust_rotation(source, target)
    assert np.allclose(rotation @ rotation.T, np.eye(3)) and np.linalg.det(rotation) > 0
    assert _angle(rotation, truth) < 0.02
    plain, _ = robust_rotation(source, target, rounds=1)  # unweighted Procrustes
    assert _angle(plain, truth) > 5 * _angle(rotation, truth)
    # a map mirrored about the narrowest axis fits best as the rotation itself, flipped back
    flipped, _ = robust_rotation(source, (source * [1.0, 1.0, -1.0]) @ truth.T)
    assert _angle(flipped, truth) < 0.1  # not pi
    with pytest.raises(InputError):
        robust_rotation(source, target[:10])
    with pytest.raises(InputError):
        robust_rotation(source, target, rounds=0)


def test_intrinsic_frames_find_a_posed_human_in_any_rotation():
    pytest.importorskip("pyFM")
    shape, truth = _rotated("biped", 2_000_007, 5)
    assert shape.faces is not None
    frames = intrinsic_frames(shape.vertices, shape.faces, "biped")
    assert [frame.family for frame in frames] == list(families("biped"))
    kept = intrinsic_frame(shape.vertices, shape.faces, "biped")
    assert kept.residual == min(frame.residual for frame in frames)
    assert _angle(kept.rotation @ truth, np.eye(3)) < 0.66  # the generator's frame
    scaled = intrinsic_frame(3.0 * shape.vertices + 5.0, shape.faces, "biped")  # any units
    assert _angle(scaled.rotation, kept.rotation) < 1e-6
    with pytest.raises(InputError):
        intrinsic_frames(shape.vertices, np.zeros((0, 3), dtype=np.int64), "biped")
    with pytest.raises(InputError):
        intrinsic_frames(shape.vertices, shape.faces, "fish")


def test_prepare_with_intrinsic_frames_turns_meshes_and_keeps_clouds_on_the_tnet(monkeypatch):
    pytest.importorskip("pyFM")
    from litege_core.matching import model as model_module

    split = model_module.candidate_turns

    def always_split(tnet, frames, n_points, seed):  # the judged-frames test of a split shape
        return [
            np.eye(3)[None] if turns is None else turns
            for turns in split(tnet, frames, n_points, seed)
        ]

    monkeypatch.setattr(model_module, "candidate_turns", always_split)
    tiny = MatchingModel.tiny_random(0)  # category "test": no reference animals
    with pytest.raises(InputError, match="intrinsic"):
        tiny.resolve_frames("intrinsic")
    model = MatchingModel.load("humans")
    mesh, truth = _rotated(model.category, 2_000_003, 9)
    cloud = Shape.from_arrays(mesh.vertices)
    prepared, plain = model.prepare_many([mesh, cloud], frames="intrinsic")
    expected = intrinsic_frame(mesh.vertices, mesh.faces, model.category)
    assert prepared.frame == f"intrinsic:{expected.family}"
    assert (prepared.frame_check, plain.frame_check) == ("split", "unchecked")
    np.testing.assert_allclose(prepared.transform.rotation, expected.rotation, atol=1e-9)
    assert _angle(np.asarray(prepared.transform.rotation) @ truth, np.eye(3)) < 0.66
    centred = prepared.aligned - prepared.aligned.mean(axis=0)
    assert abs(np.sqrt((centred**2).sum(axis=1).mean()) - 1.0) < 1.0  # unit-area frame kept
    assert plain.frame == "tnet"
    tnet_cloud = model.prepare(cloud, frames="tnet")
    np.testing.assert_allclose(  # batched T-Net runs agree to float32 rounding
        plain.transform.rotation, tnet_cloud.transform.rotation, atol=1e-5
    )
    # where the T-Net's turned runs agree, its frame stands
    monkeypatch.setattr(model_module, "candidate_turns", lambda *args: [None])
    agreed = model.prepare(mesh, frames="intrinsic")
    assert (agreed.frame, agreed.frame_check) == ("tnet", "agreed")
    tnet_mesh = model.prepare(mesh, frames="tnet")
    np.testing.assert_allclose(agreed.transform.rotation, tnet_mesh.transform.rotation)
