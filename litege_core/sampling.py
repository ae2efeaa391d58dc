"""Point sampling: area-weighted surface samples, farthest-point and Poisson-disk subsets.

* :func:`sample_surface`: i.i.d. area-weighted points on a triangle mesh.
* :func:`farthest_point_sampling`: greedy max-min subset of a point set (exact, O(N·n)).
* :func:`poisson_disk_subsample`: blue-noise subset of a point set with about ``n_target``
  points (random-order dart throwing over the candidates, radius found by a bracketed search).
* :func:`mean_nearest_neighbour_distance`: the scale statistic of reference-spec §1.4.

All functions are deterministic for a given seed.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from litege_core.errors import (
    ArrayShapeError,
    DegenerateShapeError,
    EmptyShapeError,
    IndexOutOfRangeError,
    InputError,
    NonFiniteError,
)
from litege_core.validate import triangle_areas

if TYPE_CHECKING:
    from scipy.spatial import cKDTree


class SurfaceSamples(NamedTuple):
    """Points on a triangle mesh with their location on it.

    Attributes:
        points: ``(n, 3)`` float64 positions.
        face_index: ``(n,)`` int64 triangle each point lies on.
        barycentric: ``(n, 3)`` float64 weights of the triangle's corners (rows sum to 1).
    """

    points: NDArray
    face_index: NDArray
    barycentric: NDArray


def check_seed(seed: object, what: str = "seed") -> int:
    """``seed`` as an ``int``; ``what`` names it in the error (e.g. ``"--seed"``).

    Raises:
        InputError: ``seed`` is not a non-negative integer (numpy's generators take no others).
    """
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0:
        raise InputError(f"{what} must be a non-negative integer, got {seed!r}")
    return int(seed)


def random_generator(seed: int | np.random.Generator) -> np.random.Generator:
    """``np.random.default_rng(seed)`` after :func:`check_seed`; a generator is returned as is.

    Raises:
        InputError: ``seed`` is neither a generator nor a non-negative integer.
    """
    if isinstance(seed, np.random.Generator):
        return seed
    return np.random.default_rng(check_seed(seed))


def sample_surface(
    vertices: NDArray, faces: NDArray, n_samples: int, seed: int | np.random.Generator = 0
) -> SurfaceSamples:
    """Draw ``n_samples`` points uniformly by area (faces with replacement, p ∝ area).

    Barycentric coordinates are uniform on the triangle: draw ``u, v ~ U(0, 1)`` and fold
    ``u + v > 1`` back (the authors' convention). Deterministic for a given seed.

    Raises:
        InputError: a negative ``n_samples`` or seed (see :func:`check_seed`).
    """
    if n_samples < 0:
        raise ArrayShapeError(f"n_samples must be non-negative, got {n_samples}")
    rng = random_generator(seed)
    areas = triangle_areas(vertices, faces)
    total = areas.sum()
    if not total > 0:
        raise DegenerateShapeError("cannot sample a mesh with zero area")
    cumulative = np.cumsum(areas)
    face_index = np.searchsorted(cumulative, rng.random(n_samples) * cumulative[-1], side="right")
    face_index = np.minimum(face_index, faces.shape[0] - 1).astype(np.int64)
    uv = rng.random((n_samples, 2))
    folded = uv.sum(axis=1) > 1.0
    uv[folded] = 1.0 - uv[folded]
    barycentric = np.column_stack([1.0 - uv[:, 0] - uv[:, 1], uv[:, 0], uv[:, 1]])
    corners = vertices[faces[face_index]]
    points = np.einsum("nk,nkd->nd", barycentric, corners)
    return SurfaceSamples(points, face_index, barycentric)


def as_points(points: ArrayLike, *, min_points: int = 1, what: str = "points") -> NDArray:
    """Return ``points`` as a C-contiguous float64 ``(N, 3)`` array or raise.

    Raises:
        ArrayShapeError: not numeric or not of shape ``(N, 3)``.
        EmptyShapeError: ``N == 0``.
        NonFiniteError: NaN or infinite coordinates.
        DegenerateShapeError: fewer than ``min_points`` points.
    """
    try:
        array = np.asarray(points, dtype=np.float64)
    except (ValueError, TypeError) as exc:
        raise ArrayShapeError(f"{what} must be a numeric (N, 3) array: {exc}") from exc
    if array.ndim != 2 or array.shape[1] != 3:
        raise ArrayShapeError(f"{what} must have shape (N, 3), got {array.shape}")
    if array.shape[0] == 0:
        raise EmptyShapeError(f"{what} are empty")
    if not np.isfinite(array).all():
        raise NonFiniteError(f"{what} contain NaN or infinite coordinates")
    if array.shape[0] < min_points:
        raise DegenerateShapeError(
            f"need at least {min_points} {what}, got {array.shape[0]}",
            n_points=int(array.shape[0]),
            min_points=min_points,
        )
    return np.ascontiguousarray(array)


def _check_count(name: str, value: int, upper: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int | np.integer):
        raise ArrayShapeError(f"{name} must be an integer, got {value!r}")
    if not 0 <= value <= upper:
        raise ArrayShapeError(f"{name} must be in [0, {upper}], got {value}")
    return int(value)


# --------------------------------------------------------------------------- farthest point


def farthest_point_sampling(points: ArrayLike, n_samples: int, start_index: int = 0) -> NDArray:
    """Greedy farthest-point (max-min) subset of a point set.

    Starts at ``start_index``; each next sample is the point whose squared Euclidean distance
    to the chosen set is largest (ties: lowest index). Exact and deterministic, O(N·n) time
    with one vectorized pass over the points per sample.

    Args:
        points: ``(N, 3)`` positions.
        n_samples: number of samples, ``0 <= n_samples <= N``.
        start_index: index of the first sample.

    Returns:
        ``(n_samples,)`` int64 distinct indices into ``points``, in selection order.
    """
    pts = as_points(points)
    n_points = pts.shape[0]
    n_samples = _check_count("n_samples", n_samples, n_points)
    if not 0 <= start_index < n_points:
        raise IndexOutOfRangeError(
            f"start_index {start_index} is outside [0, {n_points})", index=int(start_index)
        )
    coords = np.ascontiguousarray(pts.T)  # (3, N): one contiguous row per axis
    min_d2 = np.full(n_points, np.inf)
    d2 = np.empty(n_points)
    diff = np.empty(n_points)
    selected = np.empty(n_samples, dtype=np.int64)
    current = int(start_index)
    for k in range(n_samples):
        selected[k] = current
        np.subtract(coords[0], coords[0, current], out=diff)
        np.multiply(diff, diff, out=d2)
        for axis in (1, 2):
            np.subtract(coords[axis], coords[axis, current], out=diff)
            np.multiply(diff, diff, out=diff)
            np.add(d2, diff, out=d2)
        np.minimum(min_d2, d2, out=min_d2)
        min_d2[current] = -np.inf  # never pick a chosen point again, even among duplicates
        current = int(np.argmax(min_d2))
    return selected


def _farthest_point_sampling_reference(
    points: ArrayLike, n_samples: int, start_index: int = 0
) -> NDArray:
    """Slow pure-Python farthest-point sampling with the same arithmetic; for tests only."""
    rows = as_points(points).tolist()
    min_d2 = [math.inf] * len(rows)
    selected: list[int] = []
    current = start_index
    for _ in range(n_samples):
        selected.append(current)
        cx, cy, cz = rows[current]
        for i, (x, y, z) in enumerate(rows):
            dx, dy, dz = x - cx, y - cy, z - cz
            d2 = dx * dx + dy * dy + dz * dz
            if d2 < min_d2[i]:
                min_d2[i] = d2
        min_d2[current] = -math.inf
        best, current = -math.inf, 0
        for i, value in enumerate(min_d2):
            if value > best:
                best, current = value, i
    return np.asarray(selected, dtype=np.int64)


# --------------------------------------------------------------------------- Poisson disk

POISSON_COUNT_REL_TOL = 0.01
"""Default tolerance of :func:`poisson_disk_subsample`: ``|count − n_target| ≤ max(1, 1 %)``."""

_RADIUS_SAMPLE = 1000  # points used to estimate the initial radius
_PACKING = 2.4  # count ≈ 0.6·area/r² for dart throwing, area ≈ 4·N·(mean 1-NN)²


def poisson_disk_subsample(
    points: ArrayLike,
    n_target: int,
    seed: int | np.random.Generator = 0,
    *,
    rel_tol: float = POISSON_COUNT_REL_TOL,
    max_iterations: int = 60,
) -> NDArray:
    """Poisson-disk (blue-noise) subset of a point set with about ``n_target`` points.

    Dart throwing over the candidates: visit the points in a seeded random order and keep a
    point unless a kept point lies within radius ``r`` (Euclidean), so kept points are more
    than ``r`` apart and every dropped point is within ``r`` of a kept one (the idea of
    MeshLab's ``subsample=True`` pruning, not bit-compatible with it). ``r`` is found by a
    bracketed search in log-log space (count ∝ r^-dim) with the visiting order fixed, so the
    result is a deterministic function of ``(points, n_target, seed)`` and invariant to
    uniform scaling, rotation and translation of the input (up to floating-point ties).

    The count is within ``max(1, ⌊rel_tol·n_target⌋)`` of ``n_target`` (±1 for 50, ±5 for
    500, ±70 for 7000 with the default 1 %). Should no radius reach that band (too few
    distinct candidates), the closest count found is returned. ``N <= n_target`` returns all
    points. Candidates should outnumber ``n_target`` several times for a blue-noise result.

    Args:
        points: ``(N, 3)`` candidate positions.
        n_target: wanted number of samples (>= 1).
        seed: seed of the visiting order.

    Returns:
        ``(n,)`` int64 sorted indices into ``points``.
    """
    pts = as_points(points)
    n_points = pts.shape[0]
    if isinstance(n_target, bool) or not isinstance(n_target, int | np.integer) or n_target < 1:
        raise ArrayShapeError(f"n_target must be a positive integer, got {n_target!r}")
    if n_points <= n_target:
        return np.arange(n_points, dtype=np.int64)
    diagonal = float(np.linalg.norm(np.ptp(pts, axis=0)))
    if not diagonal > 0.0:
        raise DegenerateShapeError("cannot Poisson-disk sample points that all coincide")
    from scipy.spatial import cKDTree  # imported on first use (CLI start-up)

    rng = random_generator(seed)
    order = rng.permutation(n_points).tolist()
    tree = cKDTree(pts)
    tolerance = max(1, math.floor(rel_tol * n_target))
    radius = _initial_radius(tree, pts, n_target, diagonal, rng)
    below: tuple[float, int] | None = None  # (radius, count) with count > n_target
    above: tuple[float, int] | None = None  # (radius, count) with count < n_target
    previous: tuple[float, int] | None = None
    best: list[int] = []
    for _ in range(max_iterations):
        accepted = _dart_throwing(tree, pts, order, radius)
        count = len(accepted)
        if not best or abs(count - n_target) < abs(len(best) - n_target):
            best = accepted
        if abs(count - n_target) <= tolerance:
            break
        if count > n_target:
            below = (radius, count)
        else:
            above = (radius, count)
        if above is not None and below is not None and above[0] - below[0] <= 1e-12 * above[0]:
            break  # the count jumps over the tolerance band at this radius
        next_radius = _next_radius((radius, count), previous, n_target, below, above)
        previous, radius = (radius, count), next_radius
        if radius <= 1e-12 * diagonal:
            break  # fewer distinct points than n_target
    return np.sort(np.asarray(best, dtype=np.int64))


def _initial_radius(
    tree: cKDTree, points: NDArray, n_target: int, diagonal: float, rng: np.random.Generator
) -> float:
    """Radius guess for ``n_target`` dart-throwing samples on a surface sampled by ``points``."""
    n_points = points.shape[0]
    probe = rng.choice(n_points, size=min(n_points, _RADIUS_SAMPLE), replace=False)
    nn = tree.query(points[probe], k=2)[0][:, 1]
    mean_nn = float(nn.mean())
    if not mean_nn > 0.0:
        return diagonal / math.sqrt(n_target)
    return mean_nn * math.sqrt(_PACKING * n_points / n_target)


def _dart_throwing(tree: cKDTree, points: NDArray, order: list[int], radius: float) -> list[int]:
    """Keep each point of ``order`` unless a kept point lies within ``radius`` (inclusive).

    Inherently sequential; the Python work is O(1) per candidate, plus one C-level ball query
    per kept point.
    """
    alive = bytearray(b"\x01") * points.shape[0]
    accepted: list[int] = []
    for i in order:
        if alive[i]:
            accepted.append(i)
            for j in tree.query_ball_point(points[i], radius, return_sorted=False):
                alive[j] = 0
    return accepted


def _log_slope(a: tuple[float, int], b: tuple[float, int]) -> float:
    """d log(count) / d log(radius) through two evaluations (negative when well behaved)."""
    if a[0] == b[0]:
        return 0.0
    return math.log(max(a[1], 1) / max(b[1], 1)) / math.log(a[0] / b[0])


def _next_radius(
    current: tuple[float, int],
    previous: tuple[float, int] | None,
    n_target: int,
    below: tuple[float, int] | None,
    above: tuple[float, int] | None,
) -> float:
    """Next radius: log-log secant (slope −2 at first) while one-sided, then a safeguarded
    log-log regula falsi inside the bracket ``below.radius < r < above.radius``."""
    radius, count = current
    if below is None or above is None:
        slope = _log_slope(current, previous) if previous is not None else 0.0
        if not slope < 0.0:
            slope = -2.0  # count ∝ r^-2 on a surface
        step = math.log(n_target / max(count, 1)) / slope
        return radius * math.exp(min(max(step, -math.log(10.0)), math.log(10.0)))
    log_lo, log_hi = math.log(below[0]), math.log(above[0])
    slope = _log_slope(above, below)
    middle = 0.5 * (log_lo + log_hi)
    guess = log_lo + math.log(n_target / below[1]) / slope if slope < 0.0 else middle
    margin = 0.1 * (log_hi - log_lo)
    if not log_lo + margin <= guess <= log_hi - margin:
        guess = middle
    return math.exp(guess)


OUTLIER_NEIGHBOURS = 8
"""Neighbours whose farthest :func:`isolated_points` measures (the k-th nearest other point)."""
OUTLIER_FACTOR = 4.0
"""A point is isolated when its k-th neighbour is farther than this × the cloud's median of
that distance. Clean, noisy (σ 0.02 at unit area) and cut real dev clouds of 300 to 2000 points
have almost none (at most 3 points of a cut TOSCA cloud); at 3.0, sparse FAUST clouds lost up to
4 true points (BENCHMARKS "outliers")."""
EVEN_QUANTILE = 75.0
""":func:`evenly_spread` thins a cloud to the spacing of this percentile of its points' k-th
neighbour distances, over its surface (each point weighed by its area; BENCHMARKS
"even-density")."""
EVEN_MAX_KEEP = 0.6
""":func:`evenly_spread` thins only a cloud that would keep less than this share of its points
(uneven): area-weighted samples keep 0.65–0.74 of theirs (real dev clouds of 2000 points, with
noise or cut), a cloud 20× denser at one end than the other 0.32–0.60, FAUST's own vertices
0.35–0.42."""
EVEN_MIN_POINTS = 1000
"""Fewest points :func:`evenly_spread` thins: in sparser clouds the spacing says little (300
area-weighted samples of a TOSCA animal would keep 0.36–0.70)."""
PROBE_POINTS = 256
""":func:`evenly_spread` first measures this many points of a larger cloud (a fixed random
choice), and looks at every point only where they show a stray point or uneven density: an
8-NN query of 2000 points costs ~2 ms, a probe ~0.4 ms (a 2K-cloud pair costs ~4 ms in all).
A handful of strays can go unseen (at 1 % of the points, 8 % of clouds), moving the descriptor
little."""
PROBE_MARGIN = 0.05
"""The probe passes a cloud as even only when its share kept is this much above
:data:`EVEN_MAX_KEEP` (its estimate is noisy)."""


def _reach(points: NDArray, k: int) -> NDArray:
    """``(N,)`` distance from each point to its ``k``-th nearest other point."""
    from pykdtree.kdtree import KDTree  # imported on first use (CLI start-up)

    return _reach_in(KDTree(points), points, k)


def _reach_in(tree: Any, queries: NDArray, k: int) -> NDArray:
    """``(Q,)`` distance from each of ``queries`` (points of the cloud ``tree`` holds: a
    ``pykdtree`` KD-tree) to its ``k``-th nearest other point of the cloud."""
    return tree.query(queries, k=k + 1)[0][:, -1]  # itself first


def _isolated(reach: NDArray, factor: float) -> NDArray:
    """:func:`isolated_points` from the points' k-th neighbour distances ``reach``."""
    flagged = np.zeros(reach.shape[0], dtype=bool)
    typical = float(np.median(reach))
    if not typical > 0.0:  # most points repeated: no spacing to measure against
        return flagged
    flagged = reach > factor * typical
    return flagged if 2 * int(flagged.sum()) < reach.shape[0] else np.zeros_like(flagged)


def isolated_points(
    points: ArrayLike, k: int = OUTLIER_NEIGHBOURS, factor: float = OUTLIER_FACTOR
) -> NDArray:
    """``(N,)`` bool: the points far from the surface the others sample (a scan's stray points):
    those whose ``k``-th nearest other point lies farther than ``factor`` × the median of that
    distance over the cloud. None is flagged in a cloud of at most ``k + 1`` points, nor where
    half the points or more would be (then there is no one surface to stray from) or that
    median is 0 (most points repeated)."""
    pts = as_points(points)
    if pts.shape[0] <= k + 1:
        return np.zeros(pts.shape[0], dtype=bool)
    return _isolated(_reach(pts, k), factor)


def _area_percentile(reach: NDArray, percent: float) -> float:
    """The ``percent`` percentile of ``reach`` with each point weighed by the area it stands
    for (``∝ reach²``): a dense part's many points count for the little surface they cover."""
    ordered = np.sort(reach)
    covered = np.cumsum(ordered**2)
    if not covered[-1] > 0.0:
        return 0.0
    at = int(np.searchsorted(covered, percent / 100.0 * covered[-1]))
    return float(ordered[min(at, ordered.shape[0] - 1)])


def _keep_chances(reach: NDArray) -> NDArray | None:
    """:func:`evenly_spread`'s chance ``min(1, (r / r_ref)²)`` of keeping each point of these
    k-th neighbour distances ``reach``; ``None`` where ``r_ref`` is 0 (no spacing)."""
    reference = _area_percentile(reach, EVEN_QUANTILE)
    return np.minimum(1.0, (reach / reference) ** 2) if reference > 0.0 else None


def _looks_clean(tree: Any, pts: NDArray) -> bool:
    """Whether :data:`PROBE_POINTS` points of ``pts`` (a fixed random choice; ``tree`` a
    ``pykdtree`` KD-tree of ``pts``) show no isolated point and an even spread."""
    probe = np.random.default_rng(0).choice(pts.shape[0], PROBE_POINTS, replace=False)
    reach = _reach_in(tree, pts[probe], OUTLIER_NEIGHBOURS)
    if _isolated(reach, OUTLIER_FACTOR).any():
        return False
    chance = _keep_chances(reach)
    if pts.shape[0] < EVEN_MIN_POINTS or chance is None:
        return True
    return float(chance.mean()) >= EVEN_MAX_KEEP + PROBE_MARGIN


_KEY_WEIGHTS = np.array([1.0, 0.7548776662466927, 0.5698402909980532])
"""A generic projection of :func:`first_copies`' quick check: distinct points seldom share it,
and when they do the exact test runs anyway."""


def first_copies(points: NDArray) -> NDArray:
    """``(N,)`` int64: for each point the index of the first point at exactly its position (its
    own index where it is the first): the welding of a mesh stored with repeated vertices (a
    triangle soup, an OBJ split along its UV seams)."""
    n = points.shape[0]
    key = np.sort(points @ _KEY_WEIGHTS)  # equal points share a key: no repeat, no copies
    if n < 2 or np.all(key[1:] != key[:-1]):
        return np.arange(n, dtype=np.int64)
    _, first, inverse = np.unique(points, axis=0, return_index=True, return_inverse=True)
    return first[inverse.reshape(-1)].astype(np.int64)


def evenly_spread(points: NDArray, seed: int | np.random.Generator = 0) -> NDArray:
    """``points`` less their repeats (:func:`first_copies`: one per position) and their
    :func:`isolated_points`, thinned where they lie denser than most:
    a point is kept with probability ``min(1, (r / r_ref)²)``, ``r`` its distance to its
    :data:`OUTLIER_NEIGHBOURS`-th nearest point and ``r_ref`` the :data:`EVEN_QUANTILE`
    percentile of ``r`` over the surface (each point weighed by the area it stands for,
    ``∝ r²``: the points per area go as ``1 / r²``), so a scan denser in some parts than
    others comes out about evenly spread, as the area-weighted samples a network is trained
    on. Only a cloud of :data:`EVEN_MIN_POINTS` or more that would keep less than
    :data:`EVEN_MAX_KEEP` of its points is thinned (an even one is left as it is). A cloud
    of more than ``2 ×`` :data:`PROBE_POINTS` points whose probe looks clean is returned as
    it is. Deterministic per seed; ``points`` itself for a cloud of at most ``k + 1`` points.

    Returns:
        ``(M, 3)`` a subset of ``points``, in their order.
    """
    pts = as_points(points)
    if pts.shape[0] <= OUTLIER_NEIGHBOURS + 1:
        return points
    # one sample per position: repeated points add no surface (a cloud sent twice is the cloud)
    index = np.flatnonzero(first_copies(pts) == np.arange(pts.shape[0]))
    if index.shape[0] < pts.shape[0]:
        pts = pts[index]
        if pts.shape[0] <= OUTLIER_NEIGHBOURS + 1:
            return np.asarray(points)[index]
    from pykdtree.kdtree import KDTree  # imported on first use (CLI start-up)

    tree = KDTree(pts)
    if pts.shape[0] > 2 * PROBE_POINTS and _looks_clean(tree, pts):
        return points if index.shape[0] == len(points) else np.asarray(points)[index]
    reach = _reach_in(tree, pts, OUTLIER_NEIGHBOURS)
    kept = ~_isolated(reach, OUTLIER_FACTOR)
    chance = _keep_chances(reach[kept])
    if (
        chance is not None
        and chance.shape[0] >= EVEN_MIN_POINTS
        and float(chance.mean()) < EVEN_MAX_KEEP
    ):
        # one draw per kept point: isolated points take none (a scan with strays spreads as
        # the scan without them, and the stream goes on alike)
        kept[kept] = random_generator(seed).random(chance.shape[0]) < chance
    return np.asarray(points)[index[kept]]


def mean_nearest_neighbour_distance(points: ArrayLike) -> float:
    """Mean Euclidean distance from each point to its nearest other point (input units).

    Duplicate points count with distance 0. Needs at least 2 points.
    """
    from scipy.spatial import cKDTree  # imported on first use (CLI start-up)

    pts = as_points(points, min_points=2)
    distances, _ = cKDTree(pts).query(pts, k=2)
    return float(distances[:, 1].mean())


__all__ = [
    "POISSON_COUNT_REL_TOL",
    "SurfaceSamples",
    "as_points",
    "check_seed",
    "evenly_spread",
    "farthest_point_sampling",
    "first_copies",
    "isolated_points",
    "mean_nearest_neighbour_distance",
    "poisson_disk_subsample",
    "random_generator",
    "sample_surface",
]
