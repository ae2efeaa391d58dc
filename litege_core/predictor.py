"""The object the service holds: register a shape once, then answer geodesic queries fast.

::

    from litege_core.bundle import load_shipped
    from litege_core.predictor import Predictor

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
the shape embedding, the point embedding ``e_p`` of every vertex / cloud point, and the point
embeddings already pushed through the head's first linear layer (``head_features``, see
below), all as tensors on the predictor's device. A query then runs only the rest of the head.

**Inference-time folding.** At construction the predictor folds the network, in eval mode and
in float64, into plain affine maps: each BatchNorm into the preceding linear layer, the
coordinate z-score into the first layer, the shape half of the fusion layer into a per-shape
bias, and the head's first linear layer (``W (e_s − e_d) = W e_s − W e_d``) into per-point
features ``f_p = a ⊙ (W e_p)``. A pair then costs one subtraction, a ReLU, one ``2n × 2n``
matrix product and a dot product; results equal ``GeodesicNet.forward`` to float32 rounding
(tested to 1e-5). The path tracer differentiates the same folded maps with autograd with
respect to *canonical* coordinates (the z-score is inside), so the gradient is the true one
(spec §6 chain-rule bug not repeated).

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

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
import torch
from numpy.typing import ArrayLike, NDArray
from torch import nn

from litege_core.arrays import frozen
from litege_core.bundle import ModelBundle
from litege_core.canonical import BBOX_SQRT_AREA, Transform, canonicalize_bbox
from litege_core.describe import shape_samples
from litege_core.errors import ArrayShapeError, ArtifactError, InputError
from litege_core.geodesics.base import check_indices
from litege_core.nets import GeodesicNet
from litege_core.projection import CloudProjector, MeshProjector, as_query_points
from litege_core.shape import Shape, ShapeKind

if TYPE_CHECKING:
    from litege_core.paths import GeodesicPath

OOD_Z_THRESHOLD = 3.0
"""``ood_score`` above which a shape counts as out of distribution (calibrated bundles)."""

DEFAULT_CHUNK_PAIRS = 16_384
"""(source, target) pairs per head evaluation; bounds the temporary memory of a query."""

DEFAULT_EMBED_ROWS = 32_768
"""Points per point-embedding evaluation (registration and on-the-fly xyz queries)."""

Query = ArrayLike | None
"""Sources or targets: ``(S,)`` integer indices, ``(S, 3)`` xyz points in the user's frame,
or (targets only) ``None`` / ``"all"`` for every vertex or point."""


# --------------------------------------------------------------------------- folded network


def _bn_affine(bn: nn.BatchNorm1d) -> tuple[torch.Tensor, torch.Tensor]:
    """Eval-mode BatchNorm as ``y = a ⊙ x + c`` (float64)."""
    if bn.running_mean is None or bn.running_var is None:
        raise ArtifactError("the network's BatchNorm layers have no running statistics")
    scale = 1.0 / torch.sqrt(bn.running_var.double() + bn.eps)
    weight = bn.weight.double() if bn.weight is not None else torch.ones_like(scale)
    bias = bn.bias.double() if bn.bias is not None else torch.zeros_like(scale)
    a = weight * scale
    return a, bias - bn.running_mean.double() * a


def _bn_blocks(seq: nn.Sequential) -> list[tuple[torch.Tensor, torch.Tensor]]:
    """``[(A, b)]`` per BN-block of ``seq`` (Linear without bias, BatchNorm1d, ReLU), folded."""
    modules = list(seq)
    if len(modules) % 3:
        raise ArtifactError("unexpected layout of a BN-block MLP")
    blocks = []
    for i in range(0, len(modules), 3):
        linear, bn = modules[i], modules[i + 1]
        if not isinstance(linear, nn.Linear) or not isinstance(bn, nn.BatchNorm1d):
            raise ArtifactError("unexpected layout of a BN-block MLP")
        a, c = _bn_affine(bn)
        weight = linear.weight.double() * a[:, None]
        bias = c if linear.bias is None else c + a * linear.bias.double()
        blocks.append((weight, bias))
    return blocks


class FoldedGeodesicNet:
    """A :class:`GeodesicNet` in eval mode folded into affine maps (see the module docstring).

    Args:
        net: the network; its BatchNorm running statistics are used (eval semantics).
        device: where the folded tensors live.
        dtype: their dtype (float32).

    Attributes:
        width: ``n``.
        output: ``"abs"`` or ``"softplus"``.
    """

    def __init__(
        self,
        net: GeodesicNet,
        device: torch.device | str = "cpu",
        dtype: torch.dtype = torch.float32,
    ) -> None:
        n = net.width
        self.width = n
        self.output = net.output
        self.device = torch.device(device)
        with torch.no_grad():
            mean = net.coord_mean.double()
            std = net.coord_std.double()
            (w1, b1), (w2, b2) = _bn_blocks(net.mlp_coord)
            # z-score inside layer 1: W (p − m)/s = (W/s) p − W (m/s)
            c1_w = w1 / std[None, :]
            c1_b = b1 - w1 @ (mean / std)
            down_w = net.project_down_pcacoord.weight.double()  # (n, 2n): [shape | coord]
            down_b = net.project_down_pcacoord.bias.double()
            (w3, b3), (w4, b4) = _bn_blocks(net.mlp_pcacoord)
            # the fusion layer has no activation: fold its coordinate half into w3 and its
            # shape half (+ its bias) into a per-shape bias of the same layer.
            p1_w = w3 @ down_w[:, n:]
            self._shape_w = w3 @ down_w[:, :n]
            self._shape_b = b3 + w3 @ down_b
            e_w = net.project_embed.weight.double()
            e_b = net.project_embed.bias.double()
            (h1_w, h1_b), (h2_w, h2_b) = _bn_blocks(net.final_layers)
            f_w = net.final_linear.weight.double()[0]
            f_b = net.final_linear.bias.double()[0]

            def put(t: torch.Tensor) -> torch.Tensor:
                return t.to(device=self.device, dtype=dtype).contiguous()

            self.c1_wt, self.c1_b = put(c1_w.T), put(c1_b)
            self.c2_wt, self.c2_b = put(w2.T), put(b2)
            self.p1_wt = put(p1_w.T)
            self.p2_wt, self.p2_b = put(w4.T), put(b4)
            self.e_wt, self.e_b = put(e_w.T), put(e_b)
            self.h1_wt, self.h1_b = put(h1_w.T), put(h1_b)  # (n, 2n), (2n,)
            self.h2_wt, self.h2_b = put(h2_w.T), put(h2_b)  # (2n, 2n), (2n,)
            self.f_w, self.f_b = put(f_w[:, None]), put(f_b)  # (2n, 1), ()
            self._shape_w = put(self._shape_w)
            self._shape_b = put(self._shape_b)

    def shape_bias(self, shape_embedding: torch.Tensor) -> torch.Tensor:
        """``(..., n)`` shape embeddings → ``(..., n)`` per-shape bias of the point MLP."""
        return shape_embedding @ self._shape_w.T + self._shape_b

    def embed(self, points: torch.Tensor, shape_bias: torch.Tensor) -> torch.Tensor:
        """Point embeddings ``e_p``.

        Args:
            points: ``(R, 3)`` canonical coordinates.
            shape_bias: ``(n,)`` or ``(R, n)`` from :meth:`shape_bias`.

        Returns:
            ``(R, n)``; differentiable in ``points``.
        """
        h = torch.addmm(self.c1_b, points, self.c1_wt).relu()
        h = torch.addmm(self.c2_b, h, self.c2_wt).relu()
        h = (h @ self.p1_wt + shape_bias).relu()
        h = torch.addmm(self.p2_b, h, self.p2_wt).relu()
        return torch.addmm(self.e_b, h, self.e_wt)

    def features(self, embeddings: torch.Tensor) -> torch.Tensor:
        """``(R, n)`` point embeddings → ``(R, 2n)`` head features ``f_p = a ⊙ (W₁ e_p)``."""
        return embeddings @ self.h1_wt

    def head(self, diff: torch.Tensor, *, inplace: bool = False) -> torch.Tensor:
        """``(R, 2n)`` feature differences ``f_s − f_d`` → ``(R,)`` network outputs (≥ 0).

        ``inplace=True`` reuses ``diff`` as scratch memory (not with autograd).
        """
        h = diff.add_(self.h1_b).relu_() if inplace else (diff + self.h1_b).relu()
        h = torch.addmm(self.h2_b, h, self.h2_wt)
        h = h.relu_() if inplace else h.relu()
        out = (h @ self.f_w).squeeze(-1) + self.f_b
        return out.abs() if self.output == "abs" else nn.functional.softplus(out)


# --------------------------------------------------------------------------- shape state


@dataclass(frozen=True, eq=False)
class ShapeRecord:
    """The small, serializable half of a registration: everything :meth:`Predictor.restore`
    needs besides the shape's own arrays to rebuild its :class:`ShapeState` without
    recomputing the UDF-PCA descriptor.

    Attributes:
        shape_id: content hash of the shape it describes.
        bundle_hash: content hash of the bundle that computed it.
        transform: user frame → canonical frame.
        descriptor: ``(k,)`` float32 UDF-PCA descriptor (read-only).
        residual: PCA reconstruction residual (canonical units).
        seed: seed of the surface samples the descriptor came from.
    """

    shape_id: str
    bundle_hash: str
    transform: Transform
    descriptor: NDArray
    residual: float
    seed: int

    def to_arrays(self) -> dict[str, NDArray]:
        """Plain numpy arrays (for safetensors or any other pickle-free format)."""
        return {
            "shape_id": np.frombuffer(self.shape_id.encode("ascii"), dtype=np.uint8).copy(),
            "bundle_hash": np.frombuffer(self.bundle_hash.encode("ascii"), dtype=np.uint8).copy(),
            "rotation": np.asarray(self.transform.rotation, dtype=np.float64),
            "center": np.asarray(self.transform.center, dtype=np.float64),
            "scale": np.array([self.transform.scale], dtype=np.float64),
            "descriptor": np.asarray(self.descriptor, dtype=np.float32),
            "residual": np.array([self.residual], dtype=np.float64),
            "seed": np.array([self.seed], dtype=np.int64),
        }

    @classmethod
    def from_arrays(cls, arrays: dict[str, NDArray]) -> ShapeRecord:
        """Inverse of :meth:`to_arrays`.

        Raises:
            ArtifactError: keys are missing or arrays have the wrong shape or values.
        """
        try:
            descriptor = np.asarray(arrays["descriptor"], dtype=np.float32)
            record = cls(
                shape_id=bytes(np.asarray(arrays["shape_id"], dtype=np.uint8)).decode("ascii"),
                bundle_hash=bytes(np.asarray(arrays["bundle_hash"], dtype=np.uint8)).decode(
                    "ascii"
                ),
                transform=Transform(
                    arrays["rotation"], arrays["center"], float(arrays["scale"].reshape(-1)[0])
                ),
                descriptor=frozen(descriptor),
                residual=float(arrays["residual"].reshape(-1)[0]),
                seed=int(arrays["seed"].reshape(-1)[0]),
            )
        except (KeyError, IndexError, ValueError, TypeError, UnicodeDecodeError) as exc:
            raise ArtifactError(f"malformed shape record: {exc}") from exc
        except InputError as exc:
            raise ArtifactError(f"malformed shape record: {exc}") from exc
        if descriptor.ndim != 1 or not np.all(np.isfinite(descriptor)):
            raise ArtifactError("malformed shape record: descriptor must be a finite vector")
        return record


@dataclass(frozen=True, eq=False)
class ShapeState:
    """Everything cached for one registered shape (build with :meth:`Predictor.register`).

    Attributes:
        shape_id: the shape's content hash (:attr:`Shape.content_hash`).
        kind: mesh or point cloud.
        n_points: ``N``, vertices of a mesh or points of a cloud.
        transform: user frame → canonical frame (distances: canonical = user × ``scale``).
        descriptor: ``(k,)`` float32 UDF-PCA descriptor (read-only).
        residual: PCA reconstruction residual of the UDF (canonical units).
        ood_score: z-score of ``residual`` against the training shapes (or the raw residual
            when the bundle has no calibration, see ``ood_calibrated``).
        ood_calibrated: whether the bundle provided training residual statistics.
        bundle_hash: content hash of the bundle the state was computed with.
        vertices: ``(N, 3)`` float64 vertices in the user's frame (read-only, the shape's own
            array).
        canonical_points: ``(N, 3)`` float64 canonical vertices (read-only numpy).
        faces: ``(F, 3)`` int64 triangles (read-only) for meshes, ``None`` for clouds.
        canonical_vertices: ``(N, 3)`` float32 tensor, canonical vertices, on the device.
        shape_embedding: ``(n,)`` tensor, the shape MLP output.
        shape_bias: ``(n,)`` tensor, shape part of the folded point MLP (on-the-fly points).
        point_embeddings: ``(N, n)`` tensor, ``e_p`` of every vertex / point.
        head_features: ``(N, 2n)`` tensor, ``e_p`` through the head's first linear layer.
        record: the :class:`ShapeRecord` the state was built from (what a cache stores).

    Tensors are shared with the predictor's caches: treat them as read-only. The surface
    projector used by xyz queries and paths is built on first use and kept with the state.
    """

    shape_id: str
    kind: ShapeKind
    n_points: int
    transform: Transform
    descriptor: NDArray
    residual: float
    ood_score: float
    ood_calibrated: bool
    bundle_hash: str
    vertices: NDArray = field(repr=False)
    canonical_points: NDArray = field(repr=False)
    faces: NDArray | None = field(repr=False)
    canonical_vertices: torch.Tensor = field(repr=False)
    shape_embedding: torch.Tensor = field(repr=False)
    shape_bias: torch.Tensor = field(repr=False)
    point_embeddings: torch.Tensor = field(repr=False)
    head_features: torch.Tensor = field(repr=False)
    record: ShapeRecord | None = field(default=None, repr=False)
    _lazy: dict[str, Any] = field(default_factory=dict, repr=False)

    @property
    def is_mesh(self) -> bool:
        return self.kind is ShapeKind.MESH

    @property
    def is_out_of_distribution(self) -> bool | None:
        """``ood_score > OOD_Z_THRESHOLD`` for calibrated bundles, ``None`` otherwise."""
        return self.ood_score > OOD_Z_THRESHOLD if self.ood_calibrated else None

    @property
    def device(self) -> torch.device:
        return self.head_features.device

    @property
    def nbytes(self) -> int:
        """Bytes held by the cached arrays and tensors (for cache accounting)."""
        tensors = (
            self.canonical_vertices,
            self.shape_embedding,
            self.shape_bias,
            self.point_embeddings,
            self.head_features,
        )
        total = sum(t.numel() * t.element_size() for t in tensors)
        total += self.canonical_points.nbytes + self.descriptor.nbytes
        return int(total + (0 if self.faces is None else self.faces.nbytes))

    @property
    def projector(self) -> MeshProjector | CloudProjector:
        """Surface projector in the canonical frame (built on first use)."""
        projector = self._lazy.get("projector")
        if projector is None:
            if self.faces is not None:
                projector = MeshProjector(self.canonical_points, self.faces)
            else:
                projector = CloudProjector(self.canonical_points)
            self._lazy["projector"] = projector
        return projector

    @property
    def spacing(self) -> float:
        """Sampling resolution in canonical units: mean edge length (mesh) or mean
        nearest-neighbour distance (cloud)."""
        projector = self.projector
        if isinstance(projector, MeshProjector):
            return projector.mean_edge_length
        return projector.mean_spacing


@dataclass(frozen=True)
class ResolvedPoints:
    """Query points resolved on one shape.

    Attributes:
        features: ``(Q, 2n)`` head features.
        positions: ``(Q, 3)`` float32 canonical coordinates (tensor, on the device).
        canonical: ``(Q, 3)`` float64 canonical coordinates (numpy).
        user: ``(Q, 3)`` float64 coordinates in the user's frame (the vertices themselves for
            indices, the projected points mapped back for xyz queries).
        indices: ``(Q,)`` int64 vertex indices, or ``None`` for projected xyz points.
    """

    features: torch.Tensor
    positions: torch.Tensor
    canonical: NDArray
    user: NDArray
    indices: NDArray | None

    @property
    def count(self) -> int:
        return int(self.positions.shape[0])


# --------------------------------------------------------------------------- predictor


class Predictor:
    """Learned geodesic distances and paths for registered shapes (one bundle, one device).

    Args:
        bundle: a loaded :class:`~litege_core.bundle.ModelBundle` (regression network).
        device: ``"cpu"``, ``"cuda"``, ... where every cached tensor and query runs.
        chunk_pairs: pairs per head evaluation (memory bound, see the module docstring).

    Raises:
        ArtifactError: the bundle's pipeline is not one this predictor implements.
    """

    def __init__(
        self,
        bundle: ModelBundle,
        device: str | torch.device = "cpu",
        *,
        chunk_pairs: int = DEFAULT_CHUNK_PAIRS,
    ) -> None:
        pipeline = bundle.pipeline
        if pipeline.canonicalization != "bbox":
            raise ArtifactError(
                f"bundle {bundle.name!r} uses canonicalization {pipeline.canonicalization!r}; "
                "the geodesic predictor implements 'bbox'"
            )
        if not math.isclose(pipeline.bbox_sqrt_area, BBOX_SQRT_AREA, rel_tol=1e-12):
            raise ArtifactError(
                f"bundle {bundle.name!r} was trained with bbox_sqrt_area "
                f"{pipeline.bbox_sqrt_area}, this library canonicalizes to {BBOX_SQRT_AREA}"
            )
        if not (pipeline.target_scale > 0 and pipeline.n_mesh_samples >= 4):
            raise ArtifactError(f"bundle {bundle.name!r} has an invalid pipeline: {pipeline}")
        if isinstance(chunk_pairs, bool) or int(chunk_pairs) < 1:
            raise InputError(f"chunk_pairs must be a positive integer, got {chunk_pairs!r}")
        self.bundle = bundle
        self.device = torch.device(device)
        self.chunk_pairs = int(chunk_pairs)
        self.network = bundle.network.eval()
        self.folded = FoldedGeodesicNet(self.network, self.device)
        self._shape_mlp = _ShapeMlp(self.network, self.device)
        self.target_scale = float(pipeline.target_scale)
        self.residual = bool(pipeline.residual)
        self.n_mesh_samples = int(pipeline.n_mesh_samples)
        training = bundle.manifest.get("training") or {}
        mean, std = training.get("residual_mean"), training.get("residual_std")
        self._ood: tuple[float, float] | None = None
        if mean is not None and std is not None:
            if not (math.isfinite(float(mean)) and math.isfinite(float(std)) and std > 0):
                raise ArtifactError(
                    f"bundle {bundle.name!r} has invalid residual statistics {mean}, {std}"
                )
            self._ood = (float(mean), float(std))

    def __repr__(self) -> str:
        return f"Predictor(bundle={self.bundle.name!r}, device={str(self.device)!r})"

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
        """:meth:`register` for several shapes, batched: one UDF-PCA call, one shape-MLP
        call, and point embeddings in chunks of :data:`DEFAULT_EMBED_ROWS` points over all
        shapes. Each shape gets the same result as :meth:`register` with the same seed."""
        shapes = list(shapes)
        if not shapes:
            return []
        for i, shape in enumerate(shapes):
            if not isinstance(shape, Shape):
                raise InputError(f"shapes[{i}] is a {type(shape).__name__}, not a Shape")
        samples = [shape_samples(s, self.n_mesh_samples, seed) for s in shapes]
        transforms = [canonicalize_bbox(p) for p in samples]
        engine = self.bundle.basis.engine(self.device)
        clouds = [t.apply(p) for t, p in zip(transforms, samples, strict=True)]
        described = engine.describe_with_residual(clouds)
        descriptors = described.descriptors.detach().cpu().numpy().astype(np.float32)
        residuals = described.residual.detach().cpu().numpy().astype(np.float64)
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
        return self.restore_many(shapes, records)

    def restore(self, shape: Shape, record: ShapeRecord) -> ShapeState:
        """Rebuild a state from its :class:`ShapeRecord` without recomputing the descriptor."""
        return self.restore_many([shape], [record])[0]

    def restore_many(
        self, shapes: Sequence[Shape], records: Sequence[ShapeRecord]
    ) -> list[ShapeState]:
        """:meth:`restore` for several shapes at once (the embedding half of registration).

        The result equals :meth:`register_many` with the records' seed: registration is this
        method applied to freshly computed records. This is what a cache stores: the record is
        a few hundred bytes, the embeddings it rebuilds are ``N × 3n`` floats.

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
        transforms = [r.transform for r in records]
        descriptors = torch.from_numpy(np.stack([r.descriptor for r in records])).to(
            self.device, torch.float32
        )
        canonical = [t.apply(s.vertices) for t, s in zip(transforms, shapes, strict=True)]
        counts = [c.shape[0] for c in canonical]
        with torch.no_grad():
            shape_emb = self._shape_mlp(descriptors)  # (B, n)
            biases = self.folded.shape_bias(shape_emb)  # (B, n)
            points = torch.from_numpy(np.concatenate(canonical)).to(self.device, torch.float32)
            row_bias = torch.repeat_interleave(
                biases, torch.tensor(counts, device=self.device), dim=0
            )
            embeddings = self._embed_rows(points, row_bias)
            features = self._feature_rows(embeddings)
        offsets = np.concatenate([[0], np.cumsum(counts)])

        def rows(tensor: torch.Tensor, b: int) -> torch.Tensor:
            part = tensor[offsets[b] : offsets[b + 1]]
            # own storage per state, so evicting one state frees its memory
            return part.clone() if len(shapes) > 1 else part

        states = []
        for b, (shape, record) in enumerate(zip(shapes, records, strict=True)):
            states.append(
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
                    canonical_points=frozen(canonical[b]),
                    faces=shape.faces,
                    canonical_vertices=rows(points, b),
                    shape_embedding=shape_emb[b].clone(),
                    shape_bias=biases[b].clone(),
                    point_embeddings=rows(embeddings, b),
                    head_features=rows(features, b),
                    record=record,
                )
            )
        return states

    def _embed_rows(self, points: torch.Tensor, bias: torch.Tensor) -> torch.Tensor:
        """``(R, 3)`` canonical points, ``(R, n)`` or ``(n,)`` bias → ``(R, n)``, chunked."""
        if points.shape[0] <= DEFAULT_EMBED_ROWS:
            return self.folded.embed(points, bias)
        parts = []
        for start in range(0, points.shape[0], DEFAULT_EMBED_ROWS):
            stop = start + DEFAULT_EMBED_ROWS
            part_bias = bias[start:stop] if bias.ndim == 2 else bias
            parts.append(self.folded.embed(points[start:stop], part_bias))
        return torch.cat(parts)

    def _feature_rows(self, embeddings: torch.Tensor) -> torch.Tensor:
        if embeddings.shape[0] <= DEFAULT_EMBED_ROWS:
            return self.folded.features(embeddings)
        return torch.cat(
            [
                self.folded.features(embeddings[s : s + DEFAULT_EMBED_ROWS])
                for s in range(0, embeddings.shape[0], DEFAULT_EMBED_ROWS)
            ]
        )

    def _ood_score(self, residual: float) -> float:
        if self._ood is None:
            return residual
        mean, std = self._ood
        return (residual - mean) / std

    def ood_score(self, state: ShapeState) -> float:
        """The state's out-of-distribution score (see the module docstring)."""
        self._check_state(state)
        return state.ood_score

    # ----------------------------------------------------------------- queries

    def _check_state(self, state: ShapeState) -> None:
        if not isinstance(state, ShapeState):
            raise InputError(f"expected a ShapeState, got {type(state).__name__}")
        if state.bundle_hash != self.bundle.content_hash:
            raise InputError(
                "this shape state was computed with another model bundle; register it again"
            )

    def resolve(self, state: ShapeState, query: Query, what: str = "source") -> ResolvedPoints:
        """Resolve sources or targets on ``state`` (validation at the boundary).

        Args:
            state: a registered shape.
            query: ``(Q,)`` integer indices, ``(Q, 3)`` xyz points in the user's frame
                (projected onto the surface: closest point of a mesh, nearest point of a
                cloud), or ``None`` / ``"all"`` for every vertex / point. The rule is by rank:
                2-D is xyz, 0-D/1-D is indices (which must be integers).
            what: word used in error messages.

        Raises:
            IndexOutOfRangeError: an index outside ``[0, N)``.
            ArrayShapeError: non-integer indices, xyz not ``(Q, 3)``, empty query.
            NonFiniteError: NaN or infinite xyz.
        """
        if query is None or (isinstance(query, str) and query == "all"):
            return ResolvedPoints(
                state.head_features,
                state.canonical_vertices,
                state.canonical_points,
                state.vertices,
                None,
            )
        if isinstance(query, str):
            raise ArrayShapeError(f"{what}s must be indices, xyz points or 'all', got {query!r}")
        if isinstance(query, torch.Tensor):
            query = query.detach().cpu().numpy()
        try:
            array = np.asarray(query)
        except (TypeError, ValueError) as exc:
            raise ArrayShapeError(f"{what}s are not a regular array: {exc}") from exc
        if array.ndim == 2:
            return self._resolve_points(state, as_query_points(array, f"{what} points"))
        indices = check_indices(array, state.n_points, what)
        return self._from_indices(state, indices)

    def _from_indices(self, state: ShapeState, indices: NDArray) -> ResolvedPoints:
        index_t = torch.from_numpy(indices).to(self.device)
        return ResolvedPoints(
            state.head_features.index_select(0, index_t),
            state.canonical_vertices.index_select(0, index_t),
            state.canonical_points[indices],
            state.vertices[indices],
            indices,
        )

    def _resolve_points(self, state: ShapeState, user_points: NDArray) -> ResolvedPoints:
        canonical = state.transform.apply(user_points)
        projector = state.projector
        if isinstance(projector, CloudProjector):
            _, indices = projector.nearest(canonical)
            return self._from_indices(state, indices)
        projected = projector.project(canonical).points
        return self.embed_canonical(state, projected)

    def embed_canonical(self, state: ShapeState, canonical: NDArray) -> ResolvedPoints:
        """Embed arbitrary canonical points ``(Q, 3)`` (already on the surface) on the fly."""
        positions = torch.from_numpy(np.ascontiguousarray(canonical)).to(self.device, torch.float32)
        with torch.no_grad():
            features = self._feature_rows(self._embed_rows(positions, state.shape_bias))
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
            src_features, dst_features: ``(R, 2n)`` head features.
            src_positions, dst_positions: ``(R, 3)`` canonical coordinates.

        Returns:
            ``(R,)`` ``|head|/1.42 (+ ‖s − d‖ for residual bundles)``; no diagonal rule.
        """
        out = self.folded.head(src_features - dst_features) / self.target_scale
        if self.residual:
            out = out + torch.linalg.vector_norm(src_positions - dst_positions, dim=-1)
        return out

    def distances(self, state: ShapeState, sources: Query, targets: Query = None) -> NDArray:
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
        array = np.asarray(source)
        if array.ndim == 0:
            query: Any = array.reshape(1)
        elif array.ndim == 1 and array.shape[0] == 3 and np.issubdtype(array.dtype, np.floating):
            query = array[None]
        else:
            raise ArrayShapeError(
                f"source must be one index or one (3,) float point, got shape {array.shape}"
            )
        return self.distances(state, query)[0]

    def distances_many(
        self,
        states: Sequence[ShapeState],
        sources_list: Sequence[Query],
        targets_list: Sequence[Query] | None = None,
    ) -> list[NDArray]:
        """Distances for many shapes in one batch (the service's micro-batcher).

        Pairs of all shapes are concatenated without padding; shapes whose pairs fit together
        in ``chunk_pairs`` share one head evaluation (so e.g. 64 shapes × 1 query run in one
        head call), larger ones are chunked.

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
        blocks = []
        for state, sources, targets in zip(states, sources_list, targets_list, strict=True):
            self._check_state(state)
            blocks.append(
                (self.resolve(state, sources, "source"), self.resolve(state, targets, "target"))
            )
        outputs: list[NDArray | None] = [None] * len(blocks)
        with torch.no_grad():
            group: list[int] = []
            group_pairs = 0
            for b, (src, dst) in enumerate(blocks):
                pairs = src.count * dst.count
                if pairs >= self.chunk_pairs:
                    outputs[b] = self._dense_block(src, dst)
                    continue
                if group and group_pairs + pairs > self.chunk_pairs:
                    self._flat_group([blocks[i] for i in group], group, outputs)
                    group, group_pairs = [], 0
                group.append(b)
                group_pairs += pairs
            if group:
                self._flat_group([blocks[i] for i in group], group, outputs)
        return [
            (np.asarray(out, dtype=np.float64) / state.transform.scale).astype(np.float32)
            for out, state in zip(outputs, states, strict=True)
        ]

    def _finish(self, head: torch.Tensor, euclidean: torch.Tensor) -> torch.Tensor:
        out = head / self.target_scale
        if self.residual:
            out = out + euclidean
        return out.masked_fill_(euclidean == 0, 0.0)

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
                diff = (f_src[:, None, :] - f_dst[None, :, :]).reshape(-1, f_src.shape[1])
                head = self.folded.head(diff, inplace=True).reshape(f_src.shape[0], -1)
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
        src_rows, dst_rows, sizes = [], [], []
        src_off = dst_off = 0
        for src, dst in group:
            s, t = src.count, dst.count
            src_rows.append(torch.arange(s, device=self.device).repeat_interleave(t) + src_off)
            dst_rows.append(torch.arange(t, device=self.device).repeat(s) + dst_off)
            sizes.append((s, t))
            src_off += s
            dst_off += t
        i = torch.cat(src_rows)
        j = torch.cat(dst_rows)
        f_src = torch.cat([src.features for src, _ in group])
        f_dst = torch.cat([dst.features for _, dst in group])
        x_src = torch.cat([src.positions for src, _ in group])
        x_dst = torch.cat([dst.positions for _, dst in group])
        head = self.folded.head(f_src[i] - f_dst[j], inplace=True)
        eu = torch.linalg.vector_norm(x_src[i] - x_dst[j], dim=-1)
        flat = self._finish(head, eu).cpu().numpy()
        start = 0
        for b, (s, t) in zip(positions, sizes, strict=True):
            outputs[b] = flat[start : start + s * t].reshape(s, t)
            start += s * t

    # ----------------------------------------------------------------- paths

    def path(
        self, state: ShapeState, source: int | ArrayLike, target: int | ArrayLike, **options: Any
    ) -> GeodesicPath:
        """Geodesic path from ``target`` to ``source``; see :func:`litege_core.paths.trace_path`."""
        from litege_core.paths import trace_path

        return trace_path(self, state, source, target, **options)

    def paths(
        self, state: ShapeState, sources: ArrayLike, targets: ArrayLike, **options: Any
    ) -> list[GeodesicPath]:
        """Several paths at once; see :func:`litege_core.paths.trace_paths`."""
        from litege_core.paths import trace_paths

        return trace_paths(self, state, sources, targets, **options)


class _ShapeMlp:
    """The shape MLP (``mlp_pca``) in eval mode, folded to affine maps on the device."""

    def __init__(self, net: GeodesicNet, device: torch.device) -> None:
        with torch.no_grad():
            self.layers = [
                (w.T.to(device, torch.float32).contiguous(), b.to(device, torch.float32))
                for w, b in _bn_blocks(net.mlp_pca)
            ]
        self.descriptor_dim = net.descriptor_dim

    def __call__(self, descriptors: torch.Tensor) -> torch.Tensor:
        """``(B, k)`` descriptors → ``(B, n)`` shape embeddings."""
        if descriptors.ndim != 2 or descriptors.shape[1] != self.descriptor_dim:
            raise ArrayShapeError(
                f"descriptors must have shape (B, {self.descriptor_dim}), "
                f"got {tuple(descriptors.shape)}"
            )
        h = descriptors
        for weight_t, bias in self.layers:
            h = torch.addmm(bias, h, weight_t).relu()
        return h


__all__ = [
    "DEFAULT_CHUNK_PAIRS",
    "OOD_Z_THRESHOLD",
    "FoldedGeodesicNet",
    "Predictor",
    "Query",
    "ResolvedPoints",
    "ShapeState",
]
