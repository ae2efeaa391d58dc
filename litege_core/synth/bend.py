"""Body bends: curl, turn and arch a posed animal along its spine (issue 14, step 3).

Real animals lie curled, turn their heads back, arch or hunch their backs; animation clips
and joint noise rarely do, and on the Quaternius rigs a spine joint cannot be rotated at all
(the feet hang on IK bones parented to the root: rotating the spine would tear them off). A
bend deforms the posed surface instead, like a sculptor's curve deformer: the body's forward
axis becomes a space curve whose curvature is a smooth bump along it, and every point keeps
its offset from that axis in the curve's moving frame::

    body coordinates  p = (s, l, u)   s forward, l lateral, u up (centred on the body)
    curvatures        κ_l(s) = Θ_l · g_l(s),  κ_u(s) = Θ_u · g_u(s)   (rad per unit length;
                      g a Gaussian bump along s normalised to unit integral, so Θ is the total
                      turn: Θ_l about the up axis, a sideways curl; Θ_u about the lateral
                      axis, an arch or a hunch)
    frame             R'(s) = R(s) · [ω(s)]×,  ω = (0, κ_u, κ_l) in (s, l, u) axes,  R(0) = I
    centre line       c'(s) = R(s) e_s,  c(0) = 0
    bent point        p' = c(s) + R(s) · (0, l, u)

The body's centre (``s = 0``, clamped to the forward extent) keeps its place and direction, so
a bent body keeps its mean heading: the canonical frame of the straight body still fits it.

Legs, head and tail move with the cross-section they hang from, so feet stay on their legs. A
point at offset ``d`` on the inner side of a bend is compressed by ``1 − κ d``; each bend is
scaled down until ``max |κ| · d_max ≤ max_compression`` (``d_max``: the body's largest offset
in the bend's plane), so no part folds through itself.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from litege_core.errors import InputError
from litege_core.synth.skinning import axis_angle_to_matrix

CURVE_SAMPLES = 513
"""Samples of the centre line along the forward extent (the frame is integrated on them)."""


@dataclass(frozen=True)
class BendSettings:
    """Random bends (see the module docstring); ``probability = 0`` draws nothing.

    Attributes:
        probability: share of shapes that are bent.
        lateral_degrees: largest total sideways turn ``|Θ_l|`` (a curl, a head turned back).
        vertical_degrees: largest total arch or hunch ``|Θ_u|``.
        width_range: bump width (standard deviation) as a fraction of the body length.
        max_compression: cap on ``|κ| · d_max`` (inner-side compression of a bend).
    """

    probability: float = 0.0
    lateral_degrees: float = 140.0
    vertical_degrees: float = 40.0
    width_range: tuple[float, float] = (0.12, 0.45)
    max_compression: float = 0.6

    def __post_init__(self) -> None:
        if not 0.0 <= self.probability <= 1.0:
            raise InputError(f"bend probability must be in [0, 1], got {self.probability}")
        if self.lateral_degrees < 0 or self.vertical_degrees < 0:
            raise InputError("bend angles must be non-negative")
        low, high = self.width_range
        if not 0.0 < low <= high:
            raise InputError(f"bend width_range must satisfy 0 < low <= high, got {low, high}")
        if not 0.0 < self.max_compression < 1.0:
            raise InputError("bend max_compression must be in (0, 1)")

    def describe(self) -> str:
        """A compact, stable description (part of a dataset factory's version)."""
        low, high = self.width_range
        return (
            f"bend(p={self.probability:g},lat={self.lateral_degrees:g},"
            f"vert={self.vertical_degrees:g},w={low:g}-{high:g},c={self.max_compression:g},"
            "anchor=centre)"
        )


@dataclass(frozen=True)
class Bend:
    """One drawn bend: total turns (rad) and bump centres / widths (fractions of the length)."""

    lateral: float
    vertical: float
    lateral_centre: float
    lateral_width: float
    vertical_centre: float
    vertical_width: float


def bump(s: NDArray, start: float, length: float, centre: float, width: float) -> NDArray:
    """A Gaussian along ``s`` (centre and width as fractions of ``length``), normalised so
    that its integral over ``[start, start + length]`` is 1 (units: 1 / length)."""
    t = (s - start) / length
    g = np.exp(-0.5 * ((t - centre) / width) ** 2)
    grid = np.linspace(0.0, 1.0, CURVE_SAMPLES)
    norm = np.trapezoid(np.exp(-0.5 * ((grid - centre) / width) ** 2), grid) * length
    return g / norm


def bend_body(points: NDArray, bend: Bend) -> NDArray:
    """Bend ``(V, 3)`` body coordinates ``(s, l, u)`` (see the module docstring); returns the
    bent points in the same coordinates (the cross-section at ``s = 0`` stays put)."""
    points = np.asarray(points, dtype=np.float64)
    s0, s1 = float(points[:, 0].min()), float(points[:, 0].max())
    length = max(s1 - s0, 1e-12)
    s = np.linspace(s0, s1, CURVE_SAMPLES)
    kappa_l = bend.lateral * bump(s, s0, length, bend.lateral_centre, bend.lateral_width)
    kappa_u = bend.vertical * bump(s, s0, length, bend.vertical_centre, bend.vertical_width)
    step = np.diff(s)
    mid_kappa_l = 0.5 * (kappa_l[1:] + kappa_l[:-1])
    mid_kappa_u = 0.5 * (kappa_u[1:] + kappa_u[:-1])
    omega = np.stack([np.zeros_like(step), mid_kappa_u, mid_kappa_l], axis=1) * step[:, None]
    increments = axis_angle_to_matrix(omega)
    halves = axis_angle_to_matrix(0.5 * omega)  # the step's tangent at its midpoint
    frames = np.empty((CURVE_SAMPLES, 3, 3))
    frames[0] = np.eye(3)
    centres = np.empty((CURVE_SAMPLES, 3))
    centres[0] = (s0, 0.0, 0.0)
    for i in range(CURVE_SAMPLES - 1):  # 512 small steps per shape: cheap beside remeshing
        centres[i + 1] = centres[i] + (frames[i] @ halves[i])[:, 0] * step[i]
        frames[i + 1] = frames[i] @ increments[i]
    anchor = int(np.clip(np.rint(-s0 / length * (CURVE_SAMPLES - 1)), 0, CURVE_SAMPLES - 1))
    centres = (centres - centres[anchor]) @ frames[anchor] + (s[anchor], 0.0, 0.0)
    frames = np.einsum("ba,sbc->sac", frames[anchor], frames)  # R_anchorᵀ · R(s)
    position = (points[:, 0] - s0) / length * (CURVE_SAMPLES - 1)
    lower = np.clip(np.floor(position).astype(int), 0, CURVE_SAMPLES - 2)
    weight = (position - lower)[:, None]
    centre = (1.0 - weight) * centres[lower] + weight * centres[lower + 1]
    frame = frames[lower] + weight[:, :, None] * (frames[lower + 1] - frames[lower])
    offsets = np.stack([np.zeros(len(points)), points[:, 1], points[:, 2]], axis=1)
    return centre + np.einsum("vab,vb->va", frame, offsets)


def draw_bend(rng: np.random.Generator, points: NDArray, settings: BendSettings) -> Bend | None:
    """A random bend of ``(V, 3)`` body coordinates ``(s, l, u)`` (``None``: not bent this
    time); draws nothing from ``rng`` when ``settings.probability`` is 0."""
    if settings.probability <= 0.0:
        return None
    values = rng.uniform(size=7)
    if values[0] >= settings.probability:
        return None
    low, high = settings.width_range
    length = float(np.ptp(points[:, 0])) or 1.0
    lateral = np.radians(settings.lateral_degrees) * (2.0 * values[1] - 1.0)
    vertical = np.radians(settings.vertical_degrees) * (2.0 * values[2] - 1.0)
    lateral_centre, vertical_centre = 0.1 + 0.8 * values[3], 0.1 + 0.8 * values[4]
    lateral_width = low + (high - low) * values[5]
    vertical_width = low + (high - low) * values[6]
    for index, (turn, width, column) in enumerate(
        ((lateral, lateral_width, 1), (vertical, vertical_width, 2))
    ):
        # Peak curvature of a unit-integral Gaussian ≈ Θ / (√(2π) w L); cap |κ| d_max.
        reach = float(np.abs(points[:, column]).max())
        peak = abs(turn) / (np.sqrt(2.0 * np.pi) * width * length)
        if peak * reach > settings.max_compression:
            scale = settings.max_compression / (peak * reach)
            if index == 0:
                lateral *= scale
            else:
                vertical *= scale
    return Bend(
        float(lateral),
        float(vertical),
        float(lateral_centre),
        float(lateral_width),
        float(vertical_centre),
        float(vertical_width),
    )


def body_axes(rest: NDArray, up: int = 1) -> NDArray:
    """``(3, 3)`` rows ``(forward, lateral, up)`` of a y-up rest pose ``(V, 3)``: forward is the
    longer horizontal extent; lateral completes a right-handed frame."""
    horizontal = [axis for axis in range(3) if axis != up]
    extents = np.ptp(rest[:, horizontal], axis=0)
    forward_axis = horizontal[int(np.argmax(extents))]
    forward = np.eye(3)[forward_axis]
    upward = np.eye(3)[up]
    lateral = np.cross(upward, forward)
    return np.stack([forward, lateral, upward])


def random_bend(
    rng: np.random.Generator, vertices: NDArray, axes: NDArray, settings: BendSettings
) -> tuple[NDArray, Bend | None]:
    """Bend ``(V, 3)`` world vertices with body ``axes`` (:func:`body_axes`) at random; returns
    the vertices (unchanged when not bent) and the bend drawn."""
    centre = vertices.mean(axis=0)
    body = (vertices - centre) @ axes.T
    bend = draw_bend(rng, body, settings)
    if bend is None:
        return vertices, None
    return bend_body(body, bend) @ axes + centre, bend


__all__ = ["Bend", "BendSettings", "bend_body", "body_axes", "bump", "draw_bend", "random_bend"]
