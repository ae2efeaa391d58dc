"""The biped (human) template's anatomy: a 24-joint skeleton and its body, in an A-pose.

Joints: pelvis (root), spine1–3, neck, head; per arm collar, shoulder, elbow, wrist, hand;
per leg hip, knee, ankle, foot. Units: metres of a 1.78 m adult (height is varied by the
families; downstream code normalizes scale). The arms hang 35° below horizontal and the
legs are slightly spread so that every limb is clear of the body for meshing and skinning.
"""

from __future__ import annotations

import numpy as np

from litege_core.synth.implicit import Blend, Ellipsoid, RoundCone, as_vec3s, blend
from litege_core.synth.skeleton import Skeleton, SkeletonBuilder

Vec = tuple[float, float, float]

ARM_DROP = np.radians(35.0)
_ARM_DIR = np.array([np.cos(ARM_DROP), -np.sin(ARM_DROP), 0.0])


def _along(start: Vec, length: float) -> Vec:
    p = np.array(start) + length * _ARM_DIR
    return (float(p[0]), float(p[1]), float(p[2]))


SPINE: tuple[Vec, ...] = (
    (0.0, 0.96, -0.01),
    (0.0, 1.08, -0.01),
    (0.0, 1.21, -0.01),
    (0.0, 1.34, -0.02),
)
NECK: Vec = (0.0, 1.50, -0.01)
HEAD: Vec = (0.0, 1.59, 0.0)
HEAD_TIP: Vec = (0.0, 1.79, 0.01)
COLLAR: Vec = (0.04, 1.44, -0.02)
SHOULDER: Vec = (0.18, 1.43, -0.02)
ELBOW = _along(SHOULDER, 0.28)
WRIST = _along(ELBOW, 0.25)
HAND = _along(WRIST, 0.04)
HAND_TIP = _along(WRIST, 0.19)
HIP: Vec = (0.09, 0.92, -0.005)
KNEE: Vec = (0.115, 0.51, 0.01)
ANKLE: Vec = (0.14, 0.09, -0.02)
FOOT: Vec = (0.145, 0.035, 0.07)
TOE: Vec = (0.15, 0.025, 0.17)


def skeleton() -> Skeleton:
    """The 24-joint biped rest skeleton."""
    b = SkeletonBuilder()
    b.add("pelvis", None, SPINE[0], "trunk")
    b.add("spine1", "pelvis", SPINE[1], "trunk")
    b.add("spine2", "spine1", SPINE[2], "trunk")
    b.add("spine3", "spine2", SPINE[3], "trunk", tip=NECK)
    b.add("neck", "spine3", NECK, "neck")
    b.add("head", "neck", HEAD, "head", tip=HEAD_TIP)
    b.add_mirrored("collar", "spine3", COLLAR, "arm_l", tip=SHOULDER)
    b.add_mirrored("shoulder", "collar_l", SHOULDER, "arm_l")
    b.add_mirrored("elbow", "shoulder_l", ELBOW, "arm_l")
    b.add_mirrored("wrist", "elbow_l", WRIST, "arm_l")
    b.add_mirrored("hand", "wrist_l", HAND, "arm_l", tip=HAND_TIP)
    b.add_mirrored("hip", "pelvis", HIP, "leg_l")
    b.add_mirrored("knee", "hip_l", KNEE, "leg_l")
    b.add_mirrored("ankle", "knee_l", ANKLE, "leg_l")
    b.add_mirrored("foot", "ankle_l", FOOT, "leg_l", tip=TOE)
    return b.build()


def _rotation_to(axis: np.ndarray) -> tuple[tuple[float, float, float], ...]:
    """Orthonormal frame (rows = columns of a rotation) whose first column is ``axis``."""
    a = axis / np.linalg.norm(axis)
    helper = np.array([0.0, 0.0, 1.0])
    b = np.cross(helper, a)
    b /= np.linalg.norm(b)
    c = np.cross(a, b)
    return as_vec3s(np.stack([a, b, c], axis=1))


def _arm() -> Blend:
    hand_center = _along(WRIST, 0.10)
    return blend(
        [
            RoundCone(SHOULDER, ELBOW, 0.052, 0.04, "arm_l"),
            RoundCone(ELBOW, WRIST, 0.04, 0.028, "arm_l"),
            Ellipsoid(hand_center, (0.085, 0.024, 0.045), "arm_l", _rotation_to(_ARM_DIR)),
        ],
        0.03,
    )


def _leg() -> Blend:
    return blend(
        [
            RoundCone(HIP, KNEE, 0.085, 0.052, "leg_l"),
            RoundCone(KNEE, ANKLE, 0.05, 0.033, "leg_l"),
            Ellipsoid((0.12, 0.36, -0.025), (0.045, 0.11, 0.045), "leg_l"),
            Ellipsoid((0.147, 0.04, 0.055), (0.045, 0.036, 0.12), "leg_l"),
        ],
        0.04,
    )


def _mirror(node: Blend) -> Blend:
    leaves = []
    for leaf in node.children:
        assert not isinstance(leaf, Blend)
        leaves.append(leaf.mirrored(leaf.tag[:-2] + "_r"))
    return Blend(tuple(leaves), node.k)


def body() -> Blend:
    """The biped body field (negative inside), symmetric about ``x = 0``."""
    trunk = blend(
        [
            Ellipsoid((0.0, 0.95, -0.01), (0.165, 0.12, 0.11), "trunk"),
            Ellipsoid((0.07, 0.90, -0.06), (0.08, 0.09, 0.07), "trunk"),
            Ellipsoid((-0.07, 0.90, -0.06), (0.08, 0.09, 0.07), "trunk"),
            Ellipsoid((0.0, 1.11, 0.0), (0.145, 0.14, 0.10), "trunk"),
            Ellipsoid((0.0, 1.29, -0.01), (0.165, 0.17, 0.11), "trunk"),
            Ellipsoid((0.0, 1.405, -0.025), (0.2, 0.065, 0.08), "trunk"),
        ],
        0.06,
    )
    neck = RoundCone((0.0, 1.40, -0.02), NECK, 0.058, 0.052, "neck")
    head = blend(
        [
            Ellipsoid((0.0, 1.67, 0.01), (0.076, 0.105, 0.095), "head"),
            Ellipsoid((0.0, 1.605, 0.035), (0.058, 0.06, 0.07), "head"),
            RoundCone((0.0, 1.655, 0.09), (0.0, 1.635, 0.115), 0.022, 0.016, "head"),
        ],
        0.04,
    )
    arm, leg = _arm(), _leg()
    return blend([trunk, blend([neck], 0.0), head, arm, _mirror(arm), leg, _mirror(leg)], 0.05)


__all__ = [
    "ANKLE",
    "ARM_DROP",
    "COLLAR",
    "ELBOW",
    "FOOT",
    "HAND",
    "HAND_TIP",
    "HEAD",
    "HEAD_TIP",
    "HIP",
    "KNEE",
    "NECK",
    "SHOULDER",
    "SPINE",
    "TOE",
    "WRIST",
    "Vec",
    "body",
    "skeleton",
]
