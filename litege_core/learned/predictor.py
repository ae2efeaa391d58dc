"""The object the service holds: register a shape once, then answer geodesic queries fast.

::

    from litege_core.learned import Predictor, load_shipped

    predictor = Predictor(load_shipped("quadrupeds"))        # once per process
    state = predictor.register(shape)                        # once per shape (~ms)
    d = predictor.distances(state, [0, 17, 42])              # (3, N) float32, user's units
    field = predictor.distance_field(state, 17)              # (N,)
    path = predictor.path(state, 17, 4242)                   # GeodesicPath, user's frame

**Units and frames.** Every input (xyz query points) and output (distances, path points) is in
the *user's* frame and units: the shape is canonicalized internally with the bundle's pipeline
(bounding-box scaling and PCA alignment, reference-spec §1.2) and the predictions are mapped
back with the registration's :class:`~litege_core.canonical.Transform` (distances are divided
by its scale). The model is a residual model (spec §3.3)::

    G(s, d) = |head(e_s − e_d)| / 1.42 + ‖s − d‖          (canonical units, then / scale)

and pairs whose two points coincide (a source equal to a target index, or an xyz query that
projects exactly onto a target vertex) get an exact ``0``.

**What is cached** (:class:`ShapeState`, built by :meth:`Predictor.register`): the canonical
transform, the UDF-PCA descriptor and its reconstruction residual (out-of-distribution score),
the canonical vertices and the shape embedding, as tensors on the predictor's device. Point
features ``f_p`` (the point embedding pushed through the head's first linear layer, see
:mod:`litege_core.nets.folded`) are computed only for the points a query needs: a query of a
few points embeds just those; one that needs most of the shape (a distance field, ``"all"``)
builds the ``(N, 2n)`` table once and keeps it with the state (:meth:`Predictor.point_table`).
A query then runs only the rest of the head.

**Small head (the default where a bundle ships one).** ``head="small"`` (and ``"auto"``, the
default, for a bundle with ``head-small.*`` beside its files) runs the bundle's distilled head
(:mod:`litege_core.nets.small_head`): ``(N, m)`` point features and ``m·k`` multiply-adds per
pair instead of ``(2n)²``, with the same target scale, residual and zero-diagonal rule;
``head="full"`` runs the trained head.

**Inference-time folding.** The predictor folds the network, in eval mode and in float64, into
plain affine maps (:class:`~litege_core.nets.FoldedGeodesicNet`). A pair then costs one
subtraction, a ReLU, one ``2n × 2n`` matrix product and a dot product; results equal
``GeodesicNet.forward`` to float32 rounding (tested to 1e-5). The path tracer differentiates the
same folded maps with autograd with respect to *canonical* coordinates (the z-score is inside),
so the gradient is the true one (spec §6 chain-rule bug not repeated).

**Memory bound.** A query is evaluated in chunks of at most ``chunk_pairs`` (source, target)
pairs; the temporary memory of a chunk is about ``chunk_pairs × (4n + 8) × 4`` bytes
(≈ 53 MB for the regression width ``n = 200`` and the default 16,384 pairs), independent of
``S × T``. The output itself is ``S × T × 4`` bytes.

**Out-of-distribution score.** ``residual`` is the PCA reconstruction residual of the shape's
UDF. When the bundle manifest's ``training`` section holds ``residual_mean`` and
``residual_std`` (the residuals of the training shapes), ``ood_score`` is the z-score
``(residual − mean) / std``, and :attr:`ShapeState.is_out_of_distribution` is ``True`` above
:data:`OOD_Z_THRESHOLD` = 3 (about the 99.9th percentile of a normal training distribution).
Otherwise ``ood_score`` is the raw residual and ``is_out_of_distribution`` is ``None`` (no
calibration to compare with).
"""

from __future__ import annotations

import functools
import hashlib
import math
from collections.abc import Callable, Sequence
from typing import Any, cast

import numpy as np
import torch
from numpy.typing import ArrayLike, NDArray

from litege_core.arrays import frozen
from litege_core.canonical import canonicalize_bbox_many
from litege_core.descriptor.basis import AUTO_LATTICE
from litege_core.device import resolve_device
from litege_core.errors import ArrayShapeError, ArtifactError, InputError
from litege_core.learned.bundle import ModelBundle
from litege_core.learned.describe import shape_samples
from litege_core.learned.frame import FrameChoice, turned_frames
from litege_core.learned.fusion import cloud_graph_key, fused_distances, route_trees, shape_graph
from litege_core.learned.fusion_calibration import DEFAULT_FUSION, FusionCalibration, resolve_fusion
from litege_core.learned.manifest import (
    AUTO_HEAD,
    HEADS,
    check_pipeline,
    residual_statistics,
    resolve_head,
)
from litege_core.learned.paths import (
    GeodesicPath,
    SurfaceRouter,
    default_router,
    trace_path,
    trace_paths,
)
from litege_core.learned.routing import AGREEMENT_SOURCES, shape_agreement
from litege_core.learned.state import OOD_Z_THRESHOLD, ResolvedPoints, ShapeRecord, ShapeState
from litege_core.learned.veto_graph import EdgeGeodesics, LazyVetoGraph, grown_features
from litege_core.nets import FoldedGeodesicNet, FoldedShapeMlp
from litege_core.nets.folded import resolve_precision
from litege_core.nets.small_head import FoldedSmallHead, SmallHead
from litege_core.projection import snap
from litege_core.query import QueryLike, parse_query
from litege_core.shape import Shape

DEFAULT_CHUNK_PAIRS = 16_384
"""(source, target) pairs per head evaluation; bounds the temporary memory of a query."""

DEFAULT_EMBED_ROWS = 32_768
"""Points per point-embedding evaluation (feature tables and on-the-fly queries)."""

DENSE_MIN_PAIRS = 512
"""A query of this many pairs or more runs on its own by broadcasting (a distance field, a
matrix); smaller ones are concatenated with other shapes' pairs into one head evaluation.
Gathering the features of a 1 → 2000 field costs more than its head (issue 17 profile)."""

DEFAULT_PRECISION = "float32"
"""Arithmetic of the folded network (see :class:`Predictor`)."""
EMBED_PRECISIONS = ("float32", "bfloat16", "int8", "auto")
"""Values of :class:`Predictor`'s ``embed_precision``."""

TABLE_FRACTION = 0.25
"""A query of more than this fraction of a shape's points builds (and keeps) the shape's whole
feature table; smaller ones embed just their points."""


# --------------------------------------------------------------------------- predictor


class Predictor:
    """Learned geodesic distances and paths for registered shapes (one bundle, one device).

    Args:
        bundle: a loaded :class:`~litege_core.learned.bundle.ModelBundle` (regression network).
        device: ``"cpu"``, ``"cuda"``, ``"auto"`` (CUDA where available), ... where every cached
            tensor and query runs (:func:`~litege_core.device.resolve_device`: a malformed device
            or CUDA without a GPU is an InputError).
        chunk_pairs: pairs per head evaluation (memory bound, see the module docstring).
        precision: arithmetic of the folded network without autograd (paths always run
            float32): ``"float32"``, ``"bfloat16"`` (the head's per-pair product in bfloat16
            with float32 accumulation; point features stay float32), ``"int8"`` (that product
            in int8) or ``"auto"`` (bfloat16 where the device multiplies it natively, else
            float32); see :mod:`litege_core.nets.folded` and BENCHMARKS.md
            ``predictor-accuracy``.
        embed_precision: arithmetic of the point MLP (the per-point cost of a distance
            field) without autograd: ``"float32"`` (default), ``"bfloat16"`` (its products
            in bfloat16 with float32 accumulation: ~4× faster products where the CPU has AMX
            tiles, slower on an AVX2 one; BENCHMARKS ``bf16-point-mlp``), ``"int8"`` (CPU
            only: its ``n × n`` products in dynamic int8, fields ~1.2–1.4× faster on an AVX2
            CPU, real-shape error within 0.07: BENCHMARKS ``int8-point-mlp``) or ``"auto"``
            (bfloat16 where the device multiplies it natively, else float32); a predictor
            keeps its own feature tables per setting.
        descriptor_lattice: the informative voxels the UDF is evaluated at: ``"auto"``
            (default: ``"stride2"`` where the basis keeps enough voxels there, as the shipped
            ones do, else ``"full"``; :meth:`~litege_core.descriptor.basis.UdfPcaBasis.
            resolve_lattice`), ``"full"`` (every voxel: the trained descriptor) or a sparser
            lattice (``"bcc"`` 1/4, ``"stride2"`` 1/8, least-squares codes;
            :data:`litege_core.descriptor.basis.VOXEL_LATTICES`). ``descriptor_lattice``
            holds the resolved name. Records of a sparser lattice are approximations of the
            full ones: do not mix lattices in one record cache.
        head: the distance head every query runs: ``"auto"`` (default: ``"small"`` when the
            bundle ships one, as the shipped models do, else ``"full"``), ``"full"`` (the
            trained head) or ``"small"`` (the bundle's distilled head, ``head-small.*`` beside
            the bundle files, :mod:`litege_core.learned.small_head`; ``m·k + k`` instead of
            ``4n² + 2n`` multiply-adds per pair, its accuracy and speed recorded in its
            ``head-small.json``). A :class:`~litege_core.nets.small_head.SmallHead` module is
            taken as the small head as it is (a fresh distillation; no teacher check). With
            the small head, distances, distance fields, batches and paths all use it (a
            path then follows the small head's distance, and its ``predicted_distance``
            equals :meth:`distances` without fusion); ``precision`` applies to the full head
            (the small head runs float32, except under ``"int8"``: its per-pair product in
            dynamic int8 on a CPU, :class:`~litege_core.nets.small_head.FoldedSmallHead`;
            BENCHMARKS ``int8-point-mlp``). Registrations (records, states) do not depend on the
            head: a state may be queried by a full-head and a small-head predictor of the
            same bundle, each building its own feature table.
        fusion: ``"auto"`` (default: ``"graph"`` where the bundle ships a calibration, as
            the shipped ones do, else ``"none"``), ``"none"`` (the network's distances) or
            ``"graph"`` (a calibrated graph Dijkstra: over a mesh's own edges alone, the
            network only between parts they do not connect; over a cloud's network-pruned kNN
            graph blended with the network, weighted per shape by its OOD z-score, point count
            and roughness; :mod:`litege_core.learned.fusion`, ``fusion.json`` beside the
            bundle files), or a
            :class:`~litege_core.learned.fusion_calibration.FusionCalibration` taken as it is
            (a fresh calibration; its bundle hash must still match). Needs the bundle's residual
            statistics (the OOD z-score). Applies to :meth:`distances` and everything built
            on it; its paths follow the same graphs (:meth:`surface_router`,
            ``route="auto"``). The graph's edges are vetoed by the head the calibration names
            (``veto_head``: the shipped ones use the small head).
        udf_backend: how the descriptor's UDF is computed (:mod:`litege_core.descriptor.udf`):
            ``"auto"`` (default: a k-d tree on a CPU, the fused Triton kernel on a GPU where
            Triton is installed, else batched torch), ``"kdtree"``, ``"pykdtree"``,
            ``"torch"`` or ``"triton"``. The backends agree to 1e-5. :attr:`engine` is the
            basis placed on the device with it.

    Raises:
        ArtifactError: the bundle's pipeline is not one this predictor implements.
    """

    def __init__(
        self,
        bundle: ModelBundle,
        device: str | torch.device = "cpu",
        *,
        chunk_pairs: int = DEFAULT_CHUNK_PAIRS,
        precision: str = DEFAULT_PRECISION,
        embed_precision: str = DEFAULT_PRECISION,
        descriptor_lattice: str = AUTO_LATTICE,
        head: str | SmallHead = AUTO_HEAD,
        fusion: str | FusionCalibration = DEFAULT_FUSION,
        udf_backend: str = "auto",
    ) -> None:
        pipeline = bundle.pipeline
        check_pipeline(bundle.name, pipeline)
        if isinstance(chunk_pairs, bool) or int(chunk_pairs) < 1:
            raise InputError(f"chunk_pairs must be a positive integer, got {chunk_pairs!r}")
        self.bundle = bundle
        self.device = resolve_device(device)
        self.chunk_pairs = int(chunk_pairs)
        self.network = bundle.network.eval()
        self.precision = resolve_precision(precision, self.device)
        self.descriptor_lattice = bundle.basis.resolve_lattice(descriptor_lattice)
        self.engine = bundle.basis.engine(self.device, udf_backend, self.descriptor_lattice)
        if embed_precision not in EMBED_PRECISIONS:
            raise InputError(
                f"embed_precision must be one of {EMBED_PRECISIONS}, got {embed_precision!r}"
            )
        embed_precision = resolve_precision(embed_precision, self.device)
        self.embed_precision = embed_precision
        self.folded = FoldedGeodesicNet(
            self.network, self.device, precision=self.precision, embed_precision=embed_precision
        )
        self.small_head_config: dict[str, Any] | None = None
        self._net: FoldedGeodesicNet | FoldedSmallHead = self.folded
        self._table_key = "features"
        if isinstance(head, SmallHead):
            student = head
        elif resolve_head(bundle.path, head) == "small":
            from litege_core.learned.small_head import load_small_head

            student, self.small_head_config = load_small_head(bundle, self.device)
        else:
            student = None
        self.head = "full" if student is None else "small"
        if student is not None:
            self._net = FoldedSmallHead(student.eval(), self.folded, precision=self.precision)
            self._table_key = f"features.small.{_fingerprint(student)}"
        if embed_precision != DEFAULT_PRECISION:  # tables of another arithmetic
            self._table_key += f".{embed_precision}"
        self.fusion = self._fusion_of(fusion)
        self._shape_mlp = FoldedShapeMlp(self.network, self.device)
        self.target_scale = float(pipeline.target_scale)
        self.residual = bool(pipeline.residual)
        self.n_mesh_samples = int(pipeline.n_mesh_samples)
        self._ood = residual_statistics(bundle.name, bundle.manifest)
        if self.fusion is not None and self._ood is None:
            raise ArtifactError(
                f"bundle {bundle.name!r} has no residual statistics: graph fusion needs its "
                "OOD z-score"
            )
        self._veto = self
        if self.fusion is not None and self.fusion.veto_head != self.head:
            self._veto = Predictor(
                bundle,
                device,
                chunk_pairs=chunk_pairs,
                precision=precision,
                embed_precision=embed_precision,
                descriptor_lattice=descriptor_lattice,
                head=self.fusion.veto_head,
                fusion="none",
                udf_backend=udf_backend,
            )

    def _fusion_of(self, fusion: str | FusionCalibration) -> FusionCalibration | None:
        bundle = self.bundle
        if isinstance(fusion, FusionCalibration):
            if fusion.bundle_hash != bundle.content_hash:
                raise InputError(f"this fusion calibration is not for bundle {bundle.name!r}")
            return fusion
        return resolve_fusion(fusion, bundle.path, bundle.content_hash, bundle.name)

    def __repr__(self) -> str:
        head = "" if self.head == "full" else f", head={self.head!r}"
        lattice = self.descriptor_lattice
        lattice = "" if lattice == "full" else f", descriptor_lattice={lattice!r}"
        fusion = "" if self.fusion is None else ", fusion='graph'"
        embed = self.embed_precision
        embed = "" if embed == DEFAULT_PRECISION else f", embed_precision={embed!r}"
        device = str(self.device)
        return (
            f"Predictor(bundle={self.bundle.name!r}, device={device!r}{head}{lattice}{fusion}"
            f"{embed})"
        )

    # ----------------------------------------------------------------- registration

    def register(self, shape: Shape, *, seed: int = 0) -> ShapeState:
        """Canonicalize, describe and embed ``shape`` once.

        Args:
            shape: a validated mesh or point cloud in the user's frame.
            seed: seed of the surface samples the descriptor is computed from (meshes); the
                same shape and seed always give the same state.
        """
        return self.register_many([shape], seed=seed)[0]

    def register_many(self, shapes: Sequence[Shape], *, seed: int = 0) -> list[ShapeState]:
        """:meth:`register` for several shapes, batched: one UDF-PCA call and one shape-MLP
        call (point features come later, when a query needs them). Each shape gets the same
        result as :meth:`register` with the same seed."""
        shapes = list(shapes)
        if not shapes:
            return []
        for i, shape in enumerate(shapes):
            if not isinstance(shape, Shape):
                raise InputError(f"shapes[{i}] is a {type(shape).__name__}, not a Shape")
        samples = [shape_samples(s, self.n_mesh_samples, seed) for s in shapes]
        canonical = canonicalize_bbox_many(samples, self.device)  # frames on the device
        transforms = canonical.transforms
        described = self.engine.describe_with_residual(canonical.clouds)
        codes = described.descriptors.detach().to(torch.float32)  # (B, k), on the device
        host = torch.cat([codes, described.residual.detach()[:, None]], 1).cpu().numpy()
        descriptors, residuals = host[:, :-1], host[:, -1].astype(np.float64)  # one transfer
        records = [
            ShapeRecord(
                shape_id=shape.content_hash,
                bundle_hash=self.bundle.content_hash,
                transform=transforms[b],
                descriptor=frozen(descriptors[b]),
                residual=float(residuals[b]),
                seed=int(seed),
            )
            for b, shape in enumerate(shapes)
        ]
        return self._states(shapes, records, codes)

    def register_turned(self, shape: Shape, turns: ArrayLike, *, seed: int = 0) -> list[ShapeState]:
        """One state of ``shape`` per canonical frame ``turns[i] @ R_pca``: the PCA frame
        turned after canonicalization by each of ``turns`` ``(C, 3, 3)`` (proper rotations),
        each described in its own frame (frame probes, test-time augmentation, distillation
        views in the frames training turned). The identity gives :meth:`register`'s state."""
        points = shape_samples(shape, self.n_mesh_samples, seed)
        choices = turned_frames(points, self.engine, turns)
        records = [self.frame_record(shape, choice, seed=seed) for choice in choices]
        return self.restore_many([shape] * len(records), records)

    def frame_record(self, shape: Shape, choice: FrameChoice, *, seed: int = 0) -> ShapeRecord:
        """The :class:`ShapeRecord` of ``shape`` in the frame of a
        :class:`~litege_core.learned.frame.FrameChoice` (its transform, descriptor and
        residual), for :meth:`restore`."""
        return ShapeRecord(
            shape_id=shape.content_hash,
            bundle_hash=self.bundle.content_hash,
            transform=choice.transform,
            descriptor=frozen(np.asarray(choice.descriptor, dtype=np.float32)),
            residual=choice.residual,
            seed=int(seed),
        )

    def restore(self, shape: Shape, record: ShapeRecord) -> ShapeState:
        """Rebuild a state from its :class:`ShapeRecord` without recomputing the descriptor."""
        return self.restore_many([shape], [record])[0]

    def restore_many(
        self, shapes: Sequence[Shape], records: Sequence[ShapeRecord]
    ) -> list[ShapeState]:
        """:meth:`restore` for several shapes at once (the embedding half of registration).

        The result equals :meth:`register_many` with the records' seed: registration is this
        method applied to freshly computed records. This is what a cache stores: the record is
        a few hundred bytes; restoring it costs one shape-MLP call.

        Raises:
            InputError: a record belongs to another shape or another bundle.
        """
        shapes, records = list(shapes), list(records)
        if len(shapes) != len(records):
            raise InputError(f"got {len(shapes)} shapes and {len(records)} records")
        if not shapes:
            return []
        k = self.bundle.basis.n_components
        for shape, record in zip(shapes, records, strict=True):
            if not isinstance(shape, Shape) or not isinstance(record, ShapeRecord):
                raise InputError("restore_many takes Shape objects and ShapeRecord objects")
            if record.shape_id != shape.content_hash:
                raise InputError(
                    f"record of shape {record.shape_id[:12]}… does not belong to shape "
                    f"{shape.content_hash[:12]}…"
                )
            if record.bundle_hash != self.bundle.content_hash:
                raise InputError(
                    "this shape record was computed with another model bundle; register it again"
                )
            if record.descriptor.shape != (k,):
                raise ArrayShapeError(
                    f"record descriptor has shape {record.descriptor.shape}, bundle expects ({k},)"
                )
        descriptors = torch.from_numpy(np.stack([r.descriptor for r in records])).to(
            self.device, torch.float32
        )
        return self._states(shapes, records, descriptors)

    def _states(
        self, shapes: list[Shape], records: list[ShapeRecord], descriptors: torch.Tensor
    ) -> list[ShapeState]:
        """The states of checked ``records`` whose ``(B, k)`` descriptors are on the device
        (registration passes the ones it computed: no round trip through the host)."""
        with torch.no_grad():
            shape_emb = self._shape_mlp(descriptors)  # (B, n)
            rows = torch.cat([shape_emb, self.folded.shape_bias(shape_emb)], dim=1)  # (B, 2n)
        # Each state's embedding and bias are views of its batch's rows: no kernel per shape
        # (a copy per state cost 2B device kernels, half the launches of 64 clouds × 1 query
        # on a GPU). A state keeps its batch's B × 2n floats alive and ShapeState.nbytes
        # charges it for them (a few hundred kB at most; its feature table is N × F).
        n = shape_emb.shape[1]
        return [
            ShapeState(
                shape_id=record.shape_id,
                kind=shape.kind,
                n_points=shape.n_points,
                transform=record.transform,
                descriptor=record.descriptor,
                residual=record.residual,
                ood_score=self._ood_score(record.residual),
                ood_calibrated=self._ood is not None,
                bundle_hash=record.bundle_hash,
                vertices=shape.vertices,
                faces=shape.faces,
                device=self.device,
                shape_embedding=embedding,
                shape_bias=bias,
                record=record,
            )
            for shape, record, embedding, bias in zip(
                shapes, records, rows[:, :n].unbind(), rows[:, n:].unbind(), strict=True
            )
        ]

    def point_table(self, state: ShapeState) -> torch.Tensor:
        """``(N, F)`` head features of every point of ``state`` (``F = 2n`` for the full head,
        ``m`` for the small one): built on first use (in chunks of :data:`DEFAULT_EMBED_ROWS`
        points) and kept with the state, under a key of this predictor's head (a full-head
        table is never read by a small-head predictor, nor the other way round)."""
        table = self._table(state)
        if table is None:
            with torch.no_grad():
                table = self._features_of(state.canonical_vertices, state.shape_bias)
            state._lazy[self._table_key] = table
        return table

    def _table(self, state: ShapeState) -> torch.Tensor | None:
        """This head's feature table of ``state`` if a query built it."""
        return state._lazy.get(self._table_key)

    def _features_of(self, positions: torch.Tensor, bias: torch.Tensor) -> torch.Tensor:
        """``(R, 3)`` canonical positions → ``(R, F)`` head features, chunked (no grad).

        A single row is computed as two: one-row products take a matrix-vector kernel whose
        rounding differs from the matrix kernel's, and a point must get the same features
        whether it is embedded alone or as a row of the whole table (same query, same answer).
        """
        if positions.shape[0] == 1:
            return self._features_of(positions.expand(2, 3), bias)[:1]
        return torch.cat(
            [
                self._net.point_features(positions[s : s + DEFAULT_EMBED_ROWS], bias)
                for s in range(0, max(1, positions.shape[0]), DEFAULT_EMBED_ROWS)
            ]
        )

    def _ood_score(self, residual: float) -> float:
        if self._ood is None:
            return residual
        mean, std = self._ood
        return (residual - mean) / std

    def ood_score(self, state: ShapeState) -> float:
        """The state's out-of-distribution score (see the module docstring)."""
        self.check_state(state)
        return state.ood_score

    # ----------------------------------------------------------------- queries

    def check_state(self, state: ShapeState) -> None:
        """Raise :class:`InputError` unless ``state`` was registered with this bundle."""
        if not isinstance(state, ShapeState):
            raise InputError(f"expected a ShapeState, got {type(state).__name__}")
        if state.bundle_hash != self.bundle.content_hash:
            raise InputError(
                "this shape state was computed with another model bundle; register it again"
            )

    def resolve(self, state: ShapeState, query: QueryLike, what: str = "source") -> ResolvedPoints:
        """Resolve sources or targets on ``state`` (validation at the boundary).

        Args:
            state: a registered shape.
            query: anything :func:`litege_core.query.parse_query` takes: ``(Q,)`` integer
                indices, ``(Q, 3)`` xyz points in the user's frame (put on the surface by
                :func:`litege_core.projection.snap`), or ``None`` / ``"all"``.
            what: word used in error messages.

        Raises:
            IndexOutOfRangeError: an index outside ``[0, N)``.
            ArrayShapeError: non-integer indices, xyz not ``(Q, 3)``, empty query.
            NonFiniteError: NaN, infinite or absurdly large xyz.
        """
        return self._resolve_many([state], [query], what)[0]

    @staticmethod
    def _locate(
        state: ShapeState, query: QueryLike, what: str
    ) -> tuple[NDArray | None, NDArray | None]:
        """Where ``query`` lies on ``state``: ``(indices, None)`` for vertices (``None``
        indices: every point; xyz points that land on a vertex count as it), or ``(None,
        points)``, the canonical ``(Q, 3)`` projections of xyz points onto the surface."""
        parsed = parse_query(query, what).check(state.n_points, what)
        if parsed.points is None:
            return parsed.indices, None
        snapped = snap(state.projector, state.transform.apply(parsed.points))
        if snapped.indices is None:
            return None, np.asarray(snapped.points, np.float64)
        return snapped.indices, None

    def _resolve_many(
        self,
        states: Sequence[ShapeState],
        queries: Sequence[QueryLike],
        what: str | Sequence[str],
    ) -> list[ResolvedPoints]:
        """:meth:`resolve` of ``(state, query)`` pairs; the index queries that embed their
        points on the fly (:meth:`_embeds_on_the_fly`, xyz points snapped to vertices included)
        share one point-MLP call, each row with its own shape's bias, instead of one call per
        shape (64 shapes × 1 query, sources and targets: one call). ``what`` names the queries
        in error messages: one word for all, or one per query."""
        whats = [what] * len(states) if isinstance(what, str) else list(what)
        resolved: list[ResolvedPoints | None] = []
        pending: list[tuple[int, ShapeState, NDArray]] = []
        for b, (state, query, what) in enumerate(zip(states, queries, whats, strict=True)):
            indices, points = self._locate(state, query, what)
            if points is not None:
                resolved.append(self.embed_canonical(state, points))
                continue
            if indices is None:  # every point
                resolved.append(
                    ResolvedPoints(
                        self.point_table(state),
                        state.canonical_vertices,
                        state.canonical_points,
                        state.vertices,
                        np.arange(state.n_points),
                    )
                )
            elif self._embeds_on_the_fly(state, indices):
                pending.append((b, state, indices))
                resolved.append(None)
            else:
                resolved.append(self._from_table(state, indices))
        if pending:
            counts = [indices.shape[0] for _, _, indices in pending]
            canonical = [state.canonical_rows(indices) for _, state, indices in pending]
            positions = torch.from_numpy(np.concatenate(canonical)).to(self.device, torch.float32)
            if len(pending) == 1:
                rows = pending[0][1].shape_bias  # (n,), broadcast over the rows
            else:  # each row its shape's bias
                biases = torch.stack([state.shape_bias for _, state, _ in pending])
                if min(counts) == max(counts):  # e.g. one query per shape: no index upload
                    rows = biases.repeat_interleave(counts[0], dim=0)
                else:  # the row → shape index built on the host
                    shape_of_row = np.repeat(np.arange(len(pending)), counts)
                    rows = biases.index_select(0, torch.from_numpy(shape_of_row).to(self.device))
            with torch.no_grad():
                features = self._features_of(positions, rows).split(counts)
            for (b, state, indices), feature, where, points in zip(
                pending, features, positions.split(counts), canonical, strict=True
            ):
                resolved[b] = ResolvedPoints(
                    feature, where, points, state.vertices[indices], indices
                )
        return [r for r in resolved if r is not None]

    def _embeds_on_the_fly(self, state: ShapeState, indices: NDArray) -> bool:
        """Whether an index query embeds its points itself: no feature table yet, and too few
        points (at most :data:`TABLE_FRACTION` of the shape) to build one."""
        return self._table(state) is None and indices.shape[0] <= TABLE_FRACTION * state.n_points

    def _from_table(self, state: ShapeState, indices: NDArray) -> ResolvedPoints:
        """Index query rows of the state's feature table (built now if missing)."""
        index_t = torch.from_numpy(indices).to(self.device)
        return ResolvedPoints(
            self.point_table(state).index_select(0, index_t),
            state.canonical_vertices.index_select(0, index_t),
            state.canonical_rows(indices),
            state.vertices[indices],
            indices,
        )

    def point_features(self, state: ShapeState, positions: torch.Tensor) -> torch.Tensor:
        """``(R, 3)`` canonical positions on ``state`` → ``(R, F)`` head features
        (differentiable in ``positions``: the path tracer's gradient)."""
        return self._net.point_features(positions, state.shape_bias)

    def embed_canonical(self, state: ShapeState, canonical: NDArray) -> ResolvedPoints:
        """Embed arbitrary canonical points ``(Q, 3)`` (already on the surface) on the fly."""
        positions = torch.from_numpy(np.ascontiguousarray(canonical)).to(self.device, torch.float32)
        with torch.no_grad():
            features = self._features_of(positions, state.shape_bias)
        canonical = np.asarray(canonical, np.float64)
        return ResolvedPoints(
            features, positions, canonical, state.transform.invert(canonical), None
        )

    def predict_canonical(
        self,
        src_features: torch.Tensor,
        dst_features: torch.Tensor,
        src_positions: torch.Tensor,
        dst_positions: torch.Tensor,
    ) -> torch.Tensor:
        """Matched pairs → predicted geodesics in canonical units (differentiable).

        Args:
            src_features, dst_features: ``(R, F)`` head features (this predictor's head).
            src_positions, dst_positions: ``(R, 3)`` canonical coordinates.

        Returns:
            ``(R,)`` ``|head|/1.42 (+ ‖s − d‖ for residual bundles)``; no diagonal rule.
        """
        out = self._net.head(src_features - dst_features) / self.target_scale
        if self.residual:
            out = out + torch.linalg.vector_norm(src_positions - dst_positions, dim=-1)
        return out

    def distances(
        self, state: ShapeState, sources: QueryLike, targets: QueryLike = None
    ) -> NDArray:
        """Predicted geodesic distances ``(S, T)`` float32 in the user's units.

        Args:
            state: a registered shape.
            sources: ``(S,)`` indices or ``(S, 3)`` xyz points (user frame).
            targets: ``(T,)`` indices, ``(T, 3)`` xyz points, or ``None`` / ``"all"``
                (``T = N``: distance fields).

        Returns:
            ``(S, T)`` float32; ``[i, j]`` = G(source i, target j); exactly 0 where the two
            points coincide.
        """
        return self.distances_many([state], [sources], [targets])[0]

    def distance_field(self, state: ShapeState, source: int | ArrayLike) -> NDArray:
        """``(N,)`` float32 distances from one source (an index, or an xyz point ``(3,)``)
        to every vertex / point, in the user's units."""
        return self.distances(state, parse_query(source, "source", allow_all=False, single=True))[0]

    def distances_many(
        self,
        states: Sequence[ShapeState],
        sources_list: Sequence[QueryLike],
        targets_list: Sequence[QueryLike] | None = None,
    ) -> list[NDArray]:
        """Distances for many shapes in one batch (the service's micro-batcher).

        Pairs of all shapes are concatenated without padding; shapes whose pairs fit together
        in ``chunk_pairs`` share one head evaluation (so e.g. 64 shapes × 1 query run in one
        head call); a shape with at least :data:`DENSE_MIN_PAIRS` pairs (or ``chunk_pairs``)
        runs alone, by broadcasting in chunks (no gathered copies of its features).

        Args:
            states: ``B`` registered shapes (repeats allowed).
            sources_list: ``B`` source queries (see :meth:`distances`).
            targets_list: ``B`` target queries, or ``None`` for all targets of every shape.

        Returns:
            ``B`` float32 arrays ``(S_b, T_b)`` in each shape's user units.
        """
        states = list(states)
        sources_list = list(sources_list)
        targets_list = [None] * len(states) if targets_list is None else list(targets_list)
        if not (len(states) == len(sources_list) == len(targets_list)):
            raise InputError(
                f"got {len(states)} states, {len(sources_list)} source lists and "
                f"{len(targets_list)} target lists; they must have the same length"
            )
        for state in states:
            self.check_state(state)
        outputs: list[NDArray | None] = [None] * len(states)
        batched = []  # a mesh with a fusion is answered by its graph (the network where needed)
        for b, (state, sources, targets) in enumerate(
            zip(states, sources_list, targets_list, strict=True)
        ):
            if self.fusion is not None and state.faces is not None:
                outputs[b] = self._mesh_fused(state, sources, targets)
            else:
                batched.append(b)
        if batched:
            count = len(batched)
            resolved = self._resolve_many(  # one point-MLP call for the sources and the targets
                [states[b] for b in batched] * 2,
                [sources_list[b] for b in batched] + [targets_list[b] for b in batched],
                ["source"] * count + ["target"] * count,
            )
            blocks = list(zip(resolved[:count], resolved[count:], strict=True))
            answers = self.evaluate_blocks(blocks)
            for b, (src, dst), out in zip(batched, blocks, answers, strict=True):
                if self.fusion is not None:
                    out = self._fused(
                        states[b],
                        (src.indices, src.canonical),
                        (dst.indices, dst.canonical),
                        functools.partial(np.asarray, out),
                    )
                outputs[b] = out
        return [
            (np.asarray(out, dtype=np.float64) / state.transform.scale).astype(np.float32)
            for out, state in zip(outputs, states, strict=True)
        ]

    def agreement(self, state: ShapeState, n_sources: int = AGREEMENT_SOURCES) -> float:
        """How far the network is from the fusion's own graph on this shape: the mean
        ``|G_network − G_graph / b|`` over the rows of ``n_sources`` farthest points (from
        point 0; every point as target), divided by the graph's mean (unitless; pairs the graph
        cannot join are left out). A shape of the model's category scores ~0.03–0.05, one of
        another category ~0.06–0.12 (BENCHMARKS "routing-agreement"): the
        ``auto`` model choice weighs it (:func:`~litege_core.learned.routing.choose_model`).
        ``nan`` without a fusion calibration. The graph is built once and kept with
        ``state`` (the fused queries reuse it)."""
        self.check_state(state)
        if self.fusion is None:
            return math.nan

        def network_rows(sources: NDArray) -> NDArray:
            blocks = self._resolve_many([state, state], [sources, None], ["source", "target"])
            return self.evaluate_blocks([(blocks[0], blocks[1])])[0]

        return shape_agreement(
            network_rows,
            state.canonical_points,
            state.faces,
            self.fusion,
            state._lazy,
            self._edge_geodesics(state),
            self._veto._table_key,
            state.ood_score,
            n_sources,
        )

    def _edge_geodesics(self, state: ShapeState) -> EdgeGeodesics:
        """The fusion veto's predicted geodesics of point pairs of ``state`` (canonical)."""
        return lambda i, j: self._veto._pair_distances(state, i, j)

    def _fused(
        self,
        state: ShapeState,
        src: tuple[NDArray | None, NDArray],
        dst: tuple[NDArray | None, NDArray],
        network: Callable[[], NDArray],
    ) -> NDArray:
        """The network's ``(S, T)`` (canonical units, computed by ``network`` where needed)
        blended with the shape's graph distances between ``(indices, canonical)`` queries."""
        assert self.fusion is not None
        return fused_distances(
            network,
            self.fusion,
            state.canonical_points,
            state.faces,
            src,
            dst,
            state.ood_score,
            state._lazy,
            self._edge_geodesics(state),
            self._veto._table_key,
        )

    def _mesh_fused(self, state: ShapeState, sources: QueryLike, targets: QueryLike) -> NDArray:
        """The fused ``(S, T)`` of a mesh (canonical units): its graph's rows, without
        embedding a point unless the graph cannot join a pair."""

        def graph_query(query: QueryLike, what: str) -> tuple[NDArray | None, NDArray]:
            indices, points = self._locate(state, query, what)
            if points is not None:
                return None, points
            if indices is None:
                return np.arange(state.n_points), state.canonical_points
            return indices, state.canonical_rows(indices)

        def network() -> NDArray:
            blocks = self._resolve_many([state, state], [sources, targets], ["source", "target"])
            return self.evaluate_blocks([(blocks[0], blocks[1])])[0]

        return self._fused(
            state, graph_query(sources, "source"), graph_query(targets, "target"), network
        )

    def _pair_distances(self, state: ShapeState, i: NDArray, j: NDArray) -> NDArray:
        """``(E,)`` float64 predicted geodesics between vertex pairs ``(i, j)`` (canonical).

        Uses this head's feature table of ``state`` if a query built it, else the features of
        the pairs' points only, kept with the state for the fusion's later veto rounds (a
        single pair's veto reads a few dozen points, not the whole cloud)."""
        if i.size == 0:
            return np.empty(0)
        table, ti, tj = self._table(state), i, j
        if table is None:
            table, rows = self._veto_features(state, np.concatenate([i, j]))
            ti, tj = rows[i], rows[j]
        out = np.empty(i.shape[0])
        points = state.canonical_vertices
        with torch.no_grad():
            for start in range(0, i.shape[0], self.chunk_pairs):
                a = torch.from_numpy(i[start : start + self.chunk_pairs]).to(self.device)
                b = torch.from_numpy(j[start : start + self.chunk_pairs]).to(self.device)
                ta = torch.from_numpy(ti[start : start + self.chunk_pairs]).to(self.device)
                tb = torch.from_numpy(tj[start : start + self.chunk_pairs]).to(self.device)
                # index_select: ~2.5x faster than advanced indexing on a CPU
                diff = table.index_select(0, ta).sub_(table.index_select(0, tb))
                head = self._net.head(diff, inplace=True)
                eu = torch.linalg.vector_norm(
                    points.index_select(0, a).sub_(points.index_select(0, b)), dim=-1
                )
                out[start : start + a.shape[0]] = self._finish(head, eu).cpu().numpy()
        return out

    def _veto_features(self, state: ShapeState, points: NDArray) -> tuple[torch.Tensor, NDArray]:
        """Head features of the points the fusion veto has reached
        (:func:`~litege_core.learned.veto_graph.grown_features`), ``points`` among them; kept
        with ``state`` under ``fusion.veto.<head>``, growing as veto rounds and later queries
        reach new points (the whole cloud only if they reach all of it)."""
        key = f"fusion.veto.{self._table_key}"

        def compute(missing: NDArray) -> torch.Tensor:
            positions = state.canonical_vertices[torch.from_numpy(missing).to(self.device)]
            with torch.no_grad():
                return self._features_of(positions, state.shape_bias)

        kept = state._lazy[key] = grown_features(
            state._lazy.get(key), state.n_points, points, compute, torch.cat
        )
        return kept

    def _finish(self, head: torch.Tensor, euclidean: torch.Tensor) -> torch.Tensor:
        out = head / self.target_scale
        if self.residual:
            out = out + euclidean
        return out.masked_fill_(euclidean == 0, 0.0)

    def evaluate_blocks(self, blocks: list[tuple[ResolvedPoints, ResolvedPoints]]) -> list[NDArray]:
        """The ``(S_b, T_b)`` distances (canonical units, before fusion) of each resolved
        ``(sources, targets)`` block: a large block alone by broadcasting, small ones grouped
        into flat head calls of at most ``chunk_pairs`` pairs."""
        outputs: list[NDArray | None] = [None] * len(blocks)
        with torch.no_grad():
            group: list[int] = []
            group_pairs = 0
            for b, (src, dst) in enumerate(blocks):
                pairs = src.count * dst.count
                if pairs >= min(self.chunk_pairs, DENSE_MIN_PAIRS):
                    outputs[b] = self._dense_block(src, dst)
                    continue
                if group and group_pairs + pairs > self.chunk_pairs:
                    self._flat_group([blocks[i] for i in group], group, outputs)
                    group, group_pairs = [], 0
                group.append(b)
                group_pairs += pairs
            if group:
                self._flat_group([blocks[i] for i in group], group, outputs)
        return cast("list[NDArray]", outputs)  # every block was filled

    def _dense_block(self, src: ResolvedPoints, dst: ResolvedPoints) -> NDArray:
        """All pairs of one shape by broadcasting, in chunks of ``chunk_pairs`` pairs."""
        n_src, n_dst = src.count, dst.count
        out = torch.empty((n_src, n_dst), device=self.device)
        col_step = min(n_dst, self.chunk_pairs)
        row_step = max(1, self.chunk_pairs // col_step)
        for j0 in range(0, n_dst, col_step):
            f_dst = dst.features[j0 : j0 + col_step]
            x_dst = dst.positions[j0 : j0 + col_step]
            for i0 in range(0, n_src, row_step):
                f_src = src.features[i0 : i0 + row_step]
                x_src = src.positions[i0 : i0 + row_step]
                head = self._net.pair_head(f_src, f_dst)  # cache-sized tiles inside
                eu = torch.linalg.vector_norm(x_src[:, None, :] - x_dst[None, :, :], dim=-1)
                out[i0 : i0 + row_step, j0 : j0 + col_step] = self._finish(head, eu)
        return out.cpu().numpy()

    def _flat_group(
        self,
        group: list[tuple[ResolvedPoints, ResolvedPoints]],
        positions: list[int],
        outputs: list[NDArray | None],
    ) -> None:
        """Several small blocks in one head evaluation (pairs concatenated, no padding)."""
        sizes = [(src.count, dst.count) for src, dst in group]
        f_src = torch.cat([src.features for src, _ in group])
        f_dst = torch.cat([dst.features for _, dst in group])
        x_src = torch.cat([src.positions for src, _ in group])
        x_dst = torch.cat([dst.positions for _, dst in group])
        if any(size != (1, 1) for size in sizes):  # pair → row of the sources / targets
            src_rows, dst_rows = [], []
            src_off = dst_off = 0
            for s, t in sizes:
                src_rows.append(np.repeat(np.arange(src_off, src_off + s), t))
                dst_rows.append(np.tile(np.arange(dst_off, dst_off + t), s))
                src_off += s
                dst_off += t
            i = torch.from_numpy(np.concatenate(src_rows)).to(self.device)
            j = torch.from_numpy(np.concatenate(dst_rows)).to(self.device)
            f_src, f_dst, x_src, x_dst = f_src[i], f_dst[j], x_src[i], x_dst[j]
        # else one pair per shape: the rows are the pairs (no index upload, no gather)
        head = self._net.head(f_src - f_dst, inplace=True)
        eu = torch.linalg.vector_norm(x_src - x_dst, dim=-1)
        flat = self._finish(head, eu).cpu().numpy()
        start = 0
        for b, (s, t) in zip(positions, sizes, strict=True):
            outputs[b] = flat[start : start + s * t].reshape(s, t)
            start += s * t

    # ----------------------------------------------------------------- paths

    def path(
        self, state: ShapeState, source: int | ArrayLike, target: int | ArrayLike, **options: Any
    ) -> GeodesicPath:
        """Geodesic path from ``source`` to ``target`` (see :func:`.trace_path`)."""
        return trace_path(self, state, source, target, **options)

    def paths(
        self, state: ShapeState, sources: ArrayLike, targets: ArrayLike, **options: Any
    ) -> list[GeodesicPath]:
        """Several paths at once; see :func:`~litege_core.learned.trace_paths`."""
        return trace_paths(self, state, sources, targets, **options)

    def surface_router(self, state: ShapeState) -> SurfaceRouter:
        """The router of ``state``'s on-surface paths (kept with the state): with a fusion, a
        point cloud routes on the fusion's fully vetoed k-NN graph, the graph its distances
        read (vetoed lazily, on the routes' edges only:
        :func:`~litege_core.learned.fusion.route_trees`); a mesh, or a
        predictor without a fusion, on the router's own graphs."""
        fusion = self.fusion
        if fusion is None or state.faces is not None:
            return default_router(state)
        veto_key, z_score = self._veto._table_key, state.ood_score
        graph_key = cloud_graph_key(fusion, veto_key, state.n_points, fusion.vetoes(z_score))
        key = f"surface_router.{graph_key}"
        router = state._lazy.get(key)
        if router is None:
            graph = shape_graph(
                state.canonical_points, None, fusion, state._lazy, veto_key, z_score
            ).graph
            if isinstance(graph, LazyVetoGraph):
                edge_geodesics = self._edge_geodesics(state)
                trees = functools.partial(route_trees, graph, edge_geodesics=edge_geodesics)
                router = SurfaceRouter(state.vertices, None, graph.graph, trees)
            else:  # no veto at this OOD score: Dijkstra on the graph as it is
                router = SurfaceRouter(state.vertices, None, graph)
            router = state._lazy.setdefault(key, router)
        return router


def _fingerprint(head: SmallHead) -> str:
    """A short digest of a small head's weights (keys its feature tables on a state)."""
    digest = hashlib.sha256()
    for name, tensor in sorted(head.state_dict().items()):
        digest.update(name.encode())
        digest.update(tensor.detach().to("cpu", torch.float32).contiguous().numpy().tobytes())
    return digest.hexdigest()[:16]


__all__ = [
    "DEFAULT_CHUNK_PAIRS",
    "HEADS",
    "OOD_Z_THRESHOLD",
    "Predictor",
    "QueryLike",
    "ResolvedPoints",
    "ShapeRecord",
    "ShapeState",
]
