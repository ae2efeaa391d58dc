"""The shared templates: one quadruped and one biped mesh with skeleton and skinning weights.

Pipeline (deterministic, no randomness): the body field (``quadruped.body`` / ``biped.body``)
is contoured by marching tetrahedra on the half space ``x > −2h``, cut exactly at ``x = 0``,
remeshed isotropically to the edge length that gives ≈ 3.9K vertices on the whole body,
mirrored into a closed genus-0 mesh with an exact symmetry map, and skinned by bone heat.

Building takes several seconds, so the result is cached in memory and on disk
(``$LITEGE_CACHE_DIR`` or ``$XDG_CACHE_HOME/litege`` or ``~/.cache/litege``, file
``synth/template-<category>-<GENERATOR_VERSION>-<anatomy hash>.npz``). The cache is only
an accelerator: the file is rebuilt when missing or unreadable, and the build is reproducible
bit for bit on one platform.
"""

from __future__ import annotations

import hashlib
import os
import tempfile
from collections.abc import Callable
from dataclasses import dataclass
from functools import cache
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from litege_core.errors import ComputationError, InputError
from litege_core.synth import biped, quadruped
from litege_core.synth.contour import cut_positive_half, marching_tetrahedra
from litege_core.synth.implicit import Blend, dominant_tags, field_gradient, project_to_surface
from litege_core.synth.remesh import mirror_half, remesh_half
from litege_core.synth.skeleton import Skeleton
from litege_core.synth.skinning import attach_to_bones, bone_heat_weights, sparsify

#: Bump when anything changes the generated templates (invalidates disk caches).
GENERATOR_VERSION = "synth-template-v1"

CATEGORIES = ("quadruped", "biped")
TARGET_VERTICES = 3900
MAX_INFLUENCES = 4
SHAPE_HEAT_SCALE = 0.06


@dataclass(frozen=True)
class Anatomy:
    """What a category's template is built from."""

    body: Callable[[], Blend]
    skeleton: Callable[[], Skeleton]
    lower: tuple[float, float, float]  # sampling box (x lower bound is replaced by −2h)
    upper: tuple[float, float, float]
    grid: float  # marching-tetrahedra spacing
    edge_factor: float  # calibrates the edge length to land near TARGET_VERTICES


ANATOMIES = {
    "quadruped": Anatomy(
        quadruped.body, quadruped.skeleton, (0.0, -0.06, -0.9), (0.4, 1.6, 1.95), 0.022, 0.97
    ),
    "biped": Anatomy(biped.body, biped.skeleton, (0.0, -0.06, -0.4), (1.1, 1.95, 0.4), 0.02, 0.965),
}


@dataclass(frozen=True, eq=False)
class Template:
    """A category's template mesh in the rest pose.

    Attributes:
        category: ``"quadruped"`` or ``"biped"``.
        vertices: ``(V, 3)`` float64, template units (x lateral, y up, z forward).
        faces: ``(F, 3)`` int64, outward oriented.
        symmetry: ``(V,)`` int64; ``vertices[symmetry[i]]`` is the mirror image of vertex i.
        weights: ``(V, J)`` float64 skinning weights for posing (rows sum to 1, at most
            ``MAX_INFLUENCES`` non-zeros).
        shape_weights: ``(V, J)`` float64 smoother, dense weights used to blend the per-bone
            length/girth scalings (wide blends keep strong scale contrasts, such as a hippo's
            thick legs on its trunk, free of creases).
        skeleton: the rest skeleton.
        parts: ``(V,)`` body-part (skeleton group) name per vertex.
    """

    category: str
    vertices: NDArray
    faces: NDArray
    symmetry: NDArray
    weights: NDArray
    shape_weights: NDArray
    skeleton: Skeleton
    parts: tuple[str, ...]


def check_category(category: str) -> str:
    """Return ``category`` or raise :class:`InputError` listing the valid ones."""
    if category not in ANATOMIES:
        raise InputError(f"unknown category {category!r}; expected one of {list(CATEGORIES)}")
    return category


@cache
def template(category: str) -> Template:
    """The (cached) template of ``category``."""
    check_category(category)
    anatomy = ANATOMIES[category]
    skel = anatomy.skeleton()
    body = anatomy.body()
    arrays = _load_cached(category)
    if arrays is None:
        arrays = build_mesh(anatomy, body)
        _store_cached(category, arrays)
    vertices, faces, symmetry = arrays
    parts = dominant_tags(body, vertices)
    attachment = attach_to_bones(vertices, parts, skel)
    weights = sparsify(
        bone_heat_weights(vertices, faces, skel, attachment, symmetry), MAX_INFLUENCES, 0.01
    )
    shape_weights = bone_heat_weights(
        vertices, faces, skel, attachment, symmetry, heat_scale=SHAPE_HEAT_SCALE
    )
    for array in (vertices, faces, symmetry, weights, shape_weights):
        array.setflags(write=False)
    return Template(category, vertices, faces, symmetry, weights, shape_weights, skel, tuple(parts))


def build_mesh(anatomy: Anatomy, body: Blend) -> tuple[NDArray, NDArray, NDArray]:
    """Contour, cut, remesh and mirror ``body``; returns vertices, faces, symmetry map."""
    h = anatomy.grid
    lower = np.array(anatomy.lower, dtype=np.float64)
    lower[0] = -3.0 * h + h / 3.0  # no grid node on x = 0, so no vertex lands on the cut

    def half_field(points: NDArray) -> NDArray:
        return np.maximum(body.distance(points), -points[:, 0] - 2.0 * h)

    vertices, faces = marching_tetrahedra(half_field, lower, np.array(anatomy.upper), h)
    half_v, half_f, on_cut = cut_positive_half(vertices, faces)
    p = half_v[half_f]
    half_area = 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)
    full_area = 2.0 * float(half_area.sum())
    edge = anatomy.edge_factor * np.sqrt(2.0 * full_area / (np.sqrt(3.0) * TARGET_VERTICES))

    def project(points: NDArray) -> NDArray:
        return project_to_surface(body, points, iterations=3)

    def normals(points: NDArray) -> NDArray:
        g = field_gradient(body, points)
        return g / np.maximum(np.linalg.norm(g, axis=1, keepdims=True), 1e-12)

    rv, rf, rb = remesh_half(half_v, half_f, on_cut, float(edge), project, normals)
    return mirror_half(rv, rf, rb)


def cache_dir() -> Path:
    """Directory of the on-disk template cache (not created here)."""
    root = os.environ.get("LITEGE_CACHE_DIR")
    if root:
        return Path(root) / "synth"
    xdg = os.environ.get("XDG_CACHE_HOME")
    base = Path(xdg) if xdg else Path.home() / ".cache"
    return base / "litege" / "synth"


def _cache_path(category: str) -> Path:
    """Cache file named by the generator version and a hash of the category's anatomy (body
    primitives, skeleton, sampling parameters), so editing the anatomy never reuses a stale
    file."""
    anatomy = ANATOMIES[category]
    skel = anatomy.skeleton()
    digest = hashlib.sha256(GENERATOR_VERSION.encode())
    digest.update(repr(anatomy.body()).encode())
    digest.update(repr((anatomy.lower, anatomy.upper, anatomy.grid, anatomy.edge_factor)).encode())
    digest.update(repr((TARGET_VERTICES, skel.names)).encode())
    digest.update(np.ascontiguousarray(skel.positions).tobytes())
    return cache_dir() / f"template-{category}-{GENERATOR_VERSION}-{digest.hexdigest()[:16]}.npz"


def _load_cached(category: str) -> tuple[NDArray, NDArray, NDArray] | None:
    path = _cache_path(category)
    try:
        with np.load(path) as data:
            arrays = (
                np.array(data["vertices"], dtype=np.float64),
                np.array(data["faces"], dtype=np.int64),
                np.array(data["symmetry"], dtype=np.int64),
            )
    except (OSError, KeyError, ValueError):
        return None
    return arrays


def _store_cached(category: str, arrays: tuple[NDArray, NDArray, NDArray]) -> None:
    path = _cache_path(category)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=path.parent, suffix=".tmp", delete=False) as tmp:
            np.savez(tmp, vertices=arrays[0], faces=arrays[1], symmetry=arrays[2])
        os.replace(tmp.name, path)
    except OSError:  # a read-only home is not an error: we just rebuild next time
        return


def rebuild(category: str) -> tuple[NDArray, NDArray, NDArray]:
    """Build ``category``'s mesh from scratch, bypassing every cache (for tests)."""
    anatomy = ANATOMIES[check_category(category)]
    arrays = build_mesh(anatomy, anatomy.body())
    if len(arrays[0]) < 1000:
        raise ComputationError("template build produced too few vertices")
    return arrays


__all__ = [
    "ANATOMIES",
    "CATEGORIES",
    "GENERATOR_VERSION",
    "MAX_INFLUENCES",
    "SHAPE_HEAT_SCALE",
    "TARGET_VERTICES",
    "Anatomy",
    "Template",
    "build_mesh",
    "cache_dir",
    "check_category",
    "rebuild",
    "template",
]
