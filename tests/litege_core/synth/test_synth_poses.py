"""Poses: modes, joint limits, self-intersection rate."""

import numpy as np
import pytest

from litege_core import synth
from litege_core.errors import InputError
from litege_core.synth import poses, quality
from litege_core.synth.generate import drawn_pose_mode


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


def _trunk_pitch(shape) -> float:
    """Angle (rad) of pelvis → neck above the horizontal (y up, z forward)."""
    names = synth.template("quadruped").skeleton.names
    trunk = shape.joints[names.index("neck1")] - shape.joints[names.index("pelvis")]
    return float(np.arctan2(trunk[1], abs(trunk[2])))


def test_steep_modes_are_generated_only_when_asked_for() -> None:
    modes = synth.pose_modes("quadruped")
    assert modes == poses.QUADRUPED_MODES + poses.QUADRUPED_STEEP_MODES
    drawn = {
        drawn_pose_mode("quadruped", family, seed)
        for family in synth.families("quadruped")
        for seed in range(60)
    }
    assert drawn == set(poses.QUADRUPED_MODES)
    with pytest.raises(InputError, match="unknown biped pose mode"):
        synth.generate_shape("biped", synth.families("biped")[0], 0, pose="rearing")


@pytest.mark.parametrize("family", synth.families("quadruped"))
def test_rearing_raises_the_trunk_and_leaping_stretches_the_legs(family: str) -> None:
    names = synth.template("quadruped").skeleton.names
    standing = synth.generate_shape("quadruped", family, 3, pose="standing")
    rearing = synth.generate_shape("quadruped", family, 3, pose="rearing")
    leaping = synth.generate_shape("quadruped", family, 3, pose="leaping")
    again = synth.generate_shape("quadruped", family, 3, pose="rearing")
    np.testing.assert_array_equal(rearing.vertices, again.vertices)  # seeded
    assert (rearing.pose, leaping.pose) == ("rearing", "leaping")
    assert _trunk_pitch(rearing) > _trunk_pitch(standing) + 0.2
    if rearing.params["pose_attempts"] <= 3:  # the mode at full strength, not backed off
        assert _trunk_pitch(rearing) > np.radians(40.0)

    def paw_spread(shape) -> float:  # fore paws to hind paws along the body axis (z)
        z = shape.joints[:, 2]
        return float(z[names.index("fpaw_l")] - z[names.index("hpaw_l")])

    assert paw_spread(leaping) > paw_spread(standing)
    if leaping.params["pose_attempts"] <= 3:
        assert paw_spread(leaping) > 1.2 * paw_spread(standing)


@pytest.mark.parametrize("family", ["cat", "horse", "hippo"])
def test_sitting_up_raises_the_trunk_and_couchant_lowers_it(family: str) -> None:
    """Both fold every hind leg against the trunk, so they are kept at full strength (never
    redrawn weaker for a self-intersection)."""
    standing = synth.generate_shape("quadruped", family, 3, pose="standing")
    sitting = synth.generate_shape("quadruped", family, 3, pose="sitting_upright")
    couchant = synth.generate_shape("quadruped", family, 3, pose="couchant")
    assert sitting.params["pose_attempts"] == couchant.params["pose_attempts"] == 1
    assert _trunk_pitch(sitting) > np.radians(40.0) > _trunk_pitch(standing)
    names = synth.template("quadruped").skeleton.names

    def height(shape, joint: str) -> float:  # above the lowest vertex (the ground)
        return float(shape.joints[names.index(joint), 1] - shape.vertices[:, 1].min())

    # lying on the belly: the trunk sits far lower than standing, the forearms low and flat
    assert height(couchant, "spine2") < 0.75 * height(standing, "spine2")
    assert height(couchant, "wrist_l") <= height(couchant, "elbow_l")
    # sitting up (the trunk steep, above): the rump rests on the ground and the tail lies
    # along it (revision 2 sat up on the tail, the pelvis high)
    assert height(sitting, "pelvis") < 0.35 * height(sitting, "neck1")
    assert height(sitting, "tail3") < 0.3 * height(sitting, "neck1")


def test_steep_poses_are_a_nested_seeded_share() -> None:
    from litege_core.synth.poses import steep_pose

    seeds = range(2000)
    small = [steep_pose("quadruped", seed, 0.1) for seed in seeds]
    large = [steep_pose("quadruped", seed, 0.3) for seed in seeds]
    assert 0.07 < np.mean([mode is not None for mode in small]) < 0.13
    assert 0.26 < np.mean([mode is not None for mode in large]) < 0.34
    # a seed steep at a share stays steep, in the same mode, at a larger one
    assert all(b == a for a, b in zip(small, large, strict=True) if a is not None)
    assert {mode for mode in large if mode} == set(poses.QUADRUPED_STEEP_MODES)
    assert [steep_pose("quadruped", seed, 0.3) for seed in seeds] == large
    assert steep_pose("quadruped", 5, 0.0) is None
    assert steep_pose("biped", 5, 1.0) is None  # bipeds have no steep modes
