"""Generate one shape: a pure function of (category, family, seed).

The template is deformed by the family's shape factors (per-bone length and girth through
the skinning weights), then posed by linear blend skinning, grounded (lowest point at
``y = 0``) and, for bipeds, scaled to the sampled height. Every shape of a category has the
template's faces: vertex ``i`` corresponds across all shapes of the category.

Poses that make the surface intersect itself are redrawn from the same random stream (so the
result stays deterministic): three fresh draws, then draws with the mode's folds and the noise
backed off (``BACKOFF``); the last draw is kept whatever it gives.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from litege_core.errors import InputError
from litege_core.shape import Shape
from litege_core.synth.poses import (
    CONTACT_MODES,
    MODES,
    NOISE_STD,
    Pose,
    known_modes,
    posture_offsets,
    sample_pose,
    to_rotation_vectors,
)
from litege_core.synth.quality import self_intersects
from litege_core.synth.shape_space import (
    FAMILIES,
    GIRTH_STREAM,
    bone_scales,
    draw_girth,
    mean_factors,
    sample_factors,
    with_girth,
)
from litege_core.synth.skinning import axis_angle_to_matrix, blend, pose_maps, scale_maps
from litege_core.synth.templates import Template, check_category, template

#: (mode offset scale, noise scale) of successive pose draws when a draw self-intersects:
#: three fresh draws of the full pose, then the mode's folds are backed off step by step.
BACKOFF = ((1.0, 1.0), (1.0, 1.0), (1.0, 1.0), (0.8, 1.0), (0.65, 0.8), (0.5, 0.6), (0.3, 0.5))
#: Probability of each pose mode when none is requested (order of ``MODES[category]``).
MODE_WEIGHTS = {"quadruped": (0.25, 0.35, 0.2, 0.2), "biped": (0.3, 0.3, 0.2, 0.2)}


@dataclass(frozen=True, eq=False)
class GeneratedShape:
    """A generated shape.

    Attributes:
        vertices: ``(V, 3)`` float64 (quadrupeds: trunk length ≈ 1; bipeds: metres).
        faces: ``(F, 3)`` int64, the category template's faces (shared, read-only).
        category, family, seed: what generated it.
        pose: pose mode name.
        params: shape factors, plus ``pose_attempts`` (draws needed to avoid intersection).
        joints: ``(J, 3)`` posed joint positions in the same frame as ``vertices``.
    """

    vertices: NDArray
    faces: NDArray
    category: str
    family: str
    seed: int
    pose: str
    params: dict[str, float] = field(default_factory=dict)
    joints: NDArray | None = None

    def to_shape(self) -> Shape:
        """The mesh as a validated :class:`~litege_core.shape.Shape`."""
        return Shape.from_arrays(self.vertices, self.faces)


def families(category: str) -> tuple[str, ...]:
    """Family names of ``category``."""
    return tuple(FAMILIES[check_category(category)])


def pose_modes(category: str) -> tuple[str, ...]:
    """Every pose mode :func:`generate_shape` accepts for ``category``: the modes seeds draw
    (``poses.MODES``), then those generated only when asked for (``poses.EXTRA_MODES``)."""
    return known_modes(check_category(category))


def symmetry_map(category: str) -> NDArray:
    """``(V,)`` left-right map of the template (and every generated rest shape)."""
    return template(category).symmetry


def _rng(category: str, family: str, seed: int) -> np.random.Generator:
    key = zlib.crc32(f"{category}/{family}".encode())
    return np.random.default_rng(np.random.SeedSequence([key, int(seed)]))


def shape_rest(tmpl: Template, factors: dict[str, float]) -> tuple[NDArray, NDArray]:
    """Deform the template by shape factors; returns rest vertices ``(V, 3)`` and joints
    ``(J, 3)`` (not grounded)."""
    skel = tmpl.skeleton
    scales = bone_scales(tmpl.category, skel, factors)
    linear, joints = scale_maps(skel, scales)
    vertices = blend(tmpl.vertices, tmpl.shape_weights, linear, skel.positions, joints)
    return vertices, joints


def apply_pose(
    tmpl: Template, vertices: NDArray, joints: NDArray, pose: Pose
) -> tuple[NDArray, NDArray]:
    """Pose shaped rest ``vertices``/``joints`` by linear blend skinning."""
    rotations = axis_angle_to_matrix(pose.rotations)
    world, posed_joints = pose_maps(tmpl.skeleton.parents, joints, rotations, pose.root_translation)
    return blend(vertices, tmpl.weights, world, joints, posed_joints), posed_joints


def _draw_mode(category: str, rng: np.random.Generator) -> str:
    modes = MODES[category]
    return modes[int(rng.choice(len(modes), p=MODE_WEIGHTS[category]))]


def girth_multiplier(category: str, family: str, seed: int, girth_std: float) -> float:
    """The build multiplier of shape ``(category, family, seed)``
    (:func:`~litege_core.synth.shape_space.draw_girth`), from a stream apart from the shape's
    factors and pose."""
    key = zlib.crc32(f"{category}/{family}".encode())
    return draw_girth(
        np.random.default_rng(np.random.SeedSequence([key, int(seed), GIRTH_STREAM])), girth_std
    )


def drawn_pose_mode(category: str, family: str, seed: int) -> str:
    """The pose mode :func:`generate_shape` draws for ``(category, family, seed)`` (without
    generating the shape: microseconds)."""
    rng = _rng(category, family, seed)
    sample_factors(category, family, rng)
    return _draw_mode(category, rng)


def generate_shape(
    category: str,
    family: str,
    seed: int,
    pose: str | None = None,
    *,
    reject: bool = True,
    mean_shape: bool = False,
    rest_pose: bool = False,
    spread: float = 1.0,
    girth_std: float = 0.0,
) -> GeneratedShape:
    """Generate the shape ``(category, family, seed)``.

    Args:
        category: ``"quadruped"`` or ``"biped"``.
        family: one of :func:`families`.
        seed: any non-negative integer.
        pose: a mode of :func:`pose_modes`; ``None`` draws one from the seed.
        reject: redraw poses that self-intersect (costs ~0.1 s per check).
        mean_shape: use the family's mean factors instead of sampling them.
        rest_pose: skip posing (the template's standing pose).
        spread: multiplier of the family's proportion range
            (:func:`~litege_core.synth.shape_space.sample_factors`); the pose drawn from the
            seed does not depend on it.
        girth_std: log standard deviation of a build multiplier shared by the girth factors
            (:func:`~litege_core.synth.shape_space.with_girth`), drawn from a stream of its
            own: 0 leaves the shape as it was, and the pose never changes.
    """
    check_category(category)
    if family not in FAMILIES[category]:
        raise InputError(
            f"unknown {category} family {family!r}; expected one of {families(category)}"
        )
    if seed < 0:
        raise InputError("seed must be non-negative")
    rng = _rng(category, family, seed)
    tmpl = template(category)
    fam = FAMILIES[category][family]
    factors = sample_factors(category, family, rng, spread)
    if mean_shape:
        factors = mean_factors(category, family)
    if girth_std:
        factors = with_girth(category, factors, girth_multiplier(category, family, seed, girth_std))
    modes = pose_modes(category)
    drawn_mode = _draw_mode(category, rng)
    mode = drawn_mode if pose is None else pose
    if mode not in modes:
        raise InputError(f"unknown {category} pose mode {mode!r}; expected one of {modes}")
    rest_vertices, rest_joints = shape_rest(tmpl, factors)
    scale = factors.get("height", 1.0)
    attempts = 0
    if rest_pose:
        anatomical = posture_offsets(tmpl.skeleton, fam.posture)
        rotations = to_rotation_vectors(category, tmpl.skeleton, anatomical)
        rest = Pose("rest", rotations, np.zeros(3))
        vertices, joints = apply_pose(tmpl, rest_vertices, rest_joints, rest)
        mode = "rest"
    else:
        for attempts in range(1, len(BACKOFF) + 1):
            mode_scale, noise_scale = BACKOFF[attempts - 1]
            sampled = sample_pose(
                category,
                mode,
                tmpl.skeleton,
                rng,
                noise_std=noise_scale * NOISE_STD,
                posture=fam.posture,
                mode_scale=mode_scale,
            )
            vertices, joints = apply_pose(tmpl, rest_vertices, rest_joints, sampled)
            if not reject or mode in CONTACT_MODES or not self_intersects(vertices, tmpl.faces):
                break
    ground = np.array([0.0, vertices[:, 1].min(), 0.0])
    vertices = (vertices - ground) * scale
    joints = (joints - ground) * scale
    params = dict(factors)
    params["pose_attempts"] = float(attempts)
    vertices.setflags(write=False)
    return GeneratedShape(
        vertices=vertices,
        faces=tmpl.faces,
        category=category,
        family=family,
        seed=int(seed),
        pose=mode,
        params=params,
        joints=joints,
    )


__all__ = [
    "BACKOFF",
    "MODE_WEIGHTS",
    "GeneratedShape",
    "apply_pose",
    "drawn_pose_mode",
    "families",
    "generate_shape",
    "girth_multiplier",
    "pose_modes",
    "shape_rest",
    "symmetry_map",
]
