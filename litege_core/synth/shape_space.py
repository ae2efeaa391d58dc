"""Shape families: a parametric mean per family plus log-normal variation of named factors.

A factor is a multiplicative scale relative to the template (1 = template). Each family gives
every factor a mean and a standard deviation of its logarithm; an individual draws
``mean · exp(std · N(0, 1))`` (clipped at ±2.5 σ) for each factor, and the factors map to
per-bone ``(length, width, depth)`` scales that deform the one template through its skinning
weights (:func:`litege_core.synth.skinning.scale_maps`). Lengths and girths change
independently, so the variation is non-isometric.

Template reference (quadruped, trunk length L = 1 between hip and shoulder joints): legs
(root joint to sole) 0.74, trunk half-width 0.19 and half-depth 0.24 (mean radius ≈ 0.215),
neck 0.38, head (occiput to nose) 0.37, tail 0.62. The family means below hit the design
proportions: cat legs ≈ 0.65 L and tail ≈ 0.9 L; dog legs ≈ 0.75 L; horse legs ≈ 1.05 L and neck
≈ 0.6 L; cow trunk radius ≈ 0.3 L; hippo legs ≈ 0.35 L and trunk radius ≈ 0.38 L.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from litege_core.errors import InputError
from litege_core.synth.skeleton import Skeleton

QUADRUPED_FACTORS = (
    "trunk_length",
    "trunk_width",
    "trunk_depth",
    "front_leg_length",
    "hind_leg_length",
    "upper_leg_ratio",
    "leg_girth",
    "paw_size",
    "neck_length",
    "neck_girth",
    "head_size",
    "head_width",
    "muzzle_length",
    "muzzle_width",
    "ear_length",
    "ear_width",
    "tail_length",
    "tail_girth",
)

BIPED_FACTORS = (
    "height",
    "torso_length",
    "shoulder_width",
    "hip_width",
    "body_depth",
    "belly",
    "arm_length",
    "arm_girth",
    "leg_length",
    "thigh_ratio",
    "leg_girth",
    "head_size",
    "neck_length",
    "neck_girth",
    "hand_size",
    "foot_size",
)


@dataclass(frozen=True)
class Family:
    """A family: factor means and log standard deviations (missing factors: mean 1)."""

    name: str
    means: dict[str, float]
    log_std: dict[str, float]
    default_log_std: float = 0.06
    #: Family-typical joint offsets added to every pose (anatomical components, left side;
    #: e.g. a cow's hanging tail and sideways ears), keyed by joint name without side.
    posture: dict[str, tuple[float, float, float]] = field(default_factory=dict)


def _q(
    name: str,
    means: dict[str, float],
    log_std: dict[str, float] | None = None,
    posture: dict[str, tuple[float, float, float]] | None = None,
) -> Family:
    return Family(name, means, log_std or {}, posture=posture or {})


QUADRUPED_FAMILIES: dict[str, Family] = {
    f.name: f
    for f in (
        _q(
            "cat",
            {
                "trunk_width": 0.8,
                "trunk_depth": 0.76,
                "front_leg_length": 0.87,
                "hind_leg_length": 0.9,
                "leg_girth": 0.78,
                "paw_size": 0.85,
                "neck_length": 0.65,
                "neck_girth": 0.8,
                "head_size": 0.98,
                "head_width": 1.08,
                "muzzle_length": 0.45,
                "muzzle_width": 0.9,
                "ear_length": 0.95,
                "ear_width": 1.2,
                "tail_length": 1.42,
                "tail_girth": 0.72,
            },
            posture={"ear": (0.0, 0.0, -0.15), "tail1": (0.35, 0.0, 0.0)},
        ),
        _q(
            "dog",
            {
                "trunk_width": 0.95,
                "front_leg_length": 1.01,
                "hind_leg_length": 1.01,
                "muzzle_length": 1.0,
                "tail_length": 0.85,
                "tail_girth": 0.85,
            },
            {"muzzle_length": 0.1, "ear_length": 0.12, "tail_length": 0.12},
            posture={"ear": (0.0, 0.0, -0.35)},
        ),
        _q(
            "horse",
            {
                "trunk_width": 1.02,
                "trunk_depth": 1.08,
                "front_leg_length": 1.42,
                "hind_leg_length": 1.42,
                "leg_girth": 1.0,
                "paw_size": 1.1,
                "neck_length": 1.58,
                "neck_girth": 1.25,
                "head_size": 1.05,
                "head_width": 0.95,
                "muzzle_length": 1.75,
                "muzzle_width": 1.15,
                "ear_length": 0.85,
                "ear_width": 0.85,
                "tail_length": 0.75,
                "tail_girth": 1.35,
            },
            posture={
                "neck1": (-0.15, 0.0, 0.0),
                "head": (0.45, 0.0, 0.0),
                "tail2": (-0.3, 0.0, 0.0),
                "tail3": (-0.3, 0.0, 0.0),
            },
        ),
        _q(
            "cow",
            {
                "trunk_width": 1.5,
                "trunk_depth": 1.48,
                "front_leg_length": 0.92,
                "hind_leg_length": 0.95,
                "leg_girth": 1.3,
                "paw_size": 1.3,
                "neck_length": 0.75,
                "neck_girth": 1.5,
                "head_size": 1.2,
                "muzzle_length": 1.15,
                "muzzle_width": 1.45,
                "ear_length": 0.85,
                "ear_width": 1.1,
                "tail_length": 1.3,
                "tail_girth": 0.75,
            },
            posture={
                "neck1": (0.3, 0.0, 0.0),
                "head": (0.25, 0.0, 0.0),
                "ear": (0.0, 0.0, -1.2),
                "tail2": (-0.35, 0.0, 0.0),
                "tail3": (-0.35, 0.0, 0.0),
                "tail4": (-0.3, 0.0, 0.0),
            },
        ),
        _q(
            "hippo",
            {
                "trunk_width": 2.1,
                "trunk_depth": 1.9,
                "front_leg_length": 0.42,
                "hind_leg_length": 0.42,
                "leg_girth": 1.9,
                "paw_size": 1.55,
                "neck_length": 0.6,
                "neck_girth": 2.0,
                "head_size": 1.55,
                "head_width": 1.3,
                "muzzle_length": 1.1,
                "muzzle_width": 1.9,
                "ear_length": 0.4,
                "ear_width": 0.8,
                "tail_length": 0.5,
                "tail_girth": 0.75,
            },
            {"trunk_width": 0.05, "leg_girth": 0.05, "tail_length": 0.05},
            posture={"neck1": (0.2, 0.0, 0.0)},
        ),
    )
}

BIPED_FAMILIES: dict[str, Family] = {
    f.name: f
    for f in (
        _q("average", {}, {"height": 0.05}),
        _q(
            "slim",
            {
                "shoulder_width": 0.95,
                "hip_width": 0.9,
                "body_depth": 0.82,
                "belly": 0.85,
                "arm_girth": 0.82,
                "leg_girth": 0.82,
                "leg_length": 1.05,
                "neck_girth": 0.9,
            },
            {"height": 0.05},
        ),
        _q(
            "heavy",
            {
                "shoulder_width": 1.12,
                "hip_width": 1.2,
                "body_depth": 1.3,
                "belly": 1.35,
                "arm_girth": 1.25,
                "leg_girth": 1.25,
                "leg_length": 0.95,
                "neck_girth": 1.2,
            },
            {"height": 0.05},
        ),
        _q(
            "child",
            {
                "height": 0.7,
                "torso_length": 1.0,
                "shoulder_width": 0.85,
                "hip_width": 0.9,
                "arm_length": 0.85,
                "leg_length": 0.8,
                "head_size": 1.3,
                "neck_length": 0.8,
                "hand_size": 0.9,
                "foot_size": 0.9,
            },
            {"height": 0.06},
        ),
    )
}

FAMILIES = {"quadruped": QUADRUPED_FAMILIES, "biped": BIPED_FAMILIES}
FACTORS = {"quadruped": QUADRUPED_FACTORS, "biped": BIPED_FACTORS}


def family(category: str, name: str) -> Family:
    """The family ``name`` of ``category``, or :class:`InputError`."""
    table = FAMILIES.get(category)
    if table is None:
        raise InputError(f"unknown category {category!r}; expected one of {list(FAMILIES)}")
    if name not in table:
        raise InputError(f"unknown {category} family {name!r}; expected one of {list(table)}")
    return table[name]


def sample_factors(
    category: str, name: str, rng: np.random.Generator, spread: float = 1.0
) -> dict[str, float]:
    """Draw one individual's factors (consumes exactly one normal per factor).

    ``spread`` multiplies every factor's log standard deviation: 1 gives the family's own
    range; 3 turns the default ±6 % (1 σ) into ±18 %, so that a family's limbs, girths and
    trunk cover proportions the family means alone never reach (issue 14, step 3)."""
    if not spread > 0.0:
        raise InputError(f"spread must be positive, got {spread}")
    fam = family(category, name)
    noise = np.clip(rng.standard_normal(len(FACTORS[category])), -2.5, 2.5)
    out = {}
    for factor, z in zip(FACTORS[category], noise, strict=True):
        mean = fam.means.get(factor, 1.0)
        std = fam.log_std.get(factor, fam.default_log_std) * spread
        out[factor] = float(mean * np.exp(std * z))
    return out


GIRTH_FACTORS = {
    "quadruped": ("trunk_width", "trunk_depth", "leg_girth", "neck_girth", "tail_girth"),
    "biped": ("body_depth", "belly", "arm_girth", "leg_girth", "neck_girth"),
}
"""The factors a shared girth multiplier scales together: a lean or a stocky build
(:func:`with_girth`)."""


GIRTH_STREAM = 7
"""Last entry of the seed sequence a shape's build is drawn from (apart from its factors and
pose draws)."""


def draw_girth(rng: np.random.Generator, girth_std: float) -> float:
    """A build multiplier ``exp(girth_std · z)``, ``z ~ N(0, 1)`` clipped to [−2.5, 1]: leaner
    more often than stockier, since the family means (and the rigged animals) are average to
    stocky already and real lean builds (greyhounds, deer; TOSCA's thin parts measure two
    thirds of ours at unit area, ``scripts/compare_synth_real.py``) lie far below them."""
    if girth_std < 0.0:
        raise InputError(f"girth_std must be non-negative, got {girth_std}")
    return float(np.exp(girth_std * np.clip(rng.standard_normal(), -2.5, 1.0)))


def with_girth(category: str, factors: dict[str, float], girth: float) -> dict[str, float]:
    """``factors`` with every :data:`GIRTH_FACTORS` entry multiplied by ``girth`` (< 1: a lean
    body on thin limbs, as greyhounds, deer and TOSCA's dogs and horses have; > 1: stocky)."""
    if not girth > 0.0:
        raise InputError(f"girth must be positive, got {girth}")
    return {
        name: value * girth if name in GIRTH_FACTORS[category] else value
        for name, value in factors.items()
    }


def mean_factors(category: str, name: str) -> dict[str, float]:
    """The family's mean individual."""
    fam = family(category, name)
    return {factor: float(fam.means.get(factor, 1.0)) for factor in FACTORS[category]}


def bone_scales(category: str, skeleton: Skeleton, factors: dict[str, float]) -> NDArray:
    """``(J, 3)`` per-bone (length, width, depth) scales for an individual's factors."""
    scales = np.ones((skeleton.n_joints, 3))

    def put(joint: str, length: float, width: float, depth: float) -> None:
        for name in (joint,) if joint in skeleton.names else (joint + "_l", joint + "_r"):
            scales[skeleton.index(name)] = (length, width, depth)

    f = factors
    if category == "quadruped":
        for j in ("pelvis", "spine1", "spine2", "spine3"):
            put(j, f["trunk_length"], f["trunk_width"], f["trunk_depth"])
        for j in ("neck1", "neck2"):
            put(j, f["neck_length"], f["neck_girth"], f["neck_girth"])
        head = f["head_size"]
        wide = head * f["head_width"]
        put("head", head, wide, wide)
        snout, snout_w = head * f["muzzle_length"], head * f["muzzle_width"]
        put("muzzle", snout, snout_w, snout_w)
        put("jaw", snout, snout_w, snout_w)
        put("ear", head * f["ear_length"], head * f["ear_width"], head * f["ear_width"])
        for i in range(1, 8):
            put(f"tail{i}", f["tail_length"], f["tail_girth"], f["tail_girth"])
        r, g, paw = f["upper_leg_ratio"], f["leg_girth"], f["paw_size"]
        for upper, middle, lower, foot, length in (
            ("shoulder", "elbow", "wrist", "fpaw", f["front_leg_length"]),
            ("hip", "knee", "ankle", "hpaw", f["hind_leg_length"]),
        ):
            put(upper, length * r, g, g)
            put(middle, length / r, g, g)
            put(lower, length, g * paw**0.5, g * paw**0.5)
            put(foot, paw * g**0.5, paw * g**0.5, paw * g**0.5)
    else:
        hips, shoulders, depth = f["hip_width"], f["shoulder_width"], f["body_depth"]
        torso = f["torso_length"]
        put("pelvis", torso, hips, depth)
        put("spine1", torso, 0.5 * (hips + shoulders), depth * f["belly"])
        put("spine2", torso, shoulders, depth * f["belly"] ** 0.5)
        put("spine3", torso, shoulders, depth)
        put("neck", f["neck_length"], f["neck_girth"], f["neck_girth"])
        put("head", f["head_size"], f["head_size"], f["head_size"])
        put("collar", shoulders, depth, depth)
        put("shoulder", f["arm_length"], f["arm_girth"], f["arm_girth"])
        put("elbow", f["arm_length"], f["arm_girth"], f["arm_girth"])
        put("wrist", f["hand_size"], f["hand_size"], f["hand_size"])
        put("hand", f["hand_size"], f["hand_size"], f["hand_size"])
        r, g = f["thigh_ratio"], f["leg_girth"]
        put("hip", f["leg_length"] * r, g, g)
        put("knee", f["leg_length"] / r, g, g)
        put("ankle", f["foot_size"], f["foot_size"], f["foot_size"])
        put("foot", f["foot_size"], f["foot_size"], f["foot_size"])
    return scales


def quadruped_proportions(
    vertices: NDArray, joints: NDArray, skeleton: Skeleton, parts: tuple[str, ...]
) -> dict[str, float]:
    """Body proportions of a rest-pose quadruped, in units of its trunk length L.

    ``L`` is the distance between the midpoints of the shoulder and the hip joint pairs;
    legs run from the shoulder (front) or hip (hind) joint to the lowest vertex of that leg;
    the trunk radius averages the half-width and half-depth of the trunk's vertices within
    ±10 % of L around the middle of the trunk; neck is the chain neck1→neck2→head, tail
    the chain of the 7 tail joints times 7/6 (for its last bone), head the
    occiput-to-nose chain head→muzzle→nose.
    """
    ix = skeleton.index
    shoulders = 0.5 * (joints[ix("shoulder_l")] + joints[ix("shoulder_r")])
    hips = 0.5 * (joints[ix("hip_l")] + joints[ix("hip_r")])
    trunk = float(np.linalg.norm(shoulders - hips))
    part = np.array(parts)

    def leg(root: str, group: str) -> float:
        return float(joints[ix(root), 1] - vertices[part == group, 1].min())

    mid = 0.5 * (shoulders + hips)
    axis = (shoulders - hips) / trunk
    along = (vertices - mid) @ axis
    slab = vertices[(part == "trunk") & (np.abs(along) < 0.1 * trunk)]
    radius = 0.25 * float(np.ptp(slab[:, 0]) + np.ptp(slab[:, 1]))

    def chain(names: list[str]) -> float:
        pts = joints[[ix(n) for n in names]]
        return float(np.linalg.norm(np.diff(pts, axis=0), axis=1).sum())

    tail_names = [f"tail{i}" for i in range(1, 8)]
    nose = _farthest(vertices[part == "muzzle"], joints[ix("head")])
    return {
        "trunk_length": trunk,
        "front_leg": leg("shoulder_l", "fleg_l") / trunk,
        "hind_leg": leg("hip_l", "hleg_l") / trunk,
        "trunk_radius": radius / trunk,
        "neck": chain(["neck1", "neck2", "head"]) / trunk,
        "head": (chain(["head", "muzzle"]) + float(np.linalg.norm(nose - joints[ix("muzzle")])))
        / trunk,
        "tail": chain(tail_names) * 7.0 / 6.0 / trunk,
    }


def _farthest(points: NDArray, origin: NDArray) -> NDArray:
    """The point of ``(N, 3)`` points farthest from ``origin``."""
    return points[np.argmax(np.linalg.norm(points - origin, axis=1))]


__all__ = [
    "BIPED_FACTORS",
    "BIPED_FAMILIES",
    "FACTORS",
    "FAMILIES",
    "GIRTH_FACTORS",
    "GIRTH_STREAM",
    "QUADRUPED_FACTORS",
    "QUADRUPED_FAMILIES",
    "Family",
    "bone_scales",
    "draw_girth",
    "family",
    "mean_factors",
    "quadruped_proportions",
    "sample_factors",
    "with_girth",
]
