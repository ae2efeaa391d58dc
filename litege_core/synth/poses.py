"""Poses: a mode (walking, sitting, ...) plus per-joint axis-angle noise within joint limits.

A pose is one rotation vector per joint (radians, local to the parent, in the rest frame's
axes) and a root translation. Joint limits and mode offsets are written for the left side
and the midline in *anatomical* components ``(r0, r1, r2)``; each joint has a frame whose
columns give the world axes of those components (the identity for most joints, so r0 is
flexion about the lateral x axis, r1 twist about y, r2 roll/abduction about z with positive
values moving a left limb outwards). Right joints reuse their mirror's limits and frame and
the rotation is mirrored: ``ω_right = (ωx, −ωy, −ωz)``.

Sampling: ``ω = mode + clip(N(0, σ²), ±2σ)`` per component with ``σ = 0.2`` rad (scaled per
joint), then clipped to the joint's limits.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from litege_core.errors import InputError
from litege_core.synth.skeleton import Skeleton

NOISE_STD = 0.2

QUADRUPED_MODES = ("standing", "walking", "sitting", "lying")
BIPED_MODES = ("standing", "walking", "arms_raised", "crouching")
MODES = {"quadruped": QUADRUPED_MODES, "biped": BIPED_MODES}
"""The modes a seed draws from (``generate.MODE_WEIGHTS``)."""
QUADRUPED_STEEP_MODES = ("rearing", "leaping", "sitting_upright", "couchant")
"""Quadruped modes real animals hold and the drawn modes do not: the trunk steep or fully
stretched (rearing on the hind legs, leaping) or every leg folded (sitting up on the haunches,
lying on the belly). Generated only when asked for: seeds never draw them, so every dataset of
the drawn modes stays as it was. The frame selectors of issue 15 fail on the steep ones
(docs/jobs.md, session of 2026-11-29, second); TOSCA's five worst shapes for the geodesic
network sit up or crouch (BENCHMARKS "geodesic-folded")."""
CONTACT_MODES = ("sitting_upright", "couchant")
"""Modes whose folded legs press against the trunk, as a real animal's do: their shapes are
not redrawn for self-intersection (the geodesic targets are intrinsic to the surface)."""
MAKEHUMAN_STEEP_MODES = ("arms_overhead", "leg_lifted", "one_leg_balance", "bending_forward")
"""MakeHuman body poses outside the drawn ranges (:func:`litege_core.synth.makehuman.random_pose`):
both arms above the head, one knee bent past 90°, the one-legged balance with the lifted foot on
the other leg, and the forward bend from the hips. Real scanned humans hold them (FAUST's worst
shapes for the shipped ``humans`` are such poses, BENCHMARKS "humans-steep")."""
EXTRA_MODES: dict[str, tuple[str, ...]] = {
    "quadruped": QUADRUPED_STEEP_MODES,
    "biped": (),
    "makehuman": MAKEHUMAN_STEEP_MODES,
}
STEEP_REVISION = {"quadruped": 3, "makehuman": 1}
"""Revision of each category's steep modes: revision 1 of the quadrupeds had only rearing and
leaping, revision 2 sat up on the tail, trunk 50–65° up with the forepaws in the air
(revision 3 sits on the rump, paws on the ground), so a set of another revision draws other
poses from the same seeds and share."""


def steep_tag(category: str, share: float) -> str:
    """The version suffix of a set with a ``share`` of steep ``category`` shapes
    (``+steep0.3r2``; ``""`` for none): builds and caches of another share or revision are
    never resumed as this one."""
    if share <= 0.0:
        return ""
    revision = STEEP_REVISION.get(category, 1)
    return f"+steep{share:g}" + (f"r{revision}" if revision > 1 else "")


def known_modes(category: str) -> tuple[str, ...]:
    """Every mode of ``category`` a pose can be drawn in: :data:`MODES`, then
    :data:`EXTRA_MODES`."""
    return MODES[category] + EXTRA_MODES[category]


def check_steep_share(category: str, share: float) -> None:
    """Raise :class:`InputError` unless ``share`` (of shapes posed steep, :func:`steep_pose`)
    lies in ``[0, 1]`` and is 0 for a category without steep modes."""
    if not 0.0 <= share <= 1.0:
        raise InputError(f"the steep share must be in [0, 1], got {share!r}")
    if share > 0.0 and not EXTRA_MODES.get(category):
        raise InputError(
            f"{category!r} shapes have no steep poses (quadrupeds rear, leap, sit up or lie on "
            "the belly; MakeHuman bodies bend, balance or raise their arms)"
        )


def steep_pose(category: str, seed: int, share: float) -> str | None:
    """The steep mode (:data:`EXTRA_MODES`) shape ``seed`` of ``category`` is posed in when a
    ``share`` of a set is posed steep, or ``None`` for the pose its seed draws.

    A pure function of ``(seed, share)``: the shape is steep with probability ``share``
    (``default_rng([seed, 7919])``), each steep mode equally likely (a second draw); a seed
    steep at some share stays steep, in the same mode, at every larger share."""
    modes = EXTRA_MODES.get(category, ())
    if share <= 0.0 or not modes:
        return None
    steep_draw, mode_draw = np.random.default_rng([seed, 7919]).random(2)
    return modes[int(mode_draw * len(modes))] if steep_draw < share else None


Limits = tuple[tuple[float, float], tuple[float, float], tuple[float, float]]


def _sym(a: float, b: float, c: float) -> Limits:
    return ((-a, a), (-b, b), (-c, c))


#: Quadruped limits (left/midline), per joint name without side suffix, and noise scale.
QUADRUPED_LIMITS: dict[str, tuple[Limits, float]] = {
    "pelvis": (_sym(0.12, 0.3, 0.08), 0.5),
    "spine1": (_sym(0.25, 0.25, 0.15), 0.6),
    "spine2": (_sym(0.25, 0.25, 0.15), 0.6),
    "spine3": (_sym(0.25, 0.25, 0.15), 0.6),
    "neck1": (_sym(0.6, 0.5, 0.3), 1.0),
    "neck2": (_sym(0.6, 0.5, 0.3), 1.0),
    "head": (_sym(0.6, 0.5, 0.3), 1.0),
    "muzzle": (_sym(0.0, 0.0, 0.0), 0.0),
    "jaw": (((0.0, 0.3), (-0.05, 0.05), (-0.05, 0.05)), 0.5),
    "ear": (_sym(0.5, 0.4, 0.5), 1.0),
    **{f"tail{i}": (_sym(0.6, 0.6, 0.3), 1.0) for i in range(1, 8)},
    "shoulder": (((-1.4, 0.8), (-0.2, 0.2), (-0.12, 0.3)), 1.0),
    "elbow": (((-0.15, 1.6), (-0.1, 0.1), (-0.1, 0.1)), 1.0),
    "wrist": (((-0.3, 1.8), (-0.1, 0.1), (-0.1, 0.1)), 1.0),
    "fpaw": (((-0.5, 0.6), (-0.1, 0.1), (-0.1, 0.1)), 1.0),
    "hip": (((-1.4, 0.7), (-0.2, 0.2), (-0.12, 0.45)), 1.0),
    "knee": (((-0.3, 2.3), (-0.1, 0.1), (-0.1, 0.1)), 1.0),
    "ankle": (((-1.5, 0.4), (-0.1, 0.1), (-0.1, 0.1)), 1.0),
    "hpaw": (((-0.5, 0.6), (-0.1, 0.1), (-0.1, 0.1)), 1.0),
}

BIPED_LIMITS: dict[str, tuple[Limits, float]] = {
    "pelvis": (_sym(0.12, 0.4, 0.08), 0.5),
    "spine1": (((-0.25, 0.5), (-0.3, 0.3), (-0.2, 0.2)), 0.6),
    "spine2": (((-0.25, 0.5), (-0.3, 0.3), (-0.2, 0.2)), 0.6),
    "spine3": (((-0.25, 0.5), (-0.3, 0.3), (-0.2, 0.2)), 0.6),
    "neck": (_sym(0.5, 0.6, 0.3), 1.0),
    "head": (_sym(0.5, 0.6, 0.3), 1.0),
    "collar": (((-0.2, 0.2), (-0.2, 0.2), (-0.25, 0.5)), 0.5),
    "shoulder": (((-1.4, 1.0), (-0.7, 0.7), (-0.8, 1.9)), 1.0),
    "elbow": (((0.0, 2.2), (-0.5, 0.5), (-0.1, 0.1)), 1.0),
    "wrist": (((-0.7, 0.7), (-0.3, 0.3), (-0.5, 0.5)), 1.0),
    "hand": (((-0.3, 0.3), (-0.1, 0.1), (-0.2, 0.2)), 0.5),
    "hip": (((-1.9, 0.6), (-0.5, 0.5), (-0.2, 0.6)), 1.0),
    "knee": (((0.0, 1.7), (-0.1, 0.1), (-0.05, 0.05)), 1.0),
    "ankle": (((-0.8, 0.6), (-0.2, 0.2), (-0.3, 0.3)), 1.0),
    "foot": (((-0.3, 0.4), (-0.1, 0.1), (-0.1, 0.1)), 0.5),
}

LIMITS = {"quadruped": QUADRUPED_LIMITS, "biped": BIPED_LIMITS}


@dataclass(frozen=True)
class Pose:
    """A sampled pose.

    Attributes:
        mode: pose mode name.
        rotations: ``(J, 3)`` rotation vectors (radians), world rest axes, local to parents.
        root_translation: ``(3,)`` (posed shapes are grounded afterwards anyway).
    """

    mode: str
    rotations: NDArray
    root_translation: NDArray


def _base(name: str) -> tuple[str, str]:
    """(name without side suffix, side '' / '_l' / '_r')."""
    for side in ("_l", "_r"):
        if name.endswith(side):
            return name[:-2], side
    return name, ""


def joint_frames(category: str, skeleton: Skeleton) -> NDArray:
    """``(J, 3, 3)`` anatomical frames (columns: axes of components r0, r1, r2) for left and
    midline joints; right joints hold their mirror's frame."""
    frames = np.repeat(np.eye(3)[None], skeleton.n_joints, axis=0)
    if category == "biped":
        for name in ("elbow", "wrist", "hand"):
            j = skeleton.index(name + "_l")
            d = skeleton.tips[j] - skeleton.positions[j]
            d /= np.linalg.norm(d)
            flex = np.cross(d, [0.0, 0.0, 1.0])
            flex /= np.linalg.norm(flex)
            third = np.cross(flex, d)
            frames[j] = np.stack([flex, d, third], axis=1)
            frames[skeleton.index(name + "_r")] = frames[j]
    return frames


def mode_offsets(category: str, mode: str, skeleton: Skeleton, rng: np.random.Generator) -> NDArray:
    """``(J, 3)`` anatomical offsets of a mode; left and right are given separately."""
    known = known_modes(category)
    if mode not in known:
        raise InputError(f"unknown {category} pose mode {mode!r}; expected one of {known}")
    out = np.zeros((skeleton.n_joints, 3))
    phase = float(rng.uniform(0.0, 2.0 * np.pi))  # always drawn: keeps streams aligned
    amount = float(rng.uniform(0.6, 1.0))

    def put(name: str, r0: float = 0.0, r1: float = 0.0, r2: float = 0.0) -> None:
        out[skeleton.index(name)] = (r0, r1, r2)

    if category == "quadruped":
        if mode == "walking":
            for leg, upper, mid, low, offset in (
                ("l", "shoulder", "elbow", "wrist", 0.0),
                ("r", "shoulder", "elbow", "wrist", np.pi),
                ("l", "hip", "knee", "ankle", np.pi),
                ("r", "hip", "knee", "ankle", 0.0),
            ):
                s = np.sin(phase + offset)
                lift = max(0.0, np.cos(phase + offset))
                put(f"{upper}_{leg}", -0.45 * amount * s)
                if upper == "shoulder":
                    put(f"{mid}_{leg}", 0.5 * amount * lift)
                    put(f"{low}_{leg}", 0.9 * amount * lift)
                else:
                    put(f"{mid}_{leg}", 0.6 * amount * lift)
                    put(f"{low}_{leg}", -0.5 * amount * lift)
            put("neck1", -0.1)
            put("tail1", -0.2)
        elif mode == "sitting":
            tilt = -0.5 * (0.75 + 0.25 * amount)
            put("pelvis", tilt)
            for side in ("l", "r"):
                put(f"shoulder_{side}", -tilt + 0.05)
                put(f"hip_{side}", -0.5, 0.0, 0.3)
                put(f"knee_{side}", 1.15)
                put(f"ankle_{side}", -0.75 - 0.4 * tilt)
            put("neck1", 0.2)
            put("head", 0.25)
            put("tail1", 0.4)
        elif mode == "lying":
            # Lying on one side (lateral recumbency), legs relaxed and a little flexed.
            side_sign = 1.0 if phase < np.pi else -1.0
            put("pelvis", 0.0, 0.0, side_sign * 1.45)
            for side in ("l", "r"):
                put(f"shoulder_{side}", -0.35 * amount, 0.0, 0.1)
                put(f"elbow_{side}", 0.3 * amount)
                put(f"wrist_{side}", 0.3 * amount)
                put(f"hip_{side}", -0.3 * amount, 0.0, 0.1)
                put(f"knee_{side}", 0.5 * amount)
                put(f"ankle_{side}", -0.3 * amount)
            put("neck1", 0.0, 0.0, -side_sign * 0.35)
            put("tail1", 0.2)
        elif mode == "rearing":
            # On the hind legs, pelvis 52–69° up (negative flexion lifts the front; the
            # pelvis-to-neck line rises 45–80° with the noise), hind legs swung back to stand
            # vertical, forelegs folded in the air.
            pitch = -(0.9 + 0.3 * amount)
            put("pelvis", pitch)
            for side in ("l", "r"):
                put(f"hip_{side}", -0.9 * pitch)
                put(f"knee_{side}", 0.35)
                put(f"ankle_{side}", -0.35)
                put(f"shoulder_{side}", -0.2 * pitch - 0.3)
                put(f"elbow_{side}", 0.9 * amount)
                put(f"wrist_{side}", 1.1 * amount)
            put("neck1", -0.3 * pitch)
            put("head", -0.2 * pitch)
            put("tail1", 0.3)
        elif mode == "sitting_upright":
            # Sitting up on the haunches (a sitting cat or dog), revision 3: the chest 34–46°
            # up and the pelvis 1.3× as steep (the lumbar spine takes back the 0.3), so
            # the rump sits on the ground; the thighs folded forward along the ground, hocks
            # down; forelegs straight, a little ahead of the shoulders, paws on the ground;
            # the head held level; the tail laid back along the ground and curled to a side.
            side_sign = 1.0 if phase < np.pi else -1.0
            pitch = -(0.6 + 0.2 * amount)
            put("pelvis", 1.3 * pitch)
            for k in (1, 2, 3):
                put(f"spine{k}", -0.1 * pitch)
            for side in ("l", "r"):
                put(f"hip_{side}", -(1.45 + 1.3 * pitch), 0.0, 0.2)
                put(f"knee_{side}", 2.2)
                put(f"ankle_{side}", -1.4)
                put(f"shoulder_{side}", -pitch - 0.2)
            put("neck1", -0.4 * pitch)
            put("head", -0.5 * pitch)
            put("tail1", -1.6 * pitch, 0.0, 0.5 * side_sign)
            put("tail2", 0.0, 0.0, 0.5 * side_sign)
            put("tail3", 0.0, 0.0, 0.5 * side_sign)
        elif mode == "couchant":
            # Lying on the belly (sternal recumbency: a crouching cat, a sphinx): the hind
            # legs folded under the trunk, the upper forelegs back and the forearms forward
            # along the ground, head up.
            for side in ("l", "r"):
                put(f"hip_{side}", -1.3, 0.0, 0.2)
                put(f"knee_{side}", 2.2)
                put(f"ankle_{side}", -1.3)
                put(f"shoulder_{side}", 0.9)
                put(f"elbow_{side}", -2.0)
                put(f"wrist_{side}", 0.3)
            put("neck1", -0.3 * amount)
            put("head", 0.3)
            put("tail1", 0.3)
        elif mode == "leaping":
            # Airborne, legs stretched fore and aft (extended gallop or a jump).
            put("pelvis", -0.2 * amount)
            for side in ("l", "r"):
                put(f"shoulder_{side}", -1.2 * amount)
                put(f"elbow_{side}", 0.1)
                put(f"wrist_{side}", 0.3)
                put(f"hip_{side}", 0.9 * amount)
                put(f"knee_{side}", 0.2)
                put(f"ankle_{side}", 0.2)
            put("tail1", -0.3)
    else:
        arms_down = -0.6
        if mode == "standing":
            for side in ("l", "r"):
                put(f"shoulder_{side}", 0.0, 0.0, arms_down)
                put(f"elbow_{side}", 0.15)
        elif mode == "walking":
            for side, offset in (("l", 0.0), ("r", np.pi)):
                s = np.sin(phase + offset)
                lift = max(0.0, np.cos(phase + offset))
                put(f"hip_{side}", -0.45 * amount * s)
                put(f"knee_{side}", 0.7 * amount * lift + 0.05)
                put(f"ankle_{side}", -0.2 * amount * lift)
                put(f"shoulder_{side}", 0.35 * amount * s, 0.0, arms_down)
                put(f"elbow_{side}", 0.3 + 0.2 * amount * (1 - s))
        elif mode == "arms_raised":
            for side in ("l", "r"):
                put(f"collar_{side}", 0.0, 0.0, 0.3)
                put(f"shoulder_{side}", -0.2 * amount, 0.0, 1.1 + 0.5 * amount)
                put(f"elbow_{side}", 0.3 * amount)
        elif mode == "crouching":
            depth = 0.7 + 0.3 * amount
            put("spine1", 0.25 * depth)
            put("spine2", 0.15 * depth)
            for side in ("l", "r"):
                put(f"hip_{side}", -1.05 * depth, 0.0, 0.25)
                put(f"knee_{side}", 1.3 * depth)
                put(f"ankle_{side}", -0.3 * depth)
                put(f"shoulder_{side}", -0.6, 0.0, arms_down)
                put(f"elbow_{side}", 0.6)
    return out


def posture_offsets(
    skeleton: Skeleton, posture: dict[str, tuple[float, float, float]] | None
) -> NDArray:
    """``(J, 3)`` anatomical offsets from a family posture (keyed by name without side)."""
    out = np.zeros((skeleton.n_joints, 3))
    for j, name in enumerate(skeleton.names):
        extra = (posture or {}).get(_base(name)[0])
        if extra is not None:
            out[j] = extra
    return out


def to_rotation_vectors(category: str, skeleton: Skeleton, anatomical: NDArray) -> NDArray:
    """Map ``(J, 3)`` anatomical components to world-axis rotation vectors (mirroring the
    right side)."""
    frames = joint_frames(category, skeleton)
    omega = np.einsum("jab,jb->ja", frames, anatomical)
    right = np.array([_base(n)[1] == "_r" for n in skeleton.names])
    omega[right] *= np.array([1.0, -1.0, -1.0])
    return omega


def sample_pose(
    category: str,
    mode: str,
    skeleton: Skeleton,
    rng: np.random.Generator,
    noise_std: float = NOISE_STD,
    posture: dict[str, tuple[float, float, float]] | None = None,
    mode_scale: float = 1.0,
) -> Pose:
    """Draw a pose of ``mode``: offsets plus clipped Gaussian noise, within joint limits.

    ``posture`` adds family-typical offsets (anatomical components, keyed by joint name
    without side suffix) on top of the mode's; ``mode_scale`` shrinks the mode's offsets
    (used to back off a fold that makes a thick-limbed family intersect itself).
    """
    limits_table = LIMITS[category]
    offsets = mode_scale * mode_offsets(category, mode, skeleton, rng)
    offsets += posture_offsets(skeleton, posture)
    noise = np.clip(rng.standard_normal((skeleton.n_joints, 3)), -2.0, 2.0) * noise_std
    anatomical = np.zeros((skeleton.n_joints, 3))
    for j, name in enumerate(skeleton.names):
        limits, scale = limits_table[_base(name)[0]]
        lo = np.array([limits[k][0] for k in range(3)])
        hi = np.array([limits[k][1] for k in range(3)])
        # Mode offsets may go past the noise limits (sitting folds a knee fully): the
        # clip range always contains the offset.
        value = offsets[j] + noise[j] * scale
        anatomical[j] = np.clip(value, np.minimum(lo, offsets[j]), np.maximum(hi, offsets[j]))
    return Pose(mode, to_rotation_vectors(category, skeleton, anatomical), np.zeros(3))


__all__ = [
    "BIPED_LIMITS",
    "BIPED_MODES",
    "CONTACT_MODES",
    "EXTRA_MODES",
    "LIMITS",
    "MAKEHUMAN_STEEP_MODES",
    "MODES",
    "NOISE_STD",
    "QUADRUPED_LIMITS",
    "QUADRUPED_MODES",
    "QUADRUPED_STEEP_MODES",
    "STEEP_REVISION",
    "Limits",
    "Pose",
    "check_steep_share",
    "joint_frames",
    "known_modes",
    "mode_offsets",
    "posture_offsets",
    "sample_pose",
    "steep_pose",
    "steep_tag",
    "to_rotation_vectors",
]
