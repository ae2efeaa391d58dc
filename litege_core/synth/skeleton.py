"""Kinematic skeletons: joints, parents, rest positions and bone segments.

Each joint ``j`` owns one bone segment from ``positions[j]`` to ``tips[j]`` (its principal
child, or a free end for leaves such as the nose or a tail tip). Skinning assigns vertices to
these segments; shape variation scales each segment along its axis (length) and across it
(girth); posing rotates each joint about its rest position.

Template frame: x lateral (left = +x, the symmetry plane is x = 0), y up (ground at y = 0),
z forward (the direction the animal or person faces). Units: template units, where the
quadruped's trunk length (hip joint to shoulder joint) is 1.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
from numpy.typing import NDArray

from litege_core.errors import InputError


@dataclass(frozen=True)
class Skeleton:
    """A rest-pose skeleton.

    Attributes:
        names: ``J`` joint names; left/right joints end in ``_l`` / ``_r``.
        parents: ``(J,)`` int64 parent index, ``-1`` for the root (joint 0); parents precede
            their children.
        positions: ``(J, 3)`` float64 rest joint positions.
        tips: ``(J, 3)`` float64 end point of each joint's bone segment.
        groups: ``J`` body-part names (``"trunk"``, ``"leg_fl"``, ...) used to seed skinning.
    """

    names: tuple[str, ...]
    parents: NDArray
    positions: NDArray
    tips: NDArray
    groups: tuple[str, ...]

    def __post_init__(self) -> None:
        n = len(self.names)
        if self.parents.shape != (n,) or self.positions.shape != (n, 3):
            raise InputError("skeleton arrays disagree on the joint count")
        if self.parents[0] != -1 or np.any(self.parents[1:] >= np.arange(1, n)):
            raise InputError("joint 0 must be the root and parents must precede children")

    @property
    def n_joints(self) -> int:
        return len(self.names)

    def index(self, name: str) -> int:
        """Index of the joint called ``name``."""
        try:
            return self.names.index(name)
        except ValueError as exc:
            raise InputError(f"no joint named {name!r}") from exc

    @cached_property
    def mirror(self) -> NDArray:
        """``(J,)`` index of each joint's mirror image (itself for midline joints)."""
        out = np.arange(self.n_joints)
        for j, name in enumerate(self.names):
            for a, b in (("_l", "_r"), ("_r", "_l")):
                if name.endswith(a):
                    out[j] = self.names.index(name[: -len(a)] + b)
        return out

    @cached_property
    def children(self) -> tuple[tuple[int, ...], ...]:
        """Children of each joint."""
        kids: list[list[int]] = [[] for _ in range(self.n_joints)]
        for j, p in enumerate(self.parents.tolist()):
            if p >= 0:
                kids[p].append(j)
        return tuple(tuple(k) for k in kids)


class SkeletonBuilder:
    """Accumulates joints in parent-first order (a small helper for the anatomy modules)."""

    def __init__(self) -> None:
        self._names: list[str] = []
        self._parents: list[int] = []
        self._positions: list[tuple[float, float, float]] = []
        self._tips: list[tuple[float, float, float] | None] = []
        self._groups: list[str] = []

    def add(
        self,
        name: str,
        parent: str | None,
        position: tuple[float, float, float],
        group: str,
        tip: tuple[float, float, float] | None = None,
    ) -> None:
        """Add a joint; ``tip`` defaults to the position of the next joint added with this
        joint as parent (set by :meth:`build`)."""
        self._names.append(name)
        self._parents.append(-1 if parent is None else self._names.index(parent))
        self._positions.append(position)
        self._tips.append(tip)
        self._groups.append(group)

    def add_mirrored(
        self,
        name: str,
        parent: str | None,
        position: tuple[float, float, float],
        group: str,
        tip: tuple[float, float, float] | None = None,
    ) -> None:
        """Add ``name_l`` at ``position`` and ``name_r`` at its mirror image (x → −x).
        ``parent`` and ``group`` ending in ``_l`` are mirrored too."""
        for side, sign in (("_l", 1.0), ("_r", -1.0)):
            p_name = None if parent is None else _side(parent, side)
            mirrored = (sign * position[0], position[1], position[2])
            mtip = None if tip is None else (sign * tip[0], tip[1], tip[2])
            self.add(name + side, p_name, mirrored, _side(group, side), mtip)

    def build(self) -> Skeleton:
        positions = np.array(self._positions, dtype=np.float64)
        tips = []
        for j, tip in enumerate(self._tips):
            if tip is None:
                kids = [k for k, p in enumerate(self._parents) if p == j]
                if not kids:
                    raise InputError(f"leaf joint {self._names[j]!r} needs an explicit tip")
                tips.append(positions[kids[0]])
            else:
                tips.append(np.array(tip, dtype=np.float64))
        return Skeleton(
            names=tuple(self._names),
            parents=np.array(self._parents, dtype=np.int64),
            positions=positions,
            tips=np.array(tips),
            groups=tuple(self._groups),
        )


def _side(name: str, side: str) -> str:
    if name.endswith("_l"):
        return name[:-2] + side
    return name


def point_segment_distance(points: NDArray, a: NDArray, b: NDArray) -> NDArray:
    """``(N, S)`` distances from ``(N, 3)`` points to ``S`` segments ``a (S, 3) → b (S, 3)``."""
    ab = b - a
    denom = np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-18)
    t = np.einsum("nsk,sk->ns", points[:, None, :] - a[None], ab) / denom
    t = np.clip(t, 0.0, 1.0)
    closest = a[None] + t[..., None] * ab[None]
    return np.linalg.norm(points[:, None, :] - closest, axis=2)


__all__ = [
    "Skeleton",
    "SkeletonBuilder",
    "point_segment_distance",
]
