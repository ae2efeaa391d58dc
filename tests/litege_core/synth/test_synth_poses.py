"""Poses: modes, joint limits, self-intersection rate."""

import numpy as np
import pytest

from litege_core import synth
from litege_core.synth import poses, quality


@pytest.mark.parametrize("category", ["quadruped", "biped"])
def test_every_mode_generates_a_valid_shape(category: str) -> None:
    for i, mode in enumerate(synth.pose_modes(category)):
        family = synth.families(category)[i % len(synth.families(category))]
        shape = synth.generate_shape(category, family, 11, pose=mode, reject=False)
        assert shape.pose == mode
        assert np.isfinite(shape.vertices).all()


@pytest.mark.parametrize("category", ["quadruped", "biped"])
def test_sampled_noise_respects_joint_limits(category: str) -> None:
    skel = synth.template(category).skeleton
    rng = np.random.default_rng(5)
    table = poses.LIMITS[category]
    for _ in range(20):
        pose = poses.sample_pose(category, "standing", skel, rng)
        for j, name in enumerate(skel.names):
            limits, _ = table[poses._base(name)[0]]
            omega = pose.rotations[j]
            bound = max(max(abs(lo), abs(hi)) for lo, hi in limits)
            assert np.linalg.norm(omega) <= np.sqrt(3) * bound + 0.75  # standing offsets


def test_noise_scale_matches_design() -> None:
    """Unclipped joints get axis-angle noise with standard deviation ≈ 0.2 rad."""
    skel = synth.template("quadruped").skeleton
    rng = np.random.default_rng(0)
    draws = np.stack(
        [poses.sample_pose("quadruped", "standing", skel, rng).rotations for _ in range(300)]
    )
    tail = skel.index("tail4")
    assert np.std(draws[:, tail, 0]) == pytest.approx(poses.NOISE_STD, rel=0.2)


SELF_INTERSECTION_BOUND = 0.1


@pytest.mark.parametrize("category", ["quadruped", "biped"])
def test_self_intersection_fraction_is_small(category: str) -> None:
    families = synth.families(category)
    shapes = [
        synth.generate_shape(category, families[s % len(families)], 100 + s) for s in range(8)
    ]
    bad = sum(quality.self_intersects(s.vertices, s.faces) for s in shapes)
    assert bad / len(shapes) <= SELF_INTERSECTION_BOUND


def test_self_intersection_detector() -> None:
    tmpl = synth.template("quadruped")
    assert not quality.self_intersects(tmpl.vertices, tmpl.faces)
    # Push the left front leg through the right one.
    skel = tmpl.skeleton
    moved = tmpl.vertices.copy()
    leg = np.array([p == "fleg_l" for p in tmpl.parts])
    moved[leg, 0] -= 0.26
    assert quality.self_intersects(moved, tmpl.faces)
    assert skel.n_joints > 0
