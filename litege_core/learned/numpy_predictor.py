"""A torch-free CPU runtime of a geodesic bundle: numpy in, numpy out (issue 17).

:class:`NumpyPredictor` answers what a one-shot ``litege geodesic`` call needs (register one
shape, distances between indexed points, distance fields) with numpy and a k-d tree, so a
process that uses it never imports torch (about 2 s of a 300-point CLI call on this machine's
CPU). It reads the same bundle files as :class:`~litege_core.learned.Predictor` (hashes
verified by :mod:`litege_core.learned.manifest`) and folds the network the same way
(:mod:`litege_core.nets.folded`: BatchNorm into the linear layers, the coordinate z-score into
the first layer, the shape half of the fusion layer into a per-shape bias, ``project_embed``
into the head's first layer), in float64, then evaluates in float32::

    f_p  = point_features(p | shape)                    (N, 2n) once per shape
    G    = |w · relu(W₂ relu(f_s − f_d + b₁) + b₂) + b| / 1.42 + ‖s − d‖   (canonical units)

and divides by the canonicalization scale. Pairs whose points coincide get an exact 0.

Scope: the trained (full) head or the bundle's distilled small head (``head="small"``,
:mod:`litege_core.nets.small_head`, folded the same way), float32, any descriptor lattice
(:data:`~litege_core.descriptor.basis.VOXEL_LATTICES`), the graph fusion
(:mod:`litege_core.learned.fusion`, the same functions as the torch predictor's; numpy and scipy
only), integer-index queries. Everything else (reduced precision, xyz queries, paths, GPUs) is
the torch :class:`~litege_core.learned.Predictor`'s; the two agree to float32 rounding
(``tests/litege_core/learned/test_numpy_predictor.py``).
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from litege_core.canonical import Transform, canonicalize_bbox
from litege_core.descriptor.basis import AUTO_LATTICE, LATTICE_CHOICES
from litege_core.descriptor.udf import compute_udf
from litege_core.errors import ArtifactError, InputError
from litege_core.learned.describe import shape_samples
from litege_core.learned.fusion import fused_distances
from litege_core.learned.fusion_calibration import DEFAULT_FUSION, resolve_fusion
from litege_core.learned.manifest import (
    AUTO_HEAD,
    GEODESIC,
    HEAD_CHOICES,
    NETWORK_FILE,
    SHIPPED_DIR,
    PipelineConfig,
    check_pipeline,
    consistent_manifest,
    open_bundle,
    residual_statistics,
    resolve_head,
    shipped_bundles,
    verified_small_head,
)
from litege_core.learned.routing import AGREEMENT_SOURCES, shape_agreement
from litege_core.learned.veto_graph import EdgeGeodesics, grown_features
from litege_core.query import parse_query
from litege_core.shape import Shape

PAIR_CHUNK = 8192
"""(source, target) pairs per head evaluation: ``PAIR_CHUNK × 2n`` float32 activations
(13 MB at ``n = 200``), independent of the query size."""

BN_EPS = 1e-5
"""BatchNorm1d's default epsilon, the one every GeodesicNet layer is trained with."""

_BN_BLOCKS = {"mlp_coord": 2, "mlp_pca": 3, "mlp_pcacoord": 2, "final_layers": 2}
"""BN-block MLPs of the network (Linear without bias, BatchNorm1d, ReLU) and their depth."""


Affine = tuple[NDArray, NDArray]
"""``(W (out, in), b (out,))`` float64."""


def _load_weights(path: Path) -> dict[str, NDArray]:
    from safetensors import SafetensorError
    from safetensors.numpy import load_file

    try:
        return {key: value.astype(np.float64) for key, value in load_file(str(path)).items()}
    except (SafetensorError, OSError) as exc:
        raise ArtifactError(f"cannot read {path.name}: {exc}") from exc


def _apply_output(out: NDArray, output: str) -> NDArray:
    """The head's output convention: ``abs`` or ``softplus``."""
    if output == "abs":
        return np.abs(out)
    return np.logaddexp(np.float32(0.0), out)


def _pair_head(
    diff: NDArray,
    first_bias: NDArray,
    hidden_wt: NDArray,
    hidden_b: NDArray,
    final_w: NDArray,
    final_b: float,
    output: str,
) -> NDArray:
    """``|w · relu(W relu(diff + b₁) + b) + b_f|`` (or softplus) per row of ``(R, d)`` feature
    differences, overwritten as scratch: the trained and the small head alike."""
    diff += first_bias
    np.maximum(diff, 0.0, out=diff)
    h = diff @ hidden_wt
    h += hidden_b
    np.maximum(h, 0.0, out=h)
    return _apply_output(h @ final_w + np.float32(final_b), output)


def _f32(array: NDArray) -> NDArray:
    return np.ascontiguousarray(array, dtype=np.float32)


def _bn_blocks(weights: dict[str, NDArray], prefix: str, depth: int) -> list[Affine]:
    """The ``depth`` BN-blocks of ``prefix`` folded into affine maps (eval semantics)."""
    blocks = []
    for layer in range(depth):
        linear, bn = f"{prefix}.{3 * layer}", f"{prefix}.{3 * layer + 1}"
        scale = weights[f"{bn}.weight"] / np.sqrt(weights[f"{bn}.running_var"] + BN_EPS)
        shift = weights[f"{bn}.bias"] - weights[f"{bn}.running_mean"] * scale
        blocks.append((weights[f"{linear}.weight"] * scale[:, None], shift))
    return blocks


@dataclass(frozen=True)
class FoldedNumpyNet:
    """A GeodesicNet's eval-mode affine maps, float32, for the numpy runtime.

    Attributes (``n`` the width, ``k`` the descriptor size; ``*_wt`` transposed weights):
        shape_layers: the shape MLP, ``[(k|n, n), (n,)]`` × 3.
        shape_wt, shape_b: ``(n, n)``, ``(n,)``: shape embedding → per-shape bias.
        c1_wt, c1_b, c2_wt, c2_b, p1_wt, p2_wt, p2_b: the point MLP.
        pf_wt, pf_b: ``(n, 2n)``, ``(2n,)``: last hidden layer → head features.
        h1_b, h2_wt, h2_b, f_w, f_b: the rest of the head.
        output: ``"abs"`` or ``"softplus"``.
    """

    shape_layers: tuple[tuple[NDArray, NDArray], ...]
    shape_wt: NDArray
    shape_b: NDArray
    c1_wt: NDArray
    c1_b: NDArray
    c2_wt: NDArray
    c2_b: NDArray
    p1_wt: NDArray
    p2_wt: NDArray
    p2_b: NDArray
    pf_wt: NDArray
    pf_b: NDArray
    h1_b: NDArray
    h2_wt: NDArray
    h2_b: NDArray
    f_w: NDArray
    f_b: float
    output: str

    @classmethod
    def fold(cls, weights: dict[str, NDArray], width: int, output: str) -> FoldedNumpyNet:
        """Fold a GeodesicNet state dict (float64 arrays) as :class:`~litege_core.nets.
        FoldedGeodesicNet` does."""
        n = width
        blocks = {name: _bn_blocks(weights, name, depth) for name, depth in _BN_BLOCKS.items()}
        (w1, b1), (w2, b2) = blocks["mlp_coord"]
        mean, std = weights["coord_mean"], weights["coord_std"]
        down_w, down_b = (
            weights["project_down_pcacoord.weight"],
            weights["project_down_pcacoord.bias"],
        )
        (w3, b3), (w4, b4) = blocks["mlp_pcacoord"]
        e_w, e_b = weights["project_embed.weight"], weights["project_embed.bias"]
        (h1_w, h1_b), (h2_w, h2_b) = blocks["final_layers"]
        f32 = _f32
        return cls(
            shape_layers=tuple((f32(w.T), f32(b)) for w, b in blocks["mlp_pca"]),
            shape_wt=f32((w3 @ down_w[:, :n]).T),
            shape_b=f32(b3 + w3 @ down_b),
            c1_wt=f32((w1 / std[None, :]).T),
            c1_b=f32(b1 - w1 @ (mean / std)),
            c2_wt=f32(w2.T),
            c2_b=f32(b2),
            p1_wt=f32((w3 @ down_w[:, n:]).T),
            p2_wt=f32(w4.T),
            p2_b=f32(b4),
            pf_wt=f32((h1_w @ e_w).T),
            pf_b=f32(h1_w @ e_b),
            h1_b=f32(h1_b),
            h2_wt=f32(h2_w.T),
            h2_b=f32(h2_b),
            f_w=f32(weights["final_linear.weight"][0]),
            f_b=float(weights["final_linear.bias"][0]),
            output=output,
        )

    def shape_bias(self, descriptor: NDArray) -> NDArray:
        """``(k,)`` descriptor → ``(n,)`` per-shape bias of the point MLP."""
        h = descriptor[None].astype(np.float32)
        for weight_t, bias in self.shape_layers:
            h = np.maximum(h @ weight_t + bias, 0.0)
        return (h @ self.shape_wt + self.shape_b)[0]

    def hidden(self, points: NDArray, shape_bias: NDArray) -> NDArray:
        """``(R, 3)`` float32 canonical coordinates → ``(R, n)`` last hidden layer of the
        point MLP (before ``project_embed``)."""
        h = np.maximum(points @ self.c1_wt + self.c1_b, 0.0)
        h = np.maximum(h @ self.c2_wt + self.c2_b, 0.0)
        h = np.maximum(h @ self.p1_wt + shape_bias, 0.0)
        return np.maximum(h @ self.p2_wt + self.p2_b, 0.0)

    def point_features(self, points: NDArray, shape_bias: NDArray) -> NDArray:
        """``(R, 3)`` float32 canonical coordinates → ``(R, 2n)`` float32 head features."""
        return self.hidden(points, shape_bias) @ self.pf_wt + self.pf_b

    def head(self, diff: NDArray) -> NDArray:
        """``(R, 2n)`` feature differences (overwritten) → ``(R,)`` outputs ≥ 0."""
        return _pair_head(diff, self.h1_b, self.h2_wt, self.h2_b, self.f_w, self.f_b, self.output)


@dataclass(frozen=True)
class FoldedNumpySmallHead:
    """A distilled :class:`~litege_core.nets.small_head.SmallHead` on a folded teacher, float32
    (as :class:`~litege_core.nets.small_head.FoldedSmallHead`): ``g_p = (A W_e) h_p + A b_e``
    per point, ``|w₃ · relu(W₂ relu(g_s − g_d + b₁) + b₂) + b₃|`` per pair.

    Attributes (``m`` features, ``k`` hidden): ``g_wt (n, m)``, ``g_b (m,)``, ``b1 (m,)``,
    ``h_wt (m, k)``, ``h_b (k,)``, ``f_w (k,)``, ``f_b``; ``teacher`` the folded network.
    """

    teacher: FoldedNumpyNet
    g_wt: NDArray
    g_b: NDArray
    b1: NDArray
    h_wt: NDArray
    h_b: NDArray
    f_w: NDArray
    f_b: float

    @classmethod
    def fold(
        cls, head: dict[str, NDArray], weights: dict[str, NDArray], teacher: FoldedNumpyNet
    ) -> FoldedNumpySmallHead:
        """Fold a SmallHead state dict (float64) onto the teacher's ``project_embed``."""
        a = head["point.weight"]  # (m, n)
        e_w, e_b = weights["project_embed.weight"], weights["project_embed.bias"]
        return cls(
            teacher=teacher,
            g_wt=_f32((a @ e_w).T),
            g_b=_f32(a @ e_b),
            b1=_f32(head["bias"]),
            h_wt=_f32(head["hidden.weight"].T),
            h_b=_f32(head["hidden.bias"]),
            f_w=_f32(head["final.weight"][0]),
            f_b=float(head["final.bias"][0]),
        )

    def point_features(self, points: NDArray, shape_bias: NDArray) -> NDArray:
        """``(R, 3)`` float32 canonical coordinates → ``(R, m)`` float32 student features."""
        return self.teacher.hidden(points, shape_bias) @ self.g_wt + self.g_b

    def head(self, diff: NDArray) -> NDArray:
        """``(R, m)`` feature differences (overwritten) → ``(R,)`` outputs ≥ 0."""
        return _pair_head(
            diff, self.b1, self.h_wt, self.h_b, self.f_w, self.f_b, self.teacher.output
        )


@dataclass(frozen=True, eq=False)
class NumpyShapeState:
    """One registered shape of a :class:`NumpyPredictor`.

    Attributes:
        shape_id: the shape's content hash.
        bundle_hash: content hash of the bundle it was registered with.
        n_points: ``N``.
        transform: user frame → canonical frame.
        canonical: ``(N, 3)`` float32 canonical vertices.
        residual: UDF-PCA reconstruction residual (canonical units).
        ood_score: z-score of ``residual`` against the training shapes (raw residual where
            the bundle has no statistics).
        shape_bias: ``(n,)`` float32 per-shape bias of the point MLP (point features are
            computed per query, for the points it names).
        faces: ``(F, 3)`` of a mesh, ``None`` for a cloud (the graph fusion's graph).
    """

    shape_id: str
    bundle_hash: str
    n_points: int
    transform: Transform
    canonical: NDArray
    residual: float
    ood_score: float
    shape_bias: NDArray
    faces: NDArray | None = None
    _kept: dict[str, Any] = field(default_factory=dict, repr=False, compare=False)
    """What the graph fusion computes once per shape (its graph, the veto's features)."""


class NumpyPredictor:
    """Learned geodesic distances without torch (see the module docstring).

    Args:
        path: a geodesic bundle directory (the shipped ones: :meth:`shipped`).
        head: ``"auto"`` (default: the small head when the bundle ships one), ``"full"``
            (the trained head) or ``"small"`` (the bundle's distilled head); ``head`` holds
            the resolved name.
        lattice: the informative voxels the UDF is evaluated at (``"auto"``, ``"full"``,
            ``"bcc"``, ``"stride2"``), as the torch predictor's ``descriptor_lattice``;
            ``lattice`` holds the resolved name.
        fusion: ``"auto"`` (default), ``"none"`` or ``"graph"``, as the torch predictor's
            (:mod:`litege_core.learned.fusion`): the same calibration, graph and blend;
            ``fusion`` holds the calibration, or ``None``.

    Raises:
        InputError: an unknown head, lattice or fusion; ``head="small"`` on a bundle without
            one; ``fusion="graph"`` on a bundle without a calibration, or one fitted for
            another bundle.
        ArtifactError: damaged or inconsistent bundle files (sidecars included), a pipeline
            the predictors do not implement, or a fusion on a bundle without residual
            statistics.
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        *,
        head: str = AUTO_HEAD,
        lattice: str = AUTO_LATTICE,
        fusion: str = DEFAULT_FUSION,
    ) -> None:
        if head not in HEAD_CHOICES:
            raise InputError(f"head must be one of {HEAD_CHOICES}, got {head!r}")
        if lattice not in LATTICE_CHOICES:
            raise InputError(f"lattice must be one of {LATTICE_CHOICES}, got {lattice!r}")
        directory, manifest, basis = open_bundle(path, GEODESIC, "model bundle")
        with consistent_manifest("bundle"):
            self.name = str(manifest["name"])
            self.pipeline = PipelineConfig(**manifest["pipeline"])
            network = manifest["network"]
            width, descriptor_dim = int(network["width"]), int(network["descriptor_dim"])
            output = str(network.get("output", "abs"))
            weights = _load_weights(directory / NETWORK_FILE)
            self.net = FoldedNumpyNet.fold(weights, width, output)
        check_pipeline(self.name, self.pipeline)
        if descriptor_dim != basis.n_components:
            raise ArtifactError(
                f"network expects {descriptor_dim}-d descriptors, "
                f"basis has {basis.n_components} components"
            )
        self.content_hash = str(manifest["content_hash"])
        self.manifest = manifest
        self.path = directory
        self.head, self.lattice = resolve_head(directory, head), basis.resolve_lattice(lattice)
        self._net: FoldedNumpyNet | FoldedNumpySmallHead = self.net
        if self.head == "small":
            self._net = self._small_head(directory, weights)
        self._ood = residual_statistics(self.name, manifest)
        self.fusion = resolve_fusion(fusion, directory, self.content_hash, self.name)
        if self.fusion is not None and self._ood is None:
            raise ArtifactError(
                f"bundle {self.name!r} has no residual statistics: graph fusion needs its "
                "OOD z-score"
            )
        self._veto: FoldedNumpyNet | FoldedNumpySmallHead = self._net
        if self.fusion is not None and self.fusion.veto_head != self.head:
            veto_small = self.fusion.veto_head == "small"
            self._veto = self._small_head(directory, weights) if veto_small else self.net
        self._descriptor = basis.lattice_projection(self.lattice)
        self._centers = self._descriptor.centers.astype(np.float64)  # (|S|, 3)

    def _small_head(self, directory: Path, weights: dict[str, NDArray]) -> FoldedNumpySmallHead:
        config, path = verified_small_head(directory, self.name, self.content_hash)
        head = _load_weights(path)
        with consistent_manifest("small head"):
            width, output = int(config["head"]["width"]), str(config["head"]["output"])
        if (width, output) != (self.net.c2_wt.shape[1], self.net.output):
            raise ArtifactError(
                f"small head of {self.name} (width {width}, output {output!r}) does not fit its "
                f"network (width {self.net.c2_wt.shape[1]}, output {self.net.output!r})"
            )
        return FoldedNumpySmallHead.fold(head, weights, self.net)

    @classmethod
    def shipped(cls, name: str, **options: str) -> NumpyPredictor:
        """The runtime of a shipped bundle (``quadrupeds``, ``humans``); ``options``: ``head``
        and ``lattice``."""
        if name not in shipped_bundles():
            raise InputError(f"unknown model {name!r}; shipped models: {shipped_bundles()}")
        return cls(SHIPPED_DIR / name, **options)

    def __repr__(self) -> str:
        fusion = "" if self.fusion is None else ", fusion='graph'"
        return (
            f"NumpyPredictor(bundle={self.name!r}, hash={self.content_hash[:12]}, "
            f"head={self.head!r}, lattice={self.lattice!r}{fusion})"
        )

    # ----------------------------------------------------------------- registration

    def describe(self, canonical_samples: NDArray) -> tuple[NDArray, float]:
        """``(P, 3)`` canonical samples → ``(k,)`` float32 descriptor and its residual
        ``‖c − zP‖`` (the same quantities as :meth:`~litege_core.descriptor.basis.
        DescriptorEngine.describe_with_residual` on the predictor's lattice)."""
        points = np.asarray(canonical_samples, dtype=np.float32).astype(np.float64)
        udf = compute_udf(points, self._centers, backend="auto", workers=-1)  # a k-d tree on CPU
        codes, residual = self._descriptor.describe(udf)
        return codes, float(residual)

    def register(self, shape: Shape, *, seed: int = 0) -> NumpyShapeState:
        """Canonicalize and describe ``shape`` once (its shape embedding).

        Args:
            shape: a validated mesh or point cloud in the user's frame.
            seed: seed of the surface samples of a mesh's descriptor (as the torch predictor).
        """
        if not isinstance(shape, Shape):
            raise InputError(f"expected a Shape, got {type(shape).__name__}")
        samples = shape_samples(shape, int(self.pipeline.n_mesh_samples), seed)
        transform = canonicalize_bbox(samples)
        descriptor, residual = self.describe(transform.apply(samples))
        points = transform.apply(shape.vertices)  # float64, as the torch state's
        canonical = points.astype(np.float32)
        state = NumpyShapeState(
            shape_id=shape.content_hash,
            bundle_hash=self.content_hash,
            n_points=shape.n_points,
            transform=transform,
            canonical=canonical,
            residual=residual,
            ood_score=residual if self._ood is None else (residual - self._ood[0]) / self._ood[1],
            shape_bias=self.net.shape_bias(descriptor),
            faces=shape.faces,
        )
        if self.fusion is not None:  # the fusion's graph reads float64 points
            state._kept["fusion.points"] = points
        return state

    # ----------------------------------------------------------------- queries

    def _indices(self, state: NumpyShapeState, query: ArrayLike | str | None, what: str) -> NDArray:
        parsed = parse_query(query, what).check(state.n_points, what)
        if parsed.points is not None:
            raise InputError(
                f"{what}: the numpy runtime takes point indices; xyz queries need the torch "
                "Predictor"
            )
        return np.arange(state.n_points) if parsed.indices is None else parsed.indices

    def distances(
        self,
        state: NumpyShapeState,
        sources: ArrayLike,
        targets: ArrayLike | str | None = None,
    ) -> NDArray:
        """Predicted geodesic distances ``(S, T)`` float32 in the user's units.

        Args:
            state: a shape registered by this predictor.
            sources: ``(S,)`` point indices.
            targets: ``(T,)`` point indices, or ``None`` / ``"all"`` (``T = N``).

        Raises:
            InputError: a state of another bundle, xyz queries.
            IndexOutOfRangeError, ArrayShapeError: bad indices (as the torch predictor).
        """
        if not isinstance(state, NumpyShapeState) or state.bundle_hash != self.content_hash:
            raise InputError("this shape state was not registered with this bundle")
        src = self._indices(state, sources, "source")
        dst = self._indices(state, targets, "target")
        if self.fusion is None:
            out = self._network(state, src, dst)
        else:  # the network where the answer needs it (not on a mesh its graph spans)
            out = fused_distances(
                lambda: self._network(state, src, dst),
                self.fusion,
                self._fusion_points(state),
                state.faces,
                (src, state.canonical[src]),
                (dst, state.canonical[dst]),
                state.ood_score,
                state._kept,
                self._edge_geodesics(state),
                self._veto_key,
            )
        return (out.astype(np.float64) / state.transform.scale).astype(np.float32)

    def agreement(self, state: NumpyShapeState, n_sources: int = AGREEMENT_SOURCES) -> float:
        """How far the network is from the fusion's own graph on this shape (unitless; ``nan``
        without a fusion calibration): as :meth:`~litege_core.learned.Predictor.agreement`,
        which it equals to float32 rounding. The graph is kept with ``state``."""
        if not isinstance(state, NumpyShapeState) or state.bundle_hash != self.content_hash:
            raise InputError("this shape state was not registered with this bundle")
        if self.fusion is None:
            return math.nan
        return shape_agreement(
            lambda sources: self._network(state, sources, np.arange(state.n_points)),
            self._fusion_points(state),
            state.faces,
            self.fusion,
            state._kept,
            self._edge_geodesics(state),
            self._veto_key,
            state.ood_score,
            n_sources,
        )

    @property
    def _veto_key(self) -> str:
        return f"numpy.{'small' if isinstance(self._veto, FoldedNumpySmallHead) else 'full'}"

    @staticmethod
    def _fusion_points(state: NumpyShapeState) -> NDArray:
        """``(N, 3)`` float64 canonical points the fusion's graph reads."""
        points = state._kept.get("fusion.points")
        return state.canonical.astype(np.float64) if points is None else points

    def _network(self, state: NumpyShapeState, src: NDArray, dst: NDArray) -> NDArray:
        """``(S, T)`` float32 network distances between point indices, canonical units."""
        n_dst = dst.shape[0]
        rows = max(1, PAIR_CHUNK // n_dst)
        out = np.empty((src.shape[0], n_dst), dtype=np.float32)
        x_src, x_dst = state.canonical[src], state.canonical[dst]
        f_dst = self._point_features(state, dst)  # first: a field's table in one batch
        f_src = self._point_features(state, src)
        for i0 in range(0, src.shape[0], rows):
            f_s, x_s = f_src[i0 : i0 + rows], x_src[i0 : i0 + rows]
            for j0 in range(0, n_dst, PAIR_CHUNK):
                f_t, x_t = f_dst[j0 : j0 + PAIR_CHUNK], x_dst[j0 : j0 + PAIR_CHUNK]
                diff = f_s[:, None, :] - f_t[None, :, :]  # (s, t, 2n)
                head = self._net.head(diff.reshape(-1, diff.shape[-1])).reshape(diff.shape[:2])
                euclidean = np.linalg.norm(x_s[:, None, :] - x_t[None, :, :], axis=-1)
                out[i0 : i0 + rows, j0 : j0 + PAIR_CHUNK] = self._finish(head, euclidean)
        return out

    def _point_features(self, state: NumpyShapeState, indices: NDArray) -> NDArray:
        """``(len(indices), F)`` the network's point features of ``indices``. On a cloud whose
        fusion vetoes with the network's own head (the shipped calibrations) they are read
        from the veto's table (:meth:`_veto_features`), grown to cover them: a distance
        field's features then serve its veto rounds too, computed once."""
        if self.fusion is None or self._veto is not self._net or state.faces is not None:
            return self._net.point_features(state.canonical[indices], state.shape_bias)
        table, rows = self._veto_features(state, indices)
        return table[rows[indices]]

    def _finish(self, head: NDArray, euclidean: NDArray) -> NDArray:
        """Head outputs → distances in canonical units (residual pipelines add the chord;
        coincident points get an exact 0). Both arrays of the same shape, float32."""
        block = head / np.float32(self.pipeline.target_scale)
        if self.pipeline.residual:
            block += euclidean
        block[euclidean == 0] = 0.0
        return block

    def _edge_geodesics(self, state: NumpyShapeState) -> EdgeGeodesics:
        """The fusion veto's predicted geodesics of point pairs (canonical units, float64),
        from a feature table kept with ``state`` whose rows are computed as pairs need them
        (a single pair's veto reads a few dozen points, not the whole cloud)."""

        def edges(i: NDArray, j: NDArray) -> NDArray:
            if i.size == 0:
                return np.empty(0)
            table, rows = self._veto_features(state, np.concatenate([i, j]))
            i_rows, j_rows = rows[i], rows[j]
            out = np.empty(i.shape[0])
            for start in range(0, i.shape[0], PAIR_CHUNK):
                a, b = i[start : start + PAIR_CHUNK], j[start : start + PAIR_CHUNK]
                ta, tb = i_rows[start : start + PAIR_CHUNK], j_rows[start : start + PAIR_CHUNK]
                head = self._veto.head(table[ta] - table[tb])
                euclidean = np.linalg.norm(state.canonical[a] - state.canonical[b], axis=-1)
                out[start : start + a.shape[0]] = self._finish(head, euclidean)
            return out

        return edges

    def _veto_features(self, state: NumpyShapeState, points: NDArray) -> tuple[NDArray, NDArray]:
        """Veto-head features of the points the veto has reached
        (:func:`~litege_core.learned.veto_graph.grown_features`), ``points`` among them; kept
        with ``state`` (``fusion.veto_features``), growing as the veto reaches new points."""

        def compute(missing: NDArray) -> NDArray:  # one row as two, as the torch predictor
            wanted = np.resize(missing, max(2, missing.size))
            features = self._veto.point_features(state.canonical[wanted], state.shape_bias)
            return features[: missing.size]

        kept = state._kept["fusion.veto_features"] = grown_features(
            state._kept.get("fusion.veto_features"), state.n_points, points, compute, np.concatenate
        )
        return kept


__all__ = [
    "PAIR_CHUNK",
    "FoldedNumpyNet",
    "FoldedNumpySmallHead",
    "NumpyPredictor",
    "NumpyShapeState",
]
