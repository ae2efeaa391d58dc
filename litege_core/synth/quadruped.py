"""The quadruped template's anatomy: a 34-joint skeleton in SMAL's pattern, and its body.

Joints: pelvis (root), spine1–3 (spine3 is the chest), neck1–2, head (cranium), muzzle, jaw,
ears, tail1–7 and four per leg (shoulder/elbow/wrist/paw in front, hip/knee/ankle/paw
behind): SMAL's 33 plus a muzzle bone, so that snout length and breadth vary apart from the
cranium. The rest pose is a standing, dog-like mean animal with trunk length L = 0.98 between
the hip and shoulder joints (about 1), legs ≈ 0.74, neck (neck1→head) ≈ 0.38, head ≈ 0.4,
tail ≈ 0.62; the families in :mod:`litege_core.synth.shape_space` rescale it.
"""

from __future__ import annotations

import numpy as np

from litege_core.synth.implicit import Blend, Ellipsoid, RoundCone, as_vec3s, blend
from litege_core.synth.skeleton import Skeleton, SkeletonBuilder

Vec = tuple[float, float, float]

SHOULDER: Vec = (0.13, 0.74, 0.98)
HIP: Vec = (0.13, 0.74, 0.0)
FRONT_LEG: tuple[Vec, ...] = (SHOULDER, (0.13, 0.46, 0.93), (0.13, 0.16, 0.96), (0.13, 0.05, 0.99))
FRONT_TOE: Vec = (0.13, 0.025, 1.07)
HIND_LEG: tuple[Vec, ...] = (HIP, (0.13, 0.48, 0.11), (0.13, 0.20, -0.05), (0.13, 0.05, -0.01))
HIND_TOE: Vec = (0.13, 0.025, 0.07)
SPINE: tuple[Vec, ...] = (
    (0.0, 0.80, 0.02),
    (0.0, 0.81, 0.34),
    (0.0, 0.81, 0.66),
    (0.0, 0.80, 0.98),
)
CHEST_TIP: Vec = (0.0, 0.79, 1.22)  # spine3's bone continues the spine (not up the neck)
NECK: tuple[Vec, ...] = ((0.0, 0.90, 1.12), (0.0, 1.04, 1.27))
HEAD: Vec = (0.0, 1.16, 1.40)
MUZZLE: Vec = (0.0, 1.15, 1.51)
NOSE: Vec = (0.0, 1.085, 1.77)
JAW: Vec = (0.0, 1.08, 1.44)
CHIN: Vec = (0.0, 1.02, 1.69)
EAR: Vec = (0.06, 1.26, 1.41)
EAR_TIP: Vec = (0.105, 1.46, 1.37)
TAIL_SEGMENTS = 7
TAIL_LENGTH = 0.62


def _tail_points() -> list[Vec]:
    """Tail joints and tip: a chain starting above the rump, drooping progressively."""
    start = np.array([0.0, 0.86, -0.17])
    angles = np.radians(np.linspace(-20.0, -55.0, TAIL_SEGMENTS))
    seg = TAIL_LENGTH / TAIL_SEGMENTS
    points = [start]
    for angle in angles:
        points.append(points[-1] + seg * np.array([0.0, np.sin(angle), -np.cos(angle)]))
    return [(float(p[0]), float(p[1]), float(p[2])) for p in points]


def skeleton() -> Skeleton:
    """The 34-joint quadruped rest skeleton."""
    b = SkeletonBuilder()
    b.add("pelvis", None, SPINE[0], "trunk")
    b.add("spine1", "pelvis", SPINE[1], "trunk")
    b.add("spine2", "spine1", SPINE[2], "trunk")
    b.add("spine3", "spine2", SPINE[3], "trunk", tip=CHEST_TIP)
    b.add("neck1", "spine3", NECK[0], "neck")
    b.add("neck2", "neck1", NECK[1], "neck")
    b.add("head", "neck2", HEAD, "head", tip=MUZZLE)
    b.add("muzzle", "head", MUZZLE, "muzzle", tip=NOSE)
    b.add("jaw", "head", JAW, "jaw", tip=CHIN)
    b.add_mirrored("ear", "head", EAR, "ear_l", tip=EAR_TIP)
    tail = _tail_points()
    for i in range(TAIL_SEGMENTS):
        parent = "pelvis" if i == 0 else f"tail{i}"
        tip = tail[i + 1] if i == TAIL_SEGMENTS - 1 else None
        b.add(f"tail{i + 1}", parent, tail[i], "tail", tip=tip)
    for names, points, toe, group, root_parent in (
        (("shoulder", "elbow", "wrist", "fpaw"), FRONT_LEG, FRONT_TOE, "fleg_l", "spine3"),
        (("hip", "knee", "ankle", "hpaw"), HIND_LEG, HIND_TOE, "hleg_l", "pelvis"),
    ):
        for i, (name, point) in enumerate(zip(names, points, strict=True)):
            parent = root_parent if i == 0 else names[i - 1] + "_l"
            b.add_mirrored(name, parent, point, group, tip=toe if i == 3 else None)
    return b.build()


def _leg(points: tuple[Vec, ...], toe: Vec, radii: tuple[float, ...], tag: str) -> Blend:
    """Leg: round cones between joints, a flattened paw ellipsoid at the end."""
    parts: list[RoundCone | Ellipsoid] = [
        RoundCone(points[i], points[i + 1], radii[i], radii[i + 1], tag) for i in range(3)
    ]
    paw, tip = np.array(points[3]), np.array(toe)
    center = 0.5 * (paw + tip) + np.array([0.0, 0.01, 0.0])
    parts.append(
        Ellipsoid(
            as_vec3s(center[None])[0],
            (radii[3] * 1.25, 0.04, 0.5 * float(np.linalg.norm(tip - paw)) + radii[3]),
            tag,
        )
    )
    return blend(parts, 0.03)


def _ear() -> Ellipsoid:
    """A flat ear: an ellipsoid along the ear bone, thin front to back."""
    base, tip = np.array(EAR), np.array(EAR_TIP)
    axis = tip - base
    length = float(np.linalg.norm(axis))
    axis /= length
    across = np.cross(axis, [0.0, 0.0, 1.0])
    across /= np.linalg.norm(across)
    thin = np.cross(axis, across)
    frame = np.stack([axis, across, thin], axis=1)
    center = base + 0.55 * length * axis
    return Ellipsoid(
        as_vec3s(center[None])[0],
        (0.6 * length, 0.062, 0.032),
        "ear_l",
        as_vec3s(frame),
    )


def _mirror_blend(node: Blend, side: str) -> Blend:
    leaves = []
    for leaf in node.children:
        assert not isinstance(leaf, Blend)
        leaves.append(leaf.mirrored(leaf.tag[:-2] + side))
    return Blend(tuple(leaves), node.k)


def body() -> Blend:
    """The quadruped body field (negative inside), symmetric about ``x = 0``."""
    trunk = blend(
        [
            Ellipsoid((0.0, 0.77, 0.78), (0.17, 0.23, 0.36), "trunk"),
            Ellipsoid((0.0, 0.775, 0.42), (0.165, 0.215, 0.38), "trunk"),
            Ellipsoid((0.0, 0.80, 0.06), (0.16, 0.19, 0.27), "trunk"),
            Ellipsoid((0.0, 0.86, 0.98), (0.13, 0.15, 0.20), "trunk"),
        ],
        0.22,
    )
    neck = RoundCone((0.0, 0.86, 1.02), (0.0, 1.12, 1.35), 0.135, 0.09, "neck")
    head = blend(
        [
            Ellipsoid((0.0, 1.18, 1.43), (0.10, 0.10, 0.12), "head"),
            RoundCone((0.0, 1.155, 1.50), (0.0, 1.095, 1.725), 0.078, 0.048, "muzzle"),
        ],
        0.06,
    )
    jaw = RoundCone((0.0, 1.08, 1.45), (0.0, 1.035, 1.68), 0.058, 0.03, "jaw")
    ear = _ear()
    tail_pts = _tail_points()
    tail_r = np.linspace(0.055, 0.026, TAIL_SEGMENTS + 1)
    tail = blend(
        [
            RoundCone(tail_pts[i], tail_pts[i + 1], tail_r[i], tail_r[i + 1], "tail")
            for i in range(TAIL_SEGMENTS)
        ],
        0.02,
    )
    front_l = _leg(FRONT_LEG, FRONT_TOE, (0.085, 0.052, 0.038, 0.035), "fleg_l")
    hind_l = _leg(HIND_LEG, HIND_TOE, (0.105, 0.058, 0.036, 0.035), "hleg_l")
    head_all = blend(
        [head, blend([jaw], 0.0), blend([ear], 0.0), blend([ear.mirrored("ear_r")], 0.0)], 0.04
    )
    legs = [front_l, _mirror_blend(front_l, "_r"), hind_l, _mirror_blend(hind_l, "_r")]
    return blend([trunk, blend([neck], 0.0), head_all, tail, *legs], 0.08)


__all__ = [
    "CHEST_TIP",
    "CHIN",
    "EAR",
    "EAR_TIP",
    "FRONT_LEG",
    "FRONT_TOE",
    "HEAD",
    "HIND_LEG",
    "HIND_TOE",
    "HIP",
    "JAW",
    "MUZZLE",
    "NECK",
    "NOSE",
    "SHOULDER",
    "SPINE",
    "TAIL_LENGTH",
    "TAIL_SEGMENTS",
    "Vec",
    "body",
    "skeleton",
]
