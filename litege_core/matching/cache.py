"""Multi-tier nearest-neighbour cache of a target shape Y (reference-spec §5.2, §10 item 18).

The cache is built once per target shape from its points ``(N, 3)`` (canonical coordinates)
and holds only integer tables, so :func:`~litege_core.matching.search.coarse_to_fine_search`
is pure tensor indexing:

* **tiers** ``T_0 ⊂ … ⊂ T_{K-1}`` of increasing size; the last tier is always all ``N``
  points (stored implicitly). ``tiers[j]`` is an ``(n_j,)`` int64 array of point indices.
* **neighbour tables**: for each link ``j → j+1`` an ``(n_j, k_j)`` int64 array whose row
  ``r`` holds the *rows of tier j+1* (positions in ``tiers[j+1]``, which for the last tier are
  point indices) of the ``k_j`` points of tier ``j+1`` nearest to point ``tiers[j][r]``,
  nearest first (Euclidean distance in the coordinates given, found with a KD-tree).

Two tier strategies:

* ``"fps"`` (default): one farthest-point ordering of Y, tier ``j`` is its first ``n_j``
  points, so tiers are nested and every tier has the max-min coverage of FPS. Because a point
  of tier ``j`` is also in tier ``j+1``, it is its own nearest neighbour there and the search
  can never lose a candidate on the way down. Deterministic (starts at ``start_index``).
* ``"random"``: the reference's ``buildcache_3tiers``: every tier an independent uniform
  sample without replacement (tiers are *not* nested), seeded.

Unlike the reference, neighbourhoods use the coordinates as given (pass canonical, not
z-scored, coordinates; spec §5.2 🐞). Sizes at or above ``N`` are dropped, so a small shape
gets fewer tiers (down to one tier: exhaustive search). Link ``j`` always uses ``k_j``;
``k_j`` is clipped to the size of tier ``j+1``.

Serialization is pickle-free: :meth:`NNCache.to_arrays` gives a flat ``dict`` of int64 numpy
arrays (what the service stores in Redis) and :meth:`NNCache.from_arrays` validates and
rebuilds it, raising :class:`~litege_core.errors.ArtifactError` on anything malformed.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, Literal, get_args

import numpy as np
import torch
from numpy.typing import ArrayLike, NDArray
from pykdtree.kdtree import KDTree

from litege_core.arrays import frozen
from litege_core.errors import ArtifactError, IndexOutOfRangeError, InputError
from litege_core.sampling import as_points, farthest_point_sampling

TierStrategy = Literal["fps", "random"]
_STRATEGIES: tuple[str, ...] = get_args(TierStrategy)

DEFAULT_TIER_SIZES: tuple[int, ...] = (60, 650)
"""Sizes of the sub-sampled tiers (the reference's remeshed-5K configuration, spec §5.2);
the full point set is the implicit last tier."""

DEFAULT_NEIGHBOURS: tuple[int, ...] = (65, 60)
"""``k_j`` of each link ``tier j → tier j+1`` (reference: M1 = 65, M2 = 60)."""

FORMAT_VERSION = 1
"""Version of the :meth:`NNCache.to_arrays` layout."""

_META_FIELDS = ("version", "n_points", "n_tiers", "strategy", "seed", "start_index")


def _positive_ints(values: int | Sequence[int], name: str) -> tuple[int, ...]:
    items = (values,) if isinstance(values, int | np.integer) else tuple(values)
    for value in items:
        if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < 1:
            raise InputError(f"{name} must be positive integers, got {values!r}")
    return tuple(int(v) for v in items)


def _knn(data: NDArray, queries: NDArray, k: int) -> NDArray:
    """``(M, k)`` int64 rows of ``data`` nearest to each query, nearest first (KD-tree)."""
    _, index = KDTree(data).query(queries, k=k)
    return np.asarray(index, dtype=np.int64).reshape(queries.shape[0], k)


def _candidate_indices(candidates: ArrayLike | None, n_points: int) -> NDArray:
    """``(C,)`` sorted distinct int64 point indices of ``candidates`` (``None``: all ``N``).

    Raises:
        InputError: not a non-empty 1-d integer array, or repeated indices.
        IndexOutOfRangeError: an index outside ``[0, N)``.
    """
    if candidates is None:
        return np.arange(n_points, dtype=np.int64)
    pool = np.asarray(candidates)
    if pool.ndim != 1 or pool.size == 0 or not np.issubdtype(pool.dtype, np.integer):
        raise InputError(f"candidates must be a non-empty 1-d integer array, got {pool.shape}")
    if pool.min() < 0 or pool.max() >= n_points:
        raise IndexOutOfRangeError(f"a candidate lies outside [0, {n_points})")
    pool = np.sort(pool.astype(np.int64))
    if np.any(pool[1:] == pool[:-1]):
        raise InputError("candidates must not repeat")
    return pool


def coverage_radius(points: ArrayLike, subset: ArrayLike) -> float:
    """Largest distance from any point to its nearest point of ``subset``.

    Args:
        points: ``(N, 3)`` coordinates.
        subset: ``(n,)`` indices into ``points`` (non-empty).

    Returns:
        The covering radius in the units of ``points`` (0 when ``subset`` is every point).
    """
    pts = as_points(points)
    index = np.asarray(subset, dtype=np.int64).reshape(-1)
    if index.size == 0:
        raise InputError("subset must not be empty")
    if index.min() < 0 or index.max() >= pts.shape[0]:
        raise IndexOutOfRangeError(f"subset index outside [0, {pts.shape[0]})")
    distance, _ = KDTree(pts[index]).query(pts, k=1)
    return float(np.max(distance))


@dataclass(frozen=True, eq=False)
class NNCache:
    """Tiers and neighbour tables of one target shape (build with :meth:`NNCache.build`).

    Attributes:
        n_points: ``N``, points of the target (the implicit last tier).
        tiers: ``K-1`` read-only int64 arrays ``(n_j,)`` of point indices, ``n_0 < n_1 < …
            < N`` (empty when ``N`` is at most the smallest configured size).
        neighbours: ``K-1`` read-only int64 tables ``(n_j, k_j)``; entries are rows of tier
            ``j+1`` (point indices for the last link).
        strategy: ``"fps"`` or ``"random"``.
        seed: seed of the random tiers (recorded, unused by FPS).
        start_index: first FPS point (recorded, unused by the random strategy).
    """

    n_points: int
    tiers: tuple[NDArray, ...]
    neighbours: tuple[NDArray, ...]
    strategy: TierStrategy = "fps"
    seed: int = 0
    start_index: int = 0
    _lazy: dict[str, Any] = field(default_factory=dict, repr=False)

    # ------------------------------------------------------------------ construction

    @classmethod
    def build(
        cls,
        points: ArrayLike,
        *,
        tier_sizes: int | Sequence[int] = DEFAULT_TIER_SIZES,
        neighbours: int | Sequence[int] = DEFAULT_NEIGHBOURS,
        strategy: TierStrategy = "fps",
        seed: int = 0,
        start_index: int = 0,
        candidates: ArrayLike | None = None,
    ) -> NNCache:
        """Build the cache of a target shape.

        Args:
            points: ``(N, 3)`` float64 coordinates of Y (canonical units); the search
                returns indices into this array.
            tier_sizes: strictly increasing sizes of the sub-sampled tiers; sizes ``>= N``
                are dropped.
            neighbours: ``k_j`` per link (one per entry of ``tier_sizes``, or one int for
                all); clipped to the size of the tier linked into.
            strategy: ``"fps"`` (nested farthest-point tiers) or ``"random"`` (the
                reference's independent uniform samples).
            seed: seed of the random tiers.
            start_index: first point of the FPS ordering (the first candidate where it is
                not one).
            candidates: ``(C,)`` indices of the points a search may return (default: all;
                e.g. a scan less its stray points): the tiers and the last link hold only
                these, and with fewer than ``N`` a target too small for any tier gets one
                tier of them all.

        Raises:
            ArrayShapeError, EmptyShapeError, NonFiniteError: bad ``points``.
            InputError: bad sizes, neighbour counts, strategy or candidates.
            IndexOutOfRangeError: ``start_index`` or a candidate outside the points.
        """
        pts = as_points(points)
        n_points = pts.shape[0]
        sizes = _positive_ints(tier_sizes, "tier_sizes")
        if any(b <= a for a, b in itertools.pairwise(sizes)):
            raise InputError(f"tier_sizes must be strictly increasing, got {list(sizes)}")
        counts = _positive_ints(neighbours, "neighbours")
        if len(counts) == 1:
            counts = counts * len(sizes)
        if len(counts) != len(sizes):
            raise InputError(
                f"need one neighbour count per tier size ({len(sizes)}), got {list(counts)}"
            )
        if strategy not in _STRATEGIES:
            raise InputError(f"strategy must be one of {list(_STRATEGIES)}, got {strategy!r}")
        if isinstance(seed, bool) or not isinstance(seed, int | np.integer):
            raise InputError(f"seed must be an integer, got {seed!r}")
        if not 0 <= start_index < n_points:
            raise IndexOutOfRangeError(f"start_index {start_index} outside [0, {n_points})")
        pool = _candidate_indices(candidates, n_points)  # (C,) sorted point indices
        kept = [s for s in sizes if s < pool.shape[0]]
        if strategy == "fps":
            at = int(np.searchsorted(pool, start_index))
            first = at if at < pool.shape[0] and pool[at] == start_index else 0
            order = farthest_point_sampling(pts[pool], kept[-1], first) if kept else None
            tiers = [pool[order[:size]] for size in kept] if order is not None else []
        else:
            rng = np.random.default_rng(int(seed))
            tiers = [pool[rng.choice(pool.shape[0], size=size, replace=False)] for size in kept]
        if not tiers and pool.shape[0] < n_points:  # one tier: every candidate
            tiers = [pool]
        tables = []
        for j, tier in enumerate(tiers):
            finer = tiers[j + 1] if j + 1 < len(tiers) else pool
            k = min(counts[j], finer.shape[0])
            rows = _knn(pts[finer], pts[tier], k)
            tables.append(rows if j + 1 < len(tiers) else pool[rows])  # last link: points
        return cls(
            n_points=n_points,
            tiers=tuple(frozen(t, np.int64) for t in tiers),
            neighbours=tuple(frozen(t, np.int64) for t in tables),
            strategy=strategy,
            seed=int(seed),
            start_index=int(start_index),
        )

    # ------------------------------------------------------------------ properties

    @property
    def n_tiers(self) -> int:
        """``K``, including the full-resolution tier."""
        return len(self.tiers) + 1

    @property
    def tier_sizes(self) -> tuple[int, ...]:
        """``(n_0, …, n_{K-2}, N)``."""
        return (*(int(t.shape[0]) for t in self.tiers), self.n_points)

    @property
    def neighbour_counts(self) -> tuple[int, ...]:
        """``(k_0, …, k_{K-2})``."""
        return tuple(int(t.shape[1]) for t in self.neighbours)

    @property
    def nbytes(self) -> int:
        """Bytes of the index arrays (for cache accounting; tensor copies not counted)."""
        return int(sum(a.nbytes for a in (*self.tiers, *self.neighbours)))

    def coverage_radii(self, points: ArrayLike) -> NDArray:
        """``(K-1,)`` covering radius of each sub-sampled tier (see :func:`coverage_radius`).

        Args:
            points: ``(N, 3)`` the coordinates the cache was built from.
        """
        pts = as_points(points)
        if pts.shape[0] != self.n_points:
            raise InputError(f"cache has {self.n_points} points, got {pts.shape[0]}")
        return np.array([coverage_radius(pts, tier) for tier in self.tiers], dtype=np.float64)

    def tensors(self, device: torch.device | str = "cpu") -> tuple[list[torch.Tensor], ...]:
        """``(tiers, neighbours)`` as int64 tensors on ``device`` (memoized per device).

        Treat them as read-only: they are shared between searches.
        """
        key = str(torch.device(device))
        cached = self._lazy.get(key)
        if cached is None:
            cached = (
                [torch.as_tensor(t.copy()).to(key) for t in self.tiers],
                [torch.as_tensor(t.copy()).to(key) for t in self.neighbours],
            )
            self._lazy[key] = cached
        return cached

    # ------------------------------------------------------------------ serialization

    def to_arrays(self) -> dict[str, NDArray]:
        """Plain int64 numpy arrays, no pickle: ``meta`` (``version, n_points, n_tiers,
        strategy (0 fps, 1 random), seed, start_index``), ``tier_j`` and ``neighbours_j``
        for ``j < K-1``."""
        meta = np.array(
            [
                FORMAT_VERSION,
                self.n_points,
                self.n_tiers,
                _STRATEGIES.index(self.strategy),
                self.seed,
                self.start_index,
            ],
            dtype=np.int64,
        )
        arrays = {"meta": meta}
        for j, (tier, table) in enumerate(zip(self.tiers, self.neighbours, strict=True)):
            arrays[f"tier_{j}"] = np.array(tier, dtype=np.int64)
            arrays[f"neighbours_{j}"] = np.array(table, dtype=np.int64)
        return arrays

    @classmethod
    def from_arrays(cls, arrays: dict[str, NDArray]) -> NNCache:
        """Inverse of :meth:`to_arrays`, with full validation.

        Raises:
            ArtifactError: missing keys, unknown version, wrong shapes or dtypes, indices out
                of range, tiers not strictly increasing or with repeated points.
        """
        try:
            meta = np.asarray(arrays["meta"])
            if meta.shape != (len(_META_FIELDS),) or not np.issubdtype(meta.dtype, np.integer):
                raise ArtifactError(f"meta must be {len(_META_FIELDS)} integers")
            version, n_points, n_tiers, strategy, seed, start = (int(v) for v in meta)
            if version != FORMAT_VERSION:
                raise ArtifactError(f"unsupported cache format version {version}")
            if n_points < 1 or n_tiers < 1 or not 0 <= strategy < len(_STRATEGIES):
                raise ArtifactError("meta holds invalid values")
            expected = {"meta"} | {
                f"{name}_{j}" for j in range(n_tiers - 1) for name in ("tier", "neighbours")
            }
            if set(arrays) != expected:
                raise ArtifactError(f"keys {sorted(arrays)} differ from {sorted(expected)}")
            tiers = [cls._index_array(arrays[f"tier_{j}"], 1) for j in range(n_tiers - 1)]
            tables = [cls._index_array(arrays[f"neighbours_{j}"], 2) for j in range(n_tiers - 1)]
        except KeyError as exc:
            raise ArtifactError(f"malformed NN cache: missing {exc}") from exc
        except ArtifactError as exc:
            raise ArtifactError(f"malformed NN cache: {exc}") from exc
        sizes = [t.shape[0] for t in tiers] + [n_points]
        for j, tier in enumerate(tiers):
            if not 0 < sizes[j] < sizes[j + 1]:
                raise ArtifactError("malformed NN cache: tier sizes must increase below N")
            if tier.min() < 0 or tier.max() >= n_points or np.unique(tier).size != tier.size:
                raise ArtifactError(f"malformed NN cache: tier {j} has bad point indices")
            table = tables[j]
            if table.shape[0] != sizes[j] or not 1 <= table.shape[1] <= sizes[j + 1]:
                raise ArtifactError(f"malformed NN cache: neighbours_{j} has shape {table.shape}")
            if table.min() < 0 or table.max() >= sizes[j + 1]:
                raise ArtifactError(f"malformed NN cache: neighbours_{j} index out of range")
        if not 0 <= start < n_points:
            raise ArtifactError("malformed NN cache: start_index out of range")
        return cls(
            n_points=n_points,
            tiers=tuple(frozen(t) for t in tiers),
            neighbours=tuple(frozen(t) for t in tables),
            strategy=_STRATEGIES[strategy],  # type: ignore[arg-type]
            seed=seed,
            start_index=start,
        )

    @staticmethod
    def _index_array(value: Any, ndim: int) -> NDArray:
        array = np.asarray(value)
        if array.ndim != ndim or array.size == 0 or not np.issubdtype(array.dtype, np.integer):
            raise ArtifactError(f"expected a non-empty {ndim}-d integer array, got {array.shape}")
        return array.astype(np.int64, copy=False)


__all__ = [
    "DEFAULT_NEIGHBOURS",
    "DEFAULT_TIER_SIZES",
    "FORMAT_VERSION",
    "NNCache",
    "TierStrategy",
    "coverage_radius",
]
