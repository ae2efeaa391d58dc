"""Non-isometric shape matching: prepare each shape once, then match many queries.

:class:`MatchingModel` wraps a matching bundle (T-Net, basis, matching network(s)):

* :meth:`MatchingModel.prepare` puts a shape into the aligned unit-area frame (spec §1.3–1.6),
  computes its UDF-PCA descriptor and the multi-tier NN cache of its points (spec §5.2) →
  :class:`MatchingShape` (small, pickle-free ``to_arrays`` for a cache);
* :meth:`MatchingModel.match` finds, for query points of X, the point of Y minimizing the
  predicted cross-shape geodesic, coarse to fine over Y's cache, all queries at once
  (spec §5.3, :func:`~litege_core.matching.search.coarse_to_fine_search`).

The network is ``head(f(x | z_X) − f(y | z_Y))`` with per-point features ``f`` (see
:class:`~litege_core.predictor.FoldedGeodesicNet`), so features of every point of a shape are
computed once per shape and a search step is the head alone on feature differences.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch
from numpy.typing import ArrayLike, NDArray

from litege_core.arrays import frozen
from litege_core.canonical import Transform
from litege_core.device import resolve_device
from litege_core.errors import (
    ArrayShapeError,
    ArtifactError,
    IndexOutOfRangeError,
    InputError,
    NonFiniteError,
)
from litege_core.matching.bundle import (
    MatchingBundle,
    SearchSettings,
    load_matching_bundle,
    resolve_matching_bundle,
)
from litege_core.matching.cache import NNCache
from litege_core.matching.frame import MatchingPipeline, align_shapes
from litege_core.matching.search import (
    ScoreFn,
    coarse_to_fine_search,
    exhaustive_search,
    max_evaluations,
)
from litege_core.predictor import FoldedGeodesicNet
from litege_core.shape import Shape

MAX_PAIRS_PER_CALL = 16_384
"""(query, candidate) pairs per head call: bounds the ``pairs × 2n`` scratch memory."""
_EMBED_ROWS = 8192


def _text(value: str) -> NDArray:
    return np.frombuffer(value.encode("utf-8"), dtype=np.uint8).copy()


def _untext(array: ArrayLike) -> str:
    return bytes(np.asarray(array, dtype=np.uint8)).decode("utf-8")


@dataclass(frozen=True, eq=False)
class MatchingShape:
    """A shape prepared for matching by one bundle.

    Attributes:
        shape_id: content hash of the shape.
        bundle_hash: content hash of the matching bundle.
        kind: ``"mesh"`` or ``"point_cloud"``.
        scaling: how it was scaled (``unit_area``, ``broken_mesh``, ``cloud_8k``, ``cloud_500``).
        transform: input units → aligned unit-area frame.
        aligned: ``(P, 3)`` float32 candidate points (mesh vertices or cloud points, input
            indexing) in the aligned frame (read-only).
        descriptor: ``(E,)`` float32 UDF-PCA descriptor (read-only).
        residual: PCA reconstruction residual of the descriptor (out-of-distribution signal).
        cache: the multi-tier NN cache of ``aligned``.
        seed: seed of every random draw of the preparation.
    """

    shape_id: str
    bundle_hash: str
    kind: str
    scaling: str
    transform: Transform
    aligned: NDArray
    descriptor: NDArray
    residual: float
    cache: NNCache
    seed: int
    _lazy: dict[str, Any] = field(default_factory=dict, repr=False)

    @property
    def n_points(self) -> int:
        return int(self.aligned.shape[0])

    @property
    def is_mesh(self) -> bool:
        return self.kind == "mesh"

    @property
    def nbytes(self) -> int:
        """Bytes of the arrays and of any computed feature tables."""
        own = sum(a.nbytes for a in self.to_arrays().values())
        lazy = sum(t.element_size() * t.nelement() for t in self._lazy.values())
        return int(own + lazy)

    def to_arrays(self) -> dict[str, NDArray]:
        """Plain numpy arrays, no pickle (the NN cache's arrays are prefixed ``cache.``)."""
        arrays = {
            "shape_id": _text(self.shape_id),
            "bundle_hash": _text(self.bundle_hash),
            "kind": _text(self.kind),
            "scaling": _text(self.scaling),
            "rotation": np.asarray(self.transform.rotation, dtype=np.float64),
            "center": np.asarray(self.transform.center, dtype=np.float64),
            "scale": np.array([self.transform.scale], dtype=np.float64),
            "aligned": np.asarray(self.aligned, dtype=np.float32),
            "descriptor": np.asarray(self.descriptor, dtype=np.float32),
            "residual": np.array([self.residual], dtype=np.float64),
            "seed": np.array([self.seed], dtype=np.int64),
        }
        arrays.update({f"cache.{k}": v for k, v in self.cache.to_arrays().items()})
        return arrays

    @classmethod
    def from_arrays(cls, arrays: dict[str, NDArray]) -> MatchingShape:
        """Inverse of :meth:`to_arrays`.

        Raises:
            ArtifactError: missing keys, wrong shapes or non-finite values.
        """
        try:
            aligned = np.asarray(arrays["aligned"], dtype=np.float32)
            descriptor = np.asarray(arrays["descriptor"], dtype=np.float32)
            cache = NNCache.from_arrays(
                {k[len("cache.") :]: v for k, v in arrays.items() if k.startswith("cache.")}
            )
            prepared = cls(
                shape_id=_untext(arrays["shape_id"]),
                bundle_hash=_untext(arrays["bundle_hash"]),
                kind=_untext(arrays["kind"]),
                scaling=_untext(arrays["scaling"]),
                transform=Transform(
                    arrays["rotation"], arrays["center"], float(arrays["scale"].reshape(-1)[0])
                ),
                aligned=frozen(aligned),
                descriptor=frozen(descriptor),
                residual=float(arrays["residual"].reshape(-1)[0]),
                cache=cache,
                seed=int(arrays["seed"].reshape(-1)[0]),
            )
        except (KeyError, IndexError, ValueError, TypeError, UnicodeDecodeError) as exc:
            raise ArtifactError(f"malformed matching shape: {exc}") from exc
        except InputError as exc:
            raise ArtifactError(f"malformed matching shape: {exc}") from exc
        if aligned.ndim != 2 or aligned.shape[1] != 3 or not np.isfinite(aligned).all():
            raise ArtifactError("malformed matching shape: aligned must be finite (P, 3)")
        if descriptor.ndim != 1 or not np.isfinite(descriptor).all():
            raise ArtifactError("malformed matching shape: descriptor must be a finite vector")
        if cache.n_points != aligned.shape[0]:
            raise ArtifactError("malformed matching shape: cache and points disagree")
        return prepared


@dataclass(frozen=True)
class MatchResult:
    """Matches of ``N`` queries of X on Y.

    Attributes:
        indices: ``(N,)`` int64 matched points of Y (Y's input indexing).
        distance: ``(N,)`` float32 predicted cross-shape geodesic at the match (unit-area units).
        evaluations: network pair evaluations used.
    """

    indices: NDArray
    distance: NDArray
    evaluations: int


class MatchingModel:
    """A loaded matching bundle, ready to prepare shapes and match them.

    Args:
        bundle: a :class:`MatchingBundle` (see :meth:`load`).
        device: where the networks run (default: the bundle's device).
    """

    def __init__(self, bundle: MatchingBundle, device: str | torch.device | None = None) -> None:
        self.bundle = bundle
        self.device = torch.device(device) if device is not None else bundle.device
        for net in bundle.networks:
            net.to(self.device).eval()
        bundle.tnet.to(self.device).eval()
        self._folded = [FoldedGeodesicNet(net, self.device) for net in bundle.networks]
        self._engine = bundle.basis.engine(self.device)

    @classmethod
    def load(
        cls, name_or_path: str | os.PathLike = "quadrupeds", device: str | torch.device = "cpu"
    ) -> MatchingModel:
        """Load a shipped matching model by name, or a bundle directory."""
        resolved = resolve_device(device)
        return cls(load_matching_bundle(resolve_matching_bundle(name_or_path), resolved))

    @classmethod
    def tiny_random(cls, seed: int = 0) -> MatchingModel:
        """An untrained miniature model (random weights, small basis) for fast plumbing
        tests: deterministic for ``seed``, meaningless matches."""
        from litege_core.matching.testing import tiny_matching_bundle

        return cls(tiny_matching_bundle(seed))

    # ------------------------------------------------------------------ properties

    @property
    def name(self) -> str:
        return self.bundle.name

    @property
    def category(self) -> str:
        return self.bundle.category

    @property
    def content_hash(self) -> str:
        return self.bundle.content_hash

    @property
    def pipeline(self) -> MatchingPipeline:
        return self.bundle.pipeline

    @property
    def search(self) -> SearchSettings:
        return self.bundle.search

    def __repr__(self) -> str:
        nets = len(self.bundle.networks)
        return f"MatchingModel({self.name!r}, networks={nets}, device={self.device})"

    # ------------------------------------------------------------------ preparation

    def prepare(self, shape: Shape, *, seed: int = 0, scaling: str = "auto") -> MatchingShape:
        """Prepare one shape (see :meth:`prepare_many`)."""
        return self.prepare_many([shape], seed=seed, scaling=scaling)[0]

    def prepare_many(
        self, shapes: list[Shape], *, seed: int = 0, scaling: str = "auto"
    ) -> list[MatchingShape]:
        """Align, describe and cache several shapes (one T-Net call per point count, one
        descriptor call).

        Args:
            shapes: meshes or point clouds (validated :class:`Shape` objects).
            seed: seed of the surface samples and Poisson subsets.
            scaling: ``"auto"`` or a fixed scaling (see :mod:`litege_core.matching.frame`).
        """
        shapes = list(shapes)
        for i, shape in enumerate(shapes):
            if not isinstance(shape, Shape):
                raise InputError(f"shapes[{i}] is a {type(shape).__name__}, not a Shape")
        if not shapes:
            return []
        frames = align_shapes(
            shapes, self.bundle.tnet, self.pipeline, scaling=scaling, seed=int(seed)
        )
        described = self._engine.describe_with_residual(
            [cloud.astype(np.float32) for _, cloud, _ in frames]
        )
        descriptors = described.descriptors.detach().cpu().numpy().astype(np.float32)
        residuals = described.residual.detach().cpu().numpy().astype(np.float64)
        search = self.search
        prepared = []
        for b, (shape, (transform, _, chosen)) in enumerate(zip(shapes, frames, strict=True)):
            aligned = transform.apply(shape.vertices)
            cache = NNCache.build(
                aligned,
                tier_sizes=search.tier_sizes,
                neighbours=search.neighbours,
                strategy=search.strategy,  # type: ignore[arg-type]
                seed=int(seed),
            )
            prepared.append(
                MatchingShape(
                    shape_id=shape.content_hash,
                    bundle_hash=self.content_hash,
                    kind=shape.kind,
                    scaling=chosen,
                    transform=transform,
                    aligned=frozen(aligned, np.float32),
                    descriptor=frozen(descriptors[b]),
                    residual=float(residuals[b]),
                    cache=cache,
                    seed=int(seed),
                )
            )
        return prepared

    # ------------------------------------------------------------------ features

    def _check(self, prepared: MatchingShape, what: str) -> None:
        if not isinstance(prepared, MatchingShape):
            raise InputError(f"{what} must be a MatchingShape from MatchingModel.prepare")
        if prepared.bundle_hash != self.content_hash:
            raise InputError(f"{what} was prepared with another matching model; prepare it again")

    def _biases(self, prepared: MatchingShape) -> list[torch.Tensor]:
        desc = torch.tensor(prepared.descriptor[None], device=self.device)
        with torch.no_grad():
            return [
                f.shape_bias(net.shape_embedding(desc))[0]
                for f, net in zip(self._folded, self.bundle.networks, strict=True)
            ]

    def _point_features(
        self, points: torch.Tensor, biases: list[torch.Tensor]
    ) -> list[torch.Tensor]:
        """``(R, 3)`` aligned points → per network ``(R, 2n)`` head features."""
        out = []
        with torch.no_grad():
            for folded, bias in zip(self._folded, biases, strict=True):
                chunks = [
                    folded.features(folded.embed(points[i : i + _EMBED_ROWS], bias))
                    for i in range(0, max(points.shape[0], 1), _EMBED_ROWS)
                ]
                out.append(torch.cat(chunks))
        return out

    def features(self, prepared: MatchingShape) -> list[torch.Tensor]:
        """Head features of every point of a prepared shape, per network (memoized)."""
        self._check(prepared, "shape")
        key = f"features:{self.device}"
        cached = prepared._lazy.get(key)
        if cached is None:
            points = torch.tensor(prepared.aligned, device=self.device)
            cached = torch.stack(self._point_features(points, self._biases(prepared)))
            prepared._lazy[key] = cached
        return list(cached)

    def _query_features(
        self,
        source: MatchingShape,
        queries: ArrayLike | None,
        query_points: ArrayLike | None,
    ) -> list[torch.Tensor]:
        if queries is not None and query_points is not None:
            raise InputError("give queries (indices) or query_points, not both")
        if query_points is not None:
            pts = np.asarray(query_points, dtype=np.float64)
            if pts.ndim != 2 or pts.shape[1] != 3:
                raise ArrayShapeError(f"query_points must have shape (N, 3), got {pts.shape}")
            if not np.isfinite(pts).all():
                raise NonFiniteError("query_points contain NaN or infinite coordinates")
            aligned = torch.from_numpy(source.transform.apply(pts).astype(np.float32))
            return self._point_features(aligned.to(self.device), self._biases(source))
        table = self.features(source)
        if queries is None:
            return table
        rows = check_indices(queries, source.n_points, "queries")
        index = torch.from_numpy(rows).to(self.device)
        return [t.index_select(0, index) for t in table]

    # ------------------------------------------------------------------ matching

    def _score_fn(self, query: list[torch.Tensor], target: list[torch.Tensor]) -> ScoreFn:
        return ensemble_score_fn(self._folded, query, target)

    @torch.no_grad()
    def match(
        self,
        source: MatchingShape,
        target: MatchingShape,
        queries: ArrayLike | None = None,
        *,
        query_points: ArrayLike | None = None,
        beams: int | None = None,
        exhaustive: bool = False,
    ) -> MatchResult:
        """Match query points of ``source`` (X) on ``target`` (Y).

        Args:
            source, target: prepared shapes (same model).
            queries: ``(N,)`` point indices of X; with neither this nor ``query_points``,
                every point of X.
            query_points: ``(N, 3)`` points in X's input units instead of indices.
            beams: candidates kept per coarse tier (default: the bundle's search setting).
            exhaustive: score every point of Y (the slow reference of the search).

        Raises:
            IndexOutOfRangeError, ArrayShapeError, NonFiniteError: bad queries.
        """
        self._check(target, "target")
        query = self._query_features(source, queries, query_points)
        n_queries = int(query[0].shape[0])
        score = self._score_fn(query, self.features(target))
        if exhaustive:
            found, value = exhaustive_search(
                score, n_queries, target.n_points, device=self.device, max_pairs=MAX_PAIRS_PER_CALL
            )
            evaluations = n_queries * target.n_points
        else:
            width = self.search.beams if beams is None else beams
            found, value = coarse_to_fine_search(
                target.cache,
                score,
                n_queries,
                beams=width,
                device=self.device,
                max_pairs=MAX_PAIRS_PER_CALL,
            )
            evaluations = n_queries * max_evaluations(target.cache, width)
        distance = value.float().cpu().numpy() / self.pipeline.target_scale
        return MatchResult(
            indices=found.cpu().numpy().astype(np.int64),
            distance=distance.astype(np.float32),
            evaluations=int(evaluations),
        )

    @torch.no_grad()
    def cross_distances(
        self,
        source: MatchingShape,
        target: MatchingShape,
        queries: ArrayLike,
        candidates: ArrayLike,
    ) -> NDArray:
        """Predicted cross-shape geodesics ``(N, M)`` (unit-area units) between query points
        of X and candidate points of Y (the matrix the search minimizes over)."""
        self._check(target, "target")
        query = self._query_features(source, queries, None)
        cols = check_indices(candidates, target.n_points, "candidates")
        rows = torch.arange(query[0].shape[0], device=self.device)
        cand = torch.from_numpy(cols).to(self.device).expand(rows.shape[0], cols.size)
        out = self._score_fn(query, self.features(target))(rows, cand)
        return out.cpu().numpy() / self.pipeline.target_scale


def ensemble_score_fn(
    networks: list[FoldedGeodesicNet], query: list[torch.Tensor], target: list[torch.Tensor]
) -> ScoreFn:
    """The search's score: network outputs on head-feature differences, averaged over the
    networks.

    Args:
        networks: folded networks (one, or an ensemble).
        query: per network ``(Q, 2n)`` head features of the query points of X.
        target: per network ``(P, 2n)`` head features of the points of Y.
    """
    scale = 1.0 / len(networks)

    def score(rows: torch.Tensor, cand: torch.Tensor) -> torch.Tensor:
        m, c = cand.shape
        total = None
        for net, q, t in zip(networks, query, target, strict=True):
            diff = q.index_select(0, rows)[:, None, :] - t[cand]
            out = net.head(diff.reshape(m * c, -1), inplace=True).reshape(m, c)
            total = out if total is None else total + out
        return total * scale

    return score


def check_indices(values: ArrayLike, n_points: int, what: str) -> NDArray:
    """``values`` as a non-empty ``(N,)`` int64 array of indices in ``[0, n_points)``."""
    array = np.asarray(values)
    if array.ndim != 1 or array.size == 0:
        raise ArrayShapeError(f"{what} must be a non-empty 1-d list of indices")
    integral = np.issubdtype(array.dtype, np.integer) or (
        np.issubdtype(array.dtype, np.floating)
        and np.isfinite(array).all()
        and np.all(array == np.round(array))
    )
    if not integral:
        raise InputError(f"{what} must be integers")
    array = array.astype(np.int64)
    bad = (array < 0) | (array >= n_points)
    if bad.any():
        raise IndexOutOfRangeError(
            f"{what}[{int(np.argmax(bad))}] = {int(array[bad][0])} is outside [0, {n_points})"
        )
    return array
