"""Canonicalization: centre, scale and rotate a shape into the frame the networks expect.

Reference-spec §1. Every canonicalization is a similarity transform (:class:`Transform`)

    q = s · R (p − c)        (row vectors: ``q = s · (p − c) @ R.T``)

with a proper rotation ``R`` (3, 3), a centre ``c`` (3,) in input units and a scale ``s > 0``
(canonical units per input unit). Geodesic lengths scale by ``s`` as well.

Three pipelines, which must not be mixed (each model and PCA basis belongs to one):

* :func:`canonicalize_bbox` — geodesic regression ("PC pipeline", §1.2, §1.5): mean of the
  samples, PCA axes with the sign rule, bounding-box area of the aligned samples.
* :func:`canonicalize_unit_area` — shape matching with meshes (§1.3): mean of 8000
  area-weighted samples, ``s = 1/√area``, rotation from the T-Net (passed in).
* :func:`canonicalize_poisson` — shape matching with point clouds and broken meshes (§1.4):
  mean of the cloud, scale matching the mean 1-NN distance of a Poisson-disk subset.
"""

from __future__ import annotations

import math
import sys
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from litege_core.enums import ParsableEnum
from litege_core.errors import (
    ArrayShapeError,
    ArtifactError,
    ComputationError,
    DegenerateShapeError,
    EmptyShapeError,
    InputError,
    LiteGEError,
)
from litege_core.sampling import (
    as_points,
    evenly_spread,
    mean_nearest_neighbour_distance,
    poisson_disk_subsample,
    random_generator,
    sample_surface,
)
from litege_core.shape import Shape
from litege_core.validate import ShapeLimits, triangle_areas, validate_arrays

if TYPE_CHECKING:  # torch only where a batch is canonicalized (the numpy runtime never is)
    import torch

BBOX_SQRT_AREA = 1.7
"""√(surface area) of the aligned bounding box after :func:`canonicalize_bbox`.

⚠ The paper says the box *area* is fixed ("e.g. 1.7"); the authors' code fixes **√area** = 1.7
(box area 2.89). We follow the code, which the released models and constants assume."""

DEFAULT_BBOX_SAMPLES = 2000
"""Surface samples drawn from a mesh for the PC pipeline (the authors use about 2000)."""

DEFAULT_CENTER_SAMPLES = 8000
"""Area-weighted samples whose mean is the centre of a unit-area mesh (spec §1.1)."""

ROTATION_TOLERANCE = 1e-6
"""Largest accepted ``|RᵀR − I|`` entry for a rotation matrix."""

BATCHED_MIN_CLOUDS = 4
"""Clouds of one size from which :func:`canonicalize_bbox_many` computes their frames as
batched tensor code on the device (fewer: the one-cloud reference, in numpy)."""

_RANK_TOLERANCE = 1e-12  # eigenvalue ratio λ1/λ0 below which the points count as collinear
_NO_LIMITS = ShapeLimits(max_vertices=sys.maxsize, max_faces=sys.maxsize)


# --------------------------------------------------------------------------- transform


def _as_rotation(matrix: ArrayLike, what: str = "rotation") -> NDArray:
    """Validate a proper rotation ``(3, 3)``; return a read-only float64 copy."""
    try:
        rotation = np.array(matrix, dtype=np.float64)
    except (ValueError, TypeError) as exc:
        raise ArrayShapeError(f"{what} must be a numeric (3, 3) array: {exc}") from exc
    if rotation.shape != (3, 3):
        raise ArrayShapeError(f"{what} must have shape (3, 3), got {rotation.shape}")
    if not np.isfinite(rotation).all():
        raise InputError(f"{what} has NaN or infinite entries")
    error = float(np.abs(rotation.T @ rotation - np.eye(3)).max())
    if error > ROTATION_TOLERANCE:
        raise InputError(f"{what} is not orthonormal (max |RᵀR − I| = {error:.3g})")
    if np.linalg.det(rotation) < 0.0:
        raise InputError(f"{what} is a reflection (det < 0), not a proper rotation")
    rotation.setflags(write=False)
    return rotation


def _as_vector3(vector: ArrayLike, what: str) -> NDArray:
    try:
        array = np.array(vector, dtype=np.float64)
    except (ValueError, TypeError) as exc:
        raise ArrayShapeError(f"{what} must be a numeric (3,) array: {exc}") from exc
    if array.shape != (3,):
        raise ArrayShapeError(f"{what} must have shape (3,), got {array.shape}")
    if not np.isfinite(array).all():
        raise InputError(f"{what} has NaN or infinite entries")
    array.setflags(write=False)
    return array


def _last_axis_3(array: ArrayLike, what: str) -> NDArray:
    try:
        values = np.asarray(array, dtype=np.float64)
    except (ValueError, TypeError) as exc:
        raise ArrayShapeError(f"{what} must be a numeric (..., 3) array: {exc}") from exc
    if values.ndim == 0 or values.shape[-1] != 3:
        raise ArrayShapeError(f"{what} must have shape (..., 3), got {values.shape}")
    return values


@dataclass(frozen=True, eq=False)
class Transform:
    """Similarity transform ``q = s · R (p − c)`` from input units to canonical units.

    Attributes:
        rotation: ``(3, 3)`` float64 proper rotation ``R`` (read-only).
        center: ``(3,)`` float64 centre ``c`` in input units (read-only).
        scale: ``s > 0``, canonical units per input unit.

    Similarities form a group, so :meth:`inverse` and :meth:`compose` return exact
    ``Transform`` objects of the same form (no general affine fallback is needed).
    Compare with :meth:`allclose`; ``==`` is identity.
    """

    rotation: NDArray
    center: NDArray
    scale: float

    def __post_init__(self) -> None:
        try:
            scale = float(self.scale)
        except (TypeError, ValueError) as exc:
            raise InputError(f"scale must be a number, got {self.scale!r}") from exc
        if not (math.isfinite(scale) and scale > 0.0):
            raise InputError(f"scale must be finite and positive, got {self.scale!r}")
        object.__setattr__(self, "rotation", _as_rotation(self.rotation))
        object.__setattr__(self, "center", _as_vector3(self.center, "center"))
        object.__setattr__(self, "scale", scale)

    @classmethod
    def identity(cls) -> Transform:
        return cls(np.eye(3), np.zeros(3), 1.0)

    def apply(self, points: ArrayLike) -> NDArray:
        """Input → canonical: ``(..., 3)`` points to ``(..., 3)`` float64.

        Each point is mapped on its own, by elementwise products and sums in a fixed order (no
        matrix kernel, whose rounding depends on the array's size): a subset of the points maps
        to exactly the rows of the whole (:attr:`ShapeState.canonical_points` is built lazily
        on that promise)."""
        d = _last_axis_3(points, "points") - self.center
        r = self.rotation
        return self.scale * (d[..., :1] * r[:, 0] + d[..., 1:2] * r[:, 1] + d[..., 2:] * r[:, 2])

    def invert(self, points: ArrayLike) -> NDArray:
        """Canonical → input: ``(..., 3)`` points to ``(..., 3)`` float64."""
        values = _last_axis_3(points, "points")
        return (values @ self.rotation) / self.scale + self.center

    def apply_vectors(self, vectors: ArrayLike) -> NDArray:
        """Input → canonical for displacement vectors ``(..., 3)``: ``s · R v`` (no centre).

        Unit normals need only the rotation: ``v @ transform.rotation.T``."""
        values = _last_axis_3(vectors, "vectors")
        return self.scale * (values @ self.rotation.T)

    def inverse(self) -> Transform:
        """The transform from canonical back to input units (``Rᵀ``, ``−s R c``, ``1/s``)."""
        return Transform(
            self.rotation.T, -self.scale * (self.rotation @ self.center), 1 / self.scale
        )

    def compose(self, other: Transform) -> Transform:
        """``self ∘ other``: apply ``other`` first, then ``self`` (like ``M_self @ M_other``)."""
        rotation = self.rotation @ other.rotation
        center = other.center + (other.rotation.T @ self.center) / other.scale
        return Transform(rotation, center, self.scale * other.scale)

    def then(self, other: Transform) -> Transform:
        """Apply ``self`` first, then ``other`` (``other ∘ self``)."""
        return other.compose(self)

    def scale_distance(self, distance: ArrayLike) -> NDArray | float:
        """Input-unit lengths (e.g. geodesics) to canonical units: ``d · s``."""
        return np.multiply(distance, self.scale)

    def unscale_distance(self, distance: ArrayLike) -> NDArray | float:
        """Canonical lengths (e.g. predicted geodesics) to input units: ``d / s``."""
        return np.divide(distance, self.scale)

    def as_matrix(self) -> NDArray:
        """``(4, 4)`` homogeneous matrix ``M`` with ``M @ [p, 1] = [s R (p − c), 1]``."""
        matrix = np.eye(4)
        matrix[:3, :3] = self.scale * self.rotation
        matrix[:3, 3] = -self.scale * (self.rotation @ self.center)
        return matrix

    def to_dict(self) -> dict[str, Any]:
        """JSON-safe dict (plain lists and floats; float64 values round-trip exactly)."""
        return {
            "rotation": self.rotation.tolist(),
            "center": self.center.tolist(),
            "scale": self.scale,
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> Transform:
        """Inverse of :meth:`to_dict`; raises :class:`ArtifactError` on malformed data."""
        try:
            return cls(data["rotation"], data["center"], data["scale"])
        except (KeyError, TypeError) as exc:
            raise ArtifactError(f"malformed transform record: {exc!r}") from exc
        except LiteGEError as exc:
            raise ArtifactError(f"invalid transform record: {exc}") from exc

    def allclose(self, other: Transform, atol: float = 1e-12) -> bool:
        """Whether both transforms have equal parameters within ``atol``."""
        return bool(
            np.allclose(self.rotation, other.rotation, rtol=0.0, atol=atol)
            and np.allclose(self.center, other.center, rtol=0.0, atol=atol)
            and abs(self.scale - other.scale) <= atol * max(1.0, abs(self.scale))
        )


# --------------------------------------------------------------------------- PC pipeline


def _pca_rotation(centered: NDArray) -> NDArray:
    """Rotation ``(3, 3)`` of spec §1.5 for points ``(N, 3)`` already centred on their mean."""
    covariance = centered.T @ centered / (centered.shape[0] - 1)  # unbiased, as np.cov
    try:
        eigenvalues, eigenvectors = np.linalg.eigh(covariance)
    except np.linalg.LinAlgError as exc:
        raise ComputationError(f"PCA eigen-decomposition failed: {exc}") from exc
    eigenvectors = eigenvectors * np.where(eigenvectors[0] < 0.0, -1.0, 1.0)  # x component ≥ 0
    order = np.argsort(-eigenvalues, kind="stable")
    eigenvalues, axes = eigenvalues[order], eigenvectors[:, order]
    if not eigenvalues[0] > 0.0:
        raise DegenerateShapeError("cannot align points that all coincide (zero extent)")
    if eigenvalues[1] <= _RANK_TOLERANCE * eigenvalues[0]:
        raise DegenerateShapeError(
            "points are collinear: the second principal axis is undefined",
            eigenvalues=eigenvalues.tolist(),
        )
    medians = np.median(centered @ axes[:, :2], axis=0)
    first = axes[:, 0] * (-1.0 if medians[0] < 0.0 else 1.0)
    second = axes[:, 1] * (-1.0 if medians[1] < 0.0 else 1.0)
    return np.stack([first, second, np.cross(first, second)])


def pca_alignment(points: ArrayLike) -> NDArray:
    """PCA rotation with the authors' sign rule (spec §1.5).

    Unbiased covariance of the centred points, ``eigh``; each eigenvector flipped to a
    non-negative x component; sorted by eigenvalue, descending; the first two axes flipped so
    the median projection of the centred points is ≥ 0; third axis ``a0 × a1``.

    Args:
        points: ``(N, 3)`` samples, ``N >= 4``.

    Returns:
        ``(3, 3)`` proper rotation ``R = [a0 a1 a2]ᵀ``; the aligned point is ``R (p − mean)``.

    Raises:
        DegenerateShapeError: fewer than 4 points, all points coincide, or they are collinear.
            Coplanar points are accepted: ``a0`` and ``a1`` span the plane and ``a2`` is its
            normal. (Near-equal eigenvalues, e.g. a sphere, are accepted but give a frame
            that is unstable under rotation of the input.)
    """
    pts = as_points(points, min_points=4)
    return _pca_rotation(pts - pts.mean(axis=0))


def canonicalize_bbox(points: ArrayLike) -> Transform:
    """PC pipeline (spec §1.2): centre on the mean, PCA-align, fix the bounding-box area.

    ``s = BBOX_SQRT_AREA / √A`` with ``A = 2(dx·dy + dy·dz + dz·dx)`` the surface area of the
    axis-aligned bounding box of the *aligned* points, so the canonical box has √area 1.7.

    Args:
        points: ``(N, 3)`` input samples (about 2000 in the authors' pipeline), ``N >= 4``.
    """
    pts = as_points(points, min_points=4)
    center = pts.mean(axis=0)
    centered = pts - center
    rotation = _pca_rotation(centered)
    dx, dy, dz = np.ptp(centered @ rotation.T, axis=0)
    area = 2.0 * (dx * dy + dy * dz + dz * dx)
    if not area > 0.0:
        raise DegenerateShapeError("the aligned bounding box has zero surface area")
    return Transform(rotation, center, BBOX_SQRT_AREA / math.sqrt(area))


class CanonicalBatch(NamedTuple):
    """Clouds canonicalized together by :func:`canonicalize_bbox_many`.

    Attributes:
        transforms: ``B`` :class:`Transform` objects, user frame → canonical frame.
        clouds: ``(B, P_max, 3)`` float32 tensor on the device, the canonical clouds; a cloud
            shorter than ``P_max`` is padded by repeating its first point (which changes no
            nearest-point distance: the UDF reads it as is).
    """

    transforms: list[Transform]
    clouds: torch.Tensor


def canonicalize_bbox_many(
    clouds: Sequence[ArrayLike], device: torch.device | str = "cpu"
) -> CanonicalBatch:
    """:func:`canonicalize_bbox` of many clouds at once, as batched float64 tensor code on
    ``device`` with no Python loop over the clouds of one size: the paper's Table 1 setting
    registers 64 clouds at once, and on a GPU the frames are computed where the UDF runs.

    The maths is the one-cloud reference's (unbiased covariance, ``eigh``, the sign rule with
    the mean-of-middle-two median, the aligned bounding box) and agrees with it to float64
    rounding (``tests/litege_core/test_canonical.py``). 64 clouds of 2000 points take about
    30 ms on one core of the development CPU, against 45 ms for the reference loop, and 4 ms
    on an H200 (BENCHMARKS "batch-table-cuda"). Fewer than :data:`BATCHED_MIN_CLOUDS` clouds
    of one size go through the one-cloud reference in numpy instead (then one upload): one
    cloud costs 1.1–1.6 ms of tensor-op overhead batched, on a GPU or a CPU, against 0.5 ms.

    Args:
        clouds: ``B ≥ 1`` arrays ``(P_b, 3)``, ``P_b ≥ 4``; sizes may differ.
        device: where the maths runs and :attr:`CanonicalBatch.clouds` lives.

    Raises:
        DegenerateShapeError: a cloud whose points coincide, are collinear or have a flat
            aligned box (the message names the first such cloud).
    """
    import torch

    points = [as_points(cloud, min_points=4, what=f"clouds[{b}]") for b, cloud in enumerate(clouds)]
    if not points:
        raise InputError("canonicalize_bbox_many needs at least one cloud")
    dev = torch.device(device)
    width = max(p.shape[0] for p in points)
    transforms: list[Transform] = [Transform.identity()] * len(points)
    by_size: dict[int, list[int]] = {}
    for b, cloud in enumerate(points):
        by_size.setdefault(cloud.shape[0], []).append(b)
    padded: torch.Tensor | None = None
    for size, members in by_size.items():
        if len(members) < BATCHED_MIN_CLOUDS:  # the one-cloud reference, then one upload
            group = [_named_bbox(points[b], b) for b in members]
            canonical = [t.apply(points[b]) for t, b in zip(group, members, strict=True)]
            result = torch.from_numpy(np.stack(canonical).astype(np.float32))
        else:
            stacked = np.stack([points[b] for b in members])  # (G, P, 3), a fresh copy
            group, result = _bbox_frames(torch.from_numpy(stacked).to(dev), members)
            del stacked
        if len(by_size) == 1:  # one size (the usual batch): the result is the batch
            return CanonicalBatch(group, result.to(dev, torch.float32))
        if padded is None:
            padded = torch.empty((len(points), width, 3), dtype=torch.float32, device=dev)
        index = torch.tensor(members, device=dev)
        padded[index, :size] = result.to(dev, torch.float32)
        if size < width:
            padded[index, size:] = padded[index, :1]
        for g, b in enumerate(members):
            transforms[b] = group[g]
    assert padded is not None
    return CanonicalBatch(transforms, padded)


def _named_bbox(points: NDArray, index: int) -> Transform:
    """:func:`canonicalize_bbox` whose errors name ``clouds[index]``."""
    try:
        return canonicalize_bbox(points)
    except DegenerateShapeError as exc:
        raise DegenerateShapeError(f"clouds[{index}]: {exc}") from exc


def _bbox_frames(
    stacked: torch.Tensor, members: Sequence[int]
) -> tuple[list[Transform], torch.Tensor]:
    """The batched half of :func:`canonicalize_bbox_many`: ``(G, P, 3)`` float64 clouds →
    their transforms and the ``(G, P, 3)`` float64 canonical clouds (on the same device).
    ``stacked`` is overwritten (centred in place). The ``(G, P, ·)`` work runs on the device;
    the ``(G, 3, 3)`` eigen-decompositions run in numpy (a batched GPU ``eigh`` of 3 × 3
    matrices costs milliseconds of solver set-up), with six small host–device transfers."""
    import torch

    device = stacked.device
    centers = stacked.mean(dim=1)  # (G, 3)
    centered = stacked.sub_(centers[:, None, :])
    rotations = _pca_rotations(centered, members)  # (G, 3, 3) numpy
    aligned = centered @ torch.from_numpy(rotations).to(device).transpose(1, 2)  # (G, P, 3)
    del centered, stacked
    extent = torch.cat([aligned.amax(dim=1) - aligned.amin(dim=1), centers], dim=1)
    dx, dy, dz, *center = extent.cpu().numpy().T
    areas = 2.0 * (dx * dy + dy * dz + dz * dx)
    _check_batch(areas > 0.0, members, "the aligned bounding box has zero surface area")
    scales = BBOX_SQRT_AREA / np.sqrt(areas)
    origins = np.stack(center, axis=1)
    transforms = [
        Transform(rotations[g], origins[g], float(scales[g])) for g in range(len(members))
    ]
    return transforms, aligned.mul_(torch.from_numpy(scales).to(device)[:, None, None])


def _pca_rotations(centered: torch.Tensor, members: Sequence[int]) -> NDArray:
    """The rotations of :func:`pca_alignment` for ``(G, P, 3)`` centred float64 clouds on a
    device → ``(G, 3, 3)`` float64 numpy; ``members`` names the clouds in error messages."""
    import torch

    covariance = (centered.transpose(1, 2) @ centered / (centered.shape[1] - 1)).cpu().numpy()
    try:
        eigenvalues, eigenvectors = np.linalg.eigh(covariance)  # ascending, (G, 3), (G, 3, 3)
    except np.linalg.LinAlgError as exc:
        raise ComputationError(f"PCA eigen-decomposition failed: {exc}") from exc
    eigenvectors = eigenvectors * np.where(eigenvectors[:, :1, :] < 0.0, -1.0, 1.0)
    order = np.argsort(-eigenvalues, axis=1, kind="stable")
    eigenvalues = np.take_along_axis(eigenvalues, order, axis=1)
    axes = np.take_along_axis(eigenvectors, order[:, None, :], axis=2)
    _check_batch(eigenvalues[:, 0] > 0.0, members, "cannot align points that all coincide")
    _check_batch(
        eigenvalues[:, 1] > _RANK_TOLERANCE * eigenvalues[:, 0],
        members,
        "points are collinear: the second principal axis is undefined",
    )
    projected = centered @ torch.from_numpy(axes[:, :, :2].copy()).to(centered.device)
    size = centered.shape[1]
    low = projected.kthvalue((size + 1) // 2, dim=1).values  # the middle two, as np.median
    high = low if size % 2 else projected.kthvalue(size // 2 + 1, dim=1).values
    medians = ((low + high) / 2.0).cpu().numpy()  # (G, 2)
    signs = np.where(medians < 0.0, -1.0, 1.0)
    first = axes[:, :, 0] * signs[:, :1]
    second = axes[:, :, 1] * signs[:, 1:]
    return np.stack([first, second, np.cross(first, second)], axis=1)


def _check_batch(valid: NDArray, members: Sequence[int], message: str) -> None:
    """Raise :class:`DegenerateShapeError` naming the first cloud where ``valid`` is false."""
    bad = np.flatnonzero(~valid)
    if bad.size:
        raise DegenerateShapeError(f"clouds[{members[int(bad[0])]}]: {message}")


# --------------------------------------------------------------------------- matching pipeline


def canonicalize_unit_area(
    vertices: ArrayLike,
    faces: ArrayLike,
    n_center_samples: int = DEFAULT_CENTER_SAMPLES,
    seed: int | np.random.Generator = 0,
    rotation: ArrayLike | None = None,
) -> Transform:
    """Unit-area mesh (spec §1.3): centre on the mean of area-weighted samples, ``s = 1/√area``.

    Args:
        vertices: ``(V, 3)`` mesh vertices.
        faces: ``(F, 3)`` triangles.
        n_center_samples: samples whose mean is the centre (8000 in the authors' code).
        seed: seed of the centre samples.
        rotation: optional proper rotation applied after centring and scaling (the T-Net
            alignment: the authors right-multiply by ``R_pred``, so pass ``R_predᵀ``).
            Identity when omitted.
    """
    verts, tris = validate_arrays(vertices, faces, _NO_LIMITS)
    if tris is None:  # faces=None means a point cloud to validate_arrays
        raise EmptyShapeError("unit-area canonicalization needs a mesh with faces")
    if n_center_samples < 1:
        raise ArrayShapeError(f"n_center_samples must be positive, got {n_center_samples}")
    center = sample_surface(verts, tris, n_center_samples, seed).points.mean(axis=0)
    area = float(triangle_areas(verts, tris).sum())
    turn = np.eye(3) if rotation is None else np.asarray(rotation, dtype=np.float64)
    return Transform(turn, center, 1.0 / math.sqrt(area))


@dataclass(frozen=True)
class PoissonScaleSetting:
    """One row of the spec §1.4 table: how to scale a cloud by Poisson-disk spacing.

    Attributes:
        name: short id.
        n_cloud: points in the input cloud (8000 or 500), or the dense candidate pool sampled
            from a broken mesh (our choice: 8 candidates per Poisson sample).
        n_poisson: K, the size of the Poisson-disk subset.
        target_mean_nn: mean 1-NN distance of K Poisson samples of a unit-area mesh. The
            presets hold the paper's constants, measured with MeshLab's sampler; recompute
            them for our sampler with :func:`calibrate_poisson_target`.
        subset_is_cloud: broken meshes: the Poisson subset itself becomes the point cloud
            (centred on its own mean).
    """

    name: str
    n_cloud: int
    n_poisson: int
    target_mean_nn: float
    subset_is_cloud: bool = False


POISSON_8K_CLOUD = PoissonScaleSetting("cloud_8k", 8000, 500, 0.03835)
POISSON_500_CLOUD = PoissonScaleSetting("cloud_500", 500, 50, 0.12121)
POISSON_BROKEN_MESH = PoissonScaleSetting("broken_mesh", 56_000, 7000, 0.01181, True)


def canonicalize_poisson(
    points: ArrayLike,
    n_poisson: int,
    target_mean_nn: float,
    seed: int | np.random.Generator = 0,
    rotation: ArrayLike | None = None,
) -> Transform:
    """Point cloud (spec §1.4): centre on the cloud mean, scale by Poisson-disk spacing.

    ``s = target_mean_nn / d̄`` where ``d̄`` is the mean 1-NN distance among a Poisson-disk
    subset of about ``n_poisson`` points (:func:`poisson_disk_subsample`). With fewer than
    ``n_poisson`` points the whole cloud is used.

    Args:
        points: ``(N, 3)`` cloud in input units.
        n_poisson: K, the Poisson subset size.
        target_mean_nn: wanted mean 1-NN distance of the subset, canonical units.
        seed: seed of the Poisson subset.
        rotation: optional proper rotation applied after centring and scaling (T-Net).
    """
    if not (math.isfinite(target_mean_nn) and target_mean_nn > 0.0):
        raise InputError(f"target_mean_nn must be finite and positive, got {target_mean_nn!r}")
    pts = as_points(points, min_points=2)
    subset = pts[poisson_disk_subsample(pts, n_poisson, seed)]
    if subset.shape[0] < 2:
        raise DegenerateShapeError("the Poisson-disk subset has fewer than 2 points")
    spacing = mean_nearest_neighbour_distance(subset)
    if not spacing > 0.0:
        raise DegenerateShapeError("the Poisson-disk subset has zero nearest-neighbour spacing")
    turn = np.eye(3) if rotation is None else np.asarray(rotation, dtype=np.float64)
    return Transform(turn, pts.mean(axis=0), target_mean_nn / spacing)


def poisson_spacing_unit_area(
    vertices: ArrayLike,
    faces: ArrayLike,
    n_cloud: int,
    n_poisson: int,
    seed: int | np.random.Generator = 0,
) -> float:
    """Mean 1-NN distance of ``n_poisson`` Poisson-disk samples out of ``n_cloud``
    area-weighted samples of the mesh rescaled to unit area (canonical units)."""
    verts, tris = validate_arrays(vertices, faces, _NO_LIMITS)
    if tris is None:
        raise EmptyShapeError("Poisson calibration needs meshes with faces")
    rng = random_generator(seed)
    verts = verts / math.sqrt(float(triangle_areas(verts, tris).sum()))
    cloud = sample_surface(verts, tris, n_cloud, rng).points
    return mean_nearest_neighbour_distance(cloud[poisson_disk_subsample(cloud, n_poisson, rng)])


def calibrate_poisson_target(
    unit_area_meshes: Sequence[tuple[ArrayLike, ArrayLike]],
    n_cloud: int,
    n_poisson: int,
    seed: int = 0,
) -> float:
    """Recompute a §1.4 target with our sampler: the mean over meshes of
    :func:`poisson_spacing_unit_area` (meshes are rescaled to unit area first).

    Mesh ``i`` uses the independent random stream ``default_rng([seed, i])``.
    """
    if len(unit_area_meshes) == 0:
        raise EmptyShapeError("calibration needs at least one mesh")
    spacings = [
        poisson_spacing_unit_area(v, f, n_cloud, n_poisson, np.random.default_rng([seed, i]))
        for i, (v, f) in enumerate(unit_area_meshes)
    ]
    return float(np.mean(spacings))


# --------------------------------------------------------------------------- dispatcher


class CanonicalizationMethod(ParsableEnum, noun="canonicalization"):
    """The three canonicalization pipelines of spec §1."""

    BBOX = "bbox"
    UNIT_AREA = "unit_area"
    POISSON = "poisson"


def canonicalize(
    shape: Shape,
    method: str | CanonicalizationMethod,
    *,
    seed: int = 0,
    n_bbox_samples: int = DEFAULT_BBOX_SAMPLES,
    n_center_samples: int = DEFAULT_CENTER_SAMPLES,
    poisson: PoissonScaleSetting = POISSON_8K_CLOUD,
    rotation: ArrayLike | None = None,
) -> tuple[Transform, NDArray]:
    """Canonicalize a shape; return ``(transform, canonical vertices (N, 3))``.

    * ``bbox``: a point cloud uses its points; a mesh uses ``n_bbox_samples`` surface samples.
    * ``unit_area``: meshes only; ``n_center_samples`` samples give the centre.
    * ``poisson``: a point cloud is the cloud; a mesh is first sampled with
      ``poisson.n_cloud`` surface points. With ``poisson.subset_is_cloud`` (broken meshes)
      the Poisson subset is the cloud and its mean the centre.

    ``rotation`` (T-Net, applied after centring and scaling) is for ``unit_area`` and
    ``poisson``; ``bbox`` computes its own. All randomness derives from ``seed``.
    """
    method = CanonicalizationMethod.parse(method)
    if method is CanonicalizationMethod.BBOX:
        if rotation is not None:
            raise InputError("bbox canonicalization computes its own rotation")
        points = shape.vertices
        if shape.faces is not None:
            points = sample_surface(shape.vertices, shape.faces, n_bbox_samples, seed).points
        transform = canonicalize_bbox(points)
    elif method is CanonicalizationMethod.UNIT_AREA:
        if shape.faces is None:
            raise EmptyShapeError("unit_area canonicalization needs a mesh; got a point cloud")
        transform = canonicalize_unit_area(
            shape.vertices, shape.faces, n_center_samples, seed, rotation
        )
    else:
        transform = poisson_frame(shape, poisson, seed, rotation)[0]
    return transform, transform.apply(shape.vertices)


def poisson_frame(
    shape: Shape, setting: PoissonScaleSetting, seed: int, rotation: ArrayLike | None = None
) -> tuple[Transform, NDArray]:
    """Poisson-spacing canonicalization of a shape (spec §1.4) and the cloud it used.

    Returns:
        ``(transform, cloud)``: the cloud (input units) is the point cloud itself, less its
        isolated points and thinned to an even spread (:func:`~litege_core.sampling.
        evenly_spread`), ``n_cloud`` surface samples of a mesh, or their Poisson subset when
        ``setting.subset_is_cloud``.
    """
    rng = random_generator(seed)
    if shape.faces is None:  # a scan's strays and uneven density would pull the frame
        cloud = evenly_spread(shape.vertices, rng)
    else:
        cloud = sample_surface(shape.vertices, shape.faces, setting.n_cloud, rng).points
    n_poisson = setting.n_poisson
    if setting.subset_is_cloud:  # the subset is the cloud: its spacing is used as is
        cloud = cloud[poisson_disk_subsample(cloud, n_poisson, rng)]
        n_poisson = cloud.shape[0]
    transform = canonicalize_poisson(cloud, n_poisson, setting.target_mean_nn, rng, rotation)
    return transform, cloud


__all__ = [
    "BATCHED_MIN_CLOUDS",
    "BBOX_SQRT_AREA",
    "DEFAULT_BBOX_SAMPLES",
    "DEFAULT_CENTER_SAMPLES",
    "POISSON_8K_CLOUD",
    "POISSON_500_CLOUD",
    "POISSON_BROKEN_MESH",
    "CanonicalBatch",
    "CanonicalizationMethod",
    "PoissonScaleSetting",
    "Transform",
    "calibrate_poisson_target",
    "canonicalize",
    "canonicalize_bbox",
    "canonicalize_bbox_many",
    "canonicalize_poisson",
    "canonicalize_unit_area",
    "pca_alignment",
    "poisson_frame",
    "poisson_spacing_unit_area",
]
