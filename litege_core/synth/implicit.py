"""Implicit body surfaces: signed-distance primitives blended with a smooth minimum.

A body is a tree of :class:`Blend` nodes whose leaves are :class:`RoundCone` (a capsule whose
radius varies linearly along its axis: the convex hull of two balls) and :class:`Ellipsoid`
primitives. Every primitive carries a ``tag`` (the skeleton part it belongs to), so the
template builder can ask which part dominates at a surface point (used to seed skinning).

Distances are in template units (trunk length L = 1). Fields are negative inside, positive
outside; they are exact for round cones and a good first-order bound for ellipsoids, which is
all marching tetrahedra and Newton projection need.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray


def smooth_min(a: NDArray, b: NDArray, k: float) -> NDArray:
    """Polynomial smooth minimum of two fields (C1, exact ``min`` where ``|a − b| ≥ k``).

    Args:
        a, b: ``(N,)`` field values.
        k: blend radius in template units (``k = 0`` gives the hard minimum).
    """
    if k <= 0.0:
        return np.minimum(a, b)
    h = np.maximum(k - np.abs(a - b), 0.0) / k
    return np.minimum(a, b) - h * h * k * 0.25


@dataclass(frozen=True)
class RoundCone:
    """Convex hull of the balls ``B(a, ra)`` and ``B(b, rb)``; exact signed distance."""

    a: tuple[float, float, float]
    b: tuple[float, float, float]
    ra: float
    rb: float
    tag: str

    def distance(self, points: NDArray) -> NDArray:
        """``(N,)`` signed distance of ``(N, 3)`` points."""
        a = np.asarray(self.a, dtype=np.float64)
        ba = np.asarray(self.b, dtype=np.float64) - a
        l2 = float(ba @ ba)
        rr = self.ra - self.rb
        a2 = l2 - rr * rr
        il2 = 1.0 / l2
        pa = points - a
        y = pa @ ba
        z = y - l2
        x2 = np.einsum("ij,ij->i", pa * l2 - y[:, None] * ba, pa * l2 - y[:, None] * ba)
        y2 = y * y * l2
        z2 = z * z * l2
        k = np.sign(rr) * rr * rr * x2
        cap_b = np.sqrt(x2 + z2) * il2 - self.rb
        cap_a = np.sqrt(x2 + y2) * il2 - self.ra
        side = (np.sqrt(np.maximum(x2 * a2 * il2, 0.0)) + y * rr) * il2 - self.ra
        out = np.where(np.sign(y) * a2 * y2 < k, cap_a, side)
        return np.where(np.sign(z) * a2 * z2 > k, cap_b, out)

    def mirrored(self, tag: str) -> RoundCone:
        """The same cone reflected through the plane ``x = 0``."""
        return RoundCone(_mirror(self.a), _mirror(self.b), self.ra, self.rb, tag)


@dataclass(frozen=True)
class Ellipsoid:
    """Ellipsoid with semi-axes ``radii`` along the columns of ``axes`` (a rotation)."""

    center: tuple[float, float, float]
    radii: tuple[float, float, float]
    tag: str
    axes: tuple[tuple[float, float, float], ...] = (
        (1.0, 0.0, 0.0),
        (0.0, 1.0, 0.0),
        (0.0, 0.0, 1.0),
    )

    def distance(self, points: NDArray) -> NDArray:
        """``(N,)`` approximate signed distance (Quílez's k0·(k0 − 1)/k1 bound)."""
        local = (points - np.asarray(self.center)) @ np.asarray(self.axes, dtype=np.float64)
        r = np.asarray(self.radii, dtype=np.float64)
        k0 = np.linalg.norm(local / r, axis=1)
        k1 = np.maximum(np.linalg.norm(local / (r * r), axis=1), 1e-12)
        return k0 * (k0 - 1.0) / k1

    def mirrored(self, tag: str) -> Ellipsoid:
        """The same ellipsoid reflected through the plane ``x = 0``."""
        m = np.diag([-1.0, 1.0, 1.0]) @ np.asarray(self.axes, dtype=np.float64)
        m[:, 0] *= -1.0  # keep a proper rotation: flip the first local axis back
        return Ellipsoid(_mirror(self.center), self.radii, tag, as_vec3s(m))


Primitive = RoundCone | Ellipsoid


@dataclass(frozen=True)
class Blend:
    """Smooth union (radius ``k``) of children, folded left to right."""

    children: tuple[Primitive | Blend, ...]
    k: float = 0.0
    tag: str = field(default="")

    def distance(self, points: NDArray) -> NDArray:
        """``(N,)`` blended signed distance."""
        out = self.children[0].distance(points)
        for child in self.children[1:]:
            out = smooth_min(out, child.distance(points), self.k)
        return out

    def leaves(self) -> list[Primitive]:
        """All primitives under this node, depth first."""
        found: list[Primitive] = []
        for child in self.children:
            found.extend(child.leaves() if isinstance(child, Blend) else [child])
        return found


def blend(children: Sequence[Primitive | Blend], k: float) -> Blend:
    """Convenience constructor for :class:`Blend`."""
    return Blend(tuple(children), float(k))


def dominant_tags(body: Blend, points: NDArray) -> list[str]:
    """Tag of the primitive with the smallest distance at each of ``(N, 3)`` points."""
    leaves = body.leaves()
    dist = np.stack([leaf.distance(points) for leaf in leaves], axis=1)
    return [leaves[i].tag for i in np.argmin(dist, axis=1)]


def field_gradient(body: Blend, points: NDArray, step: float = 1e-4) -> NDArray:
    """``(N, 3)`` central-difference gradient of the body field."""
    grads = np.empty_like(points)
    for axis in range(3):
        offset = np.zeros(3)
        offset[axis] = step
        grads[:, axis] = (body.distance(points + offset) - body.distance(points - offset)) / (
            2.0 * step
        )
    return grads


def project_to_surface(
    body: Blend, points: ArrayLike, iterations: int = 4, max_step: float = 0.05
) -> NDArray:
    """Newton-project ``(N, 3)`` points onto the zero level set of ``body``.

    Each step moves by at most ``max_step`` so points near thin parts do not jump across.
    """
    p = np.array(points, dtype=np.float64, copy=True)
    for _ in range(iterations):
        f = body.distance(p)
        g = field_gradient(body, p)
        g2 = np.maximum(np.einsum("ij,ij->i", g, g), 1e-12)
        delta = -(f / g2)[:, None] * g
        norm = np.linalg.norm(delta, axis=1, keepdims=True)
        p += delta * np.minimum(1.0, max_step / np.maximum(norm, 1e-15))
    return p


def _mirror(p: tuple[float, float, float]) -> tuple[float, float, float]:
    return (-p[0], p[1], p[2])


def as_vec3s(m: NDArray) -> tuple[tuple[float, float, float], ...]:
    """The rows of an ``(N, 3)`` array as tuples of Python floats (frames, centres)."""
    return tuple((float(row[0]), float(row[1]), float(row[2])) for row in m)


__all__ = [
    "Blend",
    "Ellipsoid",
    "Primitive",
    "RoundCone",
    "as_vec3s",
    "blend",
    "dominant_tags",
    "field_gradient",
    "project_to_surface",
    "smooth_min",
]
