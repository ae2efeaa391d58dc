"""Skinning sanity: weights, rest pose, bends without collapse or candy-wrapping."""

import numpy as np
import pytest

from litege_core import synth
from litege_core.synth import generate, poses, quality, skinning


@pytest.mark.parametrize("category", ["quadruped", "biped"])
def test_weights_are_a_sparse_partition_of_unity(category: str) -> None:
    tmpl = synth.template(category)
    for weights, max_nonzero in ((tmpl.weights, 4), (tmpl.shape_weights, tmpl.skeleton.n_joints)):
        assert weights.shape == (len(tmpl.vertices), tmpl.skeleton.n_joints)
        assert weights.min() >= 0.0
        assert np.allclose(weights.sum(axis=1), 1.0)
        assert (weights > 0).sum(axis=1).max() <= max_nonzero
    mirrored = tmpl.weights[tmpl.symmetry][:, tmpl.skeleton.mirror]
    assert np.allclose(mirrored, tmpl.weights, atol=1e-9)


def test_every_joint_moves_some_vertices() -> None:
    tmpl = synth.template("quadruped")
    dominant = np.bincount(tmpl.weights.argmax(axis=1), minlength=tmpl.skeleton.n_joints)
    assert np.all(dominant > 0)


@pytest.mark.parametrize("category", ["quadruped", "biped"])
def test_rest_pose_reproduces_template(category: str) -> None:
    tmpl = synth.template(category)
    skel = tmpl.skeleton
    linear, joints = skinning.scale_maps(skel, np.ones((skel.n_joints, 3)))
    assert np.allclose(joints, skel.positions)
    shaped = skinning.blend(tmpl.vertices, tmpl.shape_weights, linear, skel.positions, joints)
    rest = poses.Pose("rest", np.zeros((skel.n_joints, 3)), np.zeros(3))
    posed, _ = generate.apply_pose(tmpl, shaped, joints, rest)
    assert np.abs(posed - tmpl.vertices).max() < 1e-12


def _bend(category: str, joint: str, anatomical: tuple[float, float, float]) -> np.ndarray:
    tmpl = synth.template(category)
    skel = tmpl.skeleton
    offsets = np.zeros((skel.n_joints, 3))
    offsets[skel.index(joint)] = anatomical
    rotations = poses.to_rotation_vectors(category, skel, offsets)
    posed, _ = generate.apply_pose(
        tmpl, tmpl.vertices, skel.positions, poses.Pose("bend", rotations, np.zeros(3))
    )
    return posed


@pytest.mark.parametrize(
    ("category", "joint", "anatomical", "apart"),
    [
        # The template's hind knee is already flexed: 90° more folds the shin onto the
        # thigh, where the skin surfaces meet (contact, as on a real animal).
        ("quadruped", "knee_l", (np.pi / 2, 0.0, 0.0), False),
        ("quadruped", "elbow_l", (np.pi / 2, 0.0, 0.0), True),
        ("quadruped", "neck1", (0.0, np.pi / 2, 0.0), True),
        ("biped", "elbow_l", (np.pi / 2, 0.0, 0.0), True),
        ("biped", "knee_l", (np.pi / 2, 0.0, 0.0), True),
    ],
)
def test_right_angle_bend_keeps_local_areas(
    category: str, joint: str, anatomical: tuple[float, float, float], apart: bool
) -> None:
    """A 90° bend keeps the triangles near the joint within stated area bounds: 95 % keep at
    least 0.3× their rest area, none drops below 0.05× (linear blend skinning squeezes the
    inner side of a bend, it does not collapse it) and none grows past 2×; the bent surface
    does not pass through itself where the bent parts stay apart."""
    tmpl = synth.template(category)
    posed = _bend(category, joint, anatomical)
    j = tmpl.skeleton.index(joint)
    near = np.linalg.norm(tmpl.vertices - tmpl.skeleton.positions[j], axis=1) < 0.15
    faces = tmpl.faces[near[tmpl.faces].all(axis=1)]
    assert len(faces) > 20

    def normals(v: np.ndarray) -> np.ndarray:
        p = v[faces]
        return np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])

    n0, n1 = normals(tmpl.vertices), normals(posed)
    ratio = np.linalg.norm(n1, axis=1) / np.linalg.norm(n0, axis=1)
    assert np.percentile(ratio, 5) > 0.3
    assert ratio.min() > 0.05
    assert ratio.max() < 2.0
    if apart:
        assert not quality.self_intersects(posed, tmpl.faces)


def test_sparsify_is_continuous() -> None:
    rng = np.random.default_rng(0)
    w = rng.random((200, 12)) ** 4
    a = skinning.sparsify(w, 3, 0.01)
    b = skinning.sparsify(w + 1e-9 * rng.standard_normal(w.shape).clip(0), 3, 0.01)
    assert np.abs(a - b).max() < 1e-6
    assert (a > 0).sum(axis=1).max() <= 3
