"""The LiteGE geodesic network (regression and matching variants) and its target scaling.

Reference-spec §3. One network class, :class:`GeodesicNet`, with width ``n`` and descriptor
size ``E`` (a "BN-block" is Linear **without** bias → BatchNorm1d → ReLU):

==========================  =========================================  ==========  ==========
module                      layers                                     (200, 240)  (400, 400)
==========================  =========================================  ==========  ==========
``mlp_coord``               2 BN-blocks 3→n→n (shared by src and dst)
``mlp_pca``                 3 BN-blocks E→n→n→n (shape MLP)
fusion                      concat ``[shape_emb, coord_emb]`` (shape first)
``project_down_pcacoord``   Linear with bias 2n→n, no activation
``mlp_pcacoord``            2 BN-blocks n→n→n (point MLP)
``project_embed``           Linear with bias n→n, no activation → ``e_p``
combine                     ``e_src − e_dst`` (signed)
``final_layers``            2 BN-blocks n→2n→2n (head)
``final_linear``            Linear with bias 2n→1
output                      ``abs()`` (or ``softplus``, spec §10 item 10)
parameters                                                             613,801     2,411,601
==========================  =========================================  ==========  ==========

**Coordinate normalization lives inside the network.** The per-axis z-score of the canonical
coordinates (mean and std of the *training* vertices, spec §3.3) is stored in the buffers
``coord_mean (3,)`` and ``coord_std (3,)`` (saved with the weights, set by
:meth:`GeodesicNet.set_coord_normalization` or :meth:`GeodesicNet.fit_coord_normalization`,
never hard-coded), and every entry point takes **raw canonical coordinates**. Autograd then
differentiates through the z-score, so ``∂G/∂p_canonical = ∂G/∂p_normalized / std`` comes out
right by construction — the authors' path tracer multiplies by ``std`` instead (spec §6, §10
item 1), which this layout makes impossible to repeat.

**Target scale (spec §3.3, §3.4).** The authors train on distances multiplied by
:data:`TARGET_SCALE` = 1.42 ("canonical units × 1.42", a legacy constant that puts the mean
target near 0.9). The scale is handled only by the helpers of this module:

* regression (residual mode): the training target is
  :func:`residual_target` ``= max(1.42·(g − ‖s − d‖), 0)`` and a prediction is
  :func:`geodesic_from_residual` ``= output/1.42 + ‖s − d‖``;
* matching (no residual): the target is :func:`matching_target`
  ``= 1.42·(g_X + g_Y)/2`` and a prediction is :func:`geodesic_from_output` ``= output/1.42``,

where ``g``, ``s``, ``d`` are in canonical units (bbox pipeline for regression, unit-area
pipeline for matching) and the Euclidean distance is taken on the **un-normalized** canonical
coordinates. :func:`predict_geodesic` wraps the network and these helpers and returns canonical
units; divide by the canonicalization scale (``Transform.unscale_distance``) for input units.

**Entry points.** :meth:`GeodesicNet.forward` is the training call (BatchNorm over the batch as
the authors do: the coordinate and point MLPs see the ``2B`` stacked source and destination
rows, the shape MLP the ``B`` descriptors). The inference entry points
(:meth:`~GeodesicNet.shape_embedding`, :meth:`~GeodesicNet.point_embedding`,
:meth:`~GeodesicNet.head`, :meth:`~GeodesicNet.distance`, :meth:`~GeodesicNet.pairwise`,
:meth:`~GeodesicNet.gathered`) embed every shape and every point once and run only the head per
pair; in eval mode they equal ``forward`` to float rounding. They are meant for eval mode (in
training mode each call would normalize over its own rows).
"""

from __future__ import annotations

import itertools
from typing import Any, Literal, get_args

import numpy as np
import torch
from numpy.typing import ArrayLike
from torch import nn

from litege_core.errors import ArrayShapeError, EmptyShapeError, InputError, NonFiniteError
from litege_core.nets._checks import as_tensor_like, broadcast_batch, check_last, check_ndim

TARGET_SCALE = 1.42
"""Legacy factor between canonical distances and network targets (spec §3.3)."""

REGRESSION_WIDTH = 200
REGRESSION_DESCRIPTOR_DIM = 240
MATCHING_WIDTH = 400
MATCHING_DESCRIPTOR_DIM = 400

OutputKind = Literal["abs", "softplus"]
OUTPUT_KINDS: tuple[str, ...] = get_args(OutputKind)


def apply_output(raw: torch.Tensor, output: str) -> torch.Tensor:
    """The network's last step on raw head outputs: ``|raw|`` (``"abs"``) or ``softplus(raw)``;
    the one rule for the trained, folded and distilled heads."""
    return raw.abs() if output == "abs" else nn.functional.softplus(raw)


def _bn_mlp(*dims: int) -> nn.Sequential:
    """BN-blocks ``dims[0]→dims[1]→…``: (Linear without bias, BatchNorm1d, ReLU) each."""
    layers: list[nn.Module] = []
    for d_in, d_out in itertools.pairwise(dims):
        layers += [nn.Linear(d_in, d_out, bias=False), nn.BatchNorm1d(d_out), nn.ReLU()]
    return nn.Sequential(*layers)


def _positive_int(value: object, name: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < 1:
        raise InputError(f"{name} must be a positive integer, got {value!r}")
    return int(value)


class GeodesicNet(nn.Module):
    """Learned geodesic distance ``G(src, dst | z_src, z_dst)`` on canonical shapes.

    Args:
        width: ``n``, the embedding width (200 regression, 400 matching).
        descriptor_dim: ``E``, the size of the UDF-PCA descriptor (240 / 400).
        output: ``"abs"`` (the reference) or ``"softplus"`` (smooth, spec §10 item 10).

    Buffers ``coord_mean (3,)`` and ``coord_std (3,)`` (canonical units) start as the identity
    normalization (0, 1); set them from the training vertices before training.
    """

    coord_mean: torch.Tensor
    coord_std: torch.Tensor

    def __init__(
        self,
        width: int = REGRESSION_WIDTH,
        descriptor_dim: int = REGRESSION_DESCRIPTOR_DIM,
        output: OutputKind = "abs",
    ) -> None:
        super().__init__()
        n = _positive_int(width, "width")
        e = _positive_int(descriptor_dim, "descriptor_dim")
        if output not in OUTPUT_KINDS:
            raise InputError(f"output must be one of {list(OUTPUT_KINDS)}, got {output!r}")
        self.width = n
        self.descriptor_dim = e
        self.output = output
        self.register_buffer("coord_mean", torch.zeros(3))
        self.register_buffer("coord_std", torch.ones(3))
        self.mlp_coord = _bn_mlp(3, n, n)
        self.mlp_pca = _bn_mlp(e, n, n, n)
        self.project_down_pcacoord = nn.Linear(2 * n, n)
        self.mlp_pcacoord = _bn_mlp(n, n, n)
        self.project_embed = nn.Linear(n, n)
        self.final_layers = _bn_mlp(n, 2 * n, 2 * n)
        self.final_linear = nn.Linear(2 * n, 1)

    # ------------------------------------------------------------------ configuration

    def config(self) -> dict[str, Any]:
        """JSON-safe constructor arguments (for a bundle manifest)."""
        return {"width": self.width, "descriptor_dim": self.descriptor_dim, "output": self.output}

    @classmethod
    def from_config(cls, config: dict[str, Any]) -> GeodesicNet:
        """Inverse of :meth:`config`; unknown keys raise :class:`InputError`."""
        unknown = set(config) - {"width", "descriptor_dim", "output"}
        if unknown:
            raise InputError(f"unknown GeodesicNet config keys: {sorted(unknown)}")
        return cls(**config)

    def extra_repr(self) -> str:
        return f"width={self.width}, descriptor_dim={self.descriptor_dim}, output={self.output!r}"

    # ------------------------------------------------------------------ normalization

    @torch.no_grad()
    def set_coord_normalization(self, mean: ArrayLike, std: ArrayLike) -> None:
        """Set the per-axis z-score applied to canonical coordinates.

        Args:
            mean: ``(3,)`` per-axis mean of the training vertices (canonical units).
            std: ``(3,)`` per-axis standard deviation, all ``> 0``.
        """
        values = []
        for name, value in (("mean", mean), ("std", std)):
            try:
                array = np.asarray(
                    value.detach().cpu() if isinstance(value, torch.Tensor) else value,
                    dtype=np.float64,
                )
            except (TypeError, ValueError) as exc:
                raise ArrayShapeError(f"{name} must be a numeric (3,) array: {exc}") from exc
            if array.shape != (3,):
                raise ArrayShapeError(f"{name} must have shape (3,), got {array.shape}")
            if not np.isfinite(array).all():
                raise NonFiniteError(f"{name} has NaN or infinite entries")
            values.append(array)
        if (values[1] <= 0).any():
            raise InputError(f"std must be positive on every axis, got {values[1].tolist()}")
        self.coord_mean.copy_(torch.as_tensor(values[0]))
        self.coord_std.copy_(torch.as_tensor(values[1]))

    def fit_coord_normalization(self, points: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """Set the normalization from training vertices; return ``(mean, std)`` float64 ``(3,)``.

        Args:
            points: ``(..., 3)`` canonical training coordinates (all vertices of all training
                shapes; the std is the population std, ``ddof=0``, as numpy's default).
        """
        if isinstance(points, torch.Tensor):
            points = points.detach().cpu().numpy()
        try:
            array = np.asarray(points, dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise ArrayShapeError(f"points must be a numeric (..., 3) array: {exc}") from exc
        if array.ndim < 1 or array.shape[-1] != 3:
            raise ArrayShapeError(f"points must have shape (..., 3), got {array.shape}")
        array = array.reshape(-1, 3)
        if array.shape[0] < 2:
            raise EmptyShapeError("at least two points are needed to fit a normalization")
        mean, std = array.mean(axis=0), array.std(axis=0)
        self.set_coord_normalization(mean, std)
        return mean, std

    def normalize_coords(self, points: torch.Tensor) -> torch.Tensor:
        """``(..., 3)`` canonical coordinates → z-scored network inputs ``(p − mean)/std``."""
        return (points - self.coord_mean) / self.coord_std

    # ------------------------------------------------------------------ building blocks

    @property
    def _reference(self) -> torch.Tensor:
        return self.final_linear.weight

    def _points(
        self, value: torch.Tensor, name: str, what: str, ndim: int | None = None
    ) -> torch.Tensor:
        tensor = as_tensor_like(value, name, self._reference)
        if ndim is not None:
            check_ndim(tensor, ndim, name, what)
        check_last(tensor, 3, name, what)
        return tensor

    def _shape_emb(
        self, value: torch.Tensor, name: str, what: str, ndim: int | None = None
    ) -> torch.Tensor:
        tensor = as_tensor_like(value, name, self._reference)
        if ndim is not None:
            check_ndim(tensor, ndim, name, what)
        check_last(tensor, self.width, name, what.replace("n", str(self.width)))
        return tensor

    def _embed_rows(self, coords: torch.Tensor, shape_rows: torch.Tensor) -> torch.Tensor:
        """``(R, 3)`` canonical coordinates + ``(R, n)`` shape embeddings → ``(R, n)`` ``e_p``."""
        coord_emb = self.mlp_coord(self.normalize_coords(coords))
        fused = self.project_down_pcacoord(torch.cat((shape_rows, coord_emb), dim=-1))
        return self.project_embed(self.mlp_pcacoord(fused))

    def _output(self, raw: torch.Tensor) -> torch.Tensor:
        return apply_output(raw, self.output)

    def _head_rows(self, diff: torch.Tensor) -> torch.Tensor:
        """``(R, n)`` differences ``e_src − e_dst`` → ``(R,)`` outputs."""
        return self._output(self.final_linear(self.final_layers(diff)).squeeze(-1))

    # ------------------------------------------------------------------ training entry point

    def forward(
        self,
        src: torch.Tensor,
        dst: torch.Tensor,
        desc_src: torch.Tensor,
        desc_dst: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """Training call: one output per (source, destination) pair.

        Args:
            src: ``(B, 3)`` source points, canonical coordinates (not z-scored).
            dst: ``(B, 3)`` destination points, canonical coordinates.
            desc_src: ``(B, E)`` descriptors of the source shapes.
            desc_dst: ``(B, E)`` descriptors of the destination shapes; ``None`` (or the
                same tensor) when source and destination lie on the same shape (regression):
                the shape MLP then runs once.

        Returns:
            ``(B,)`` network output ≥ 0 in target units (1.42 × canonical units): the residual
            of :func:`residual_target` (regression) or :func:`matching_target` (matching).
            In training mode BatchNorm uses the statistics of the ``2B`` stacked point rows
            and of the ``B`` descriptor rows (of each descriptor tensor separately).
        """
        src = self._points(src, "src", "(B, 3)", ndim=2)
        dst = self._points(dst, "dst", "(B, 3)", ndim=2)
        batch = src.shape[0]
        what = f"({batch}, {self.descriptor_dim})"
        desc_src = as_tensor_like(desc_src, "desc_src", self._reference)
        if tuple(dst.shape) != (batch, 3):
            raise ArrayShapeError(f"dst must have shape ({batch}, 3), got {tuple(dst.shape)}")
        if tuple(desc_src.shape) != (batch, self.descriptor_dim):
            raise ArrayShapeError(f"desc_src must have shape {what}, got {tuple(desc_src.shape)}")
        shape_src = self.mlp_pca(desc_src)
        if desc_dst is None or desc_dst is desc_src:
            shape_dst = shape_src
        else:
            desc_dst = as_tensor_like(desc_dst, "desc_dst", self._reference)
            if tuple(desc_dst.shape) != (batch, self.descriptor_dim):
                raise ArrayShapeError(
                    f"desc_dst must have shape {what}, got {tuple(desc_dst.shape)}"
                )
            shape_dst = self.mlp_pca(desc_dst)
        embedded = self._embed_rows(torch.cat((src, dst)), torch.cat((shape_src, shape_dst)))
        return self._head_rows(embedded[:batch] - embedded[batch:])

    # ------------------------------------------------------------------ inference entry points

    def shape_embedding(self, desc: torch.Tensor) -> torch.Tensor:
        """Shape MLP, cacheable per shape.

        Args:
            desc: ``(S, E)`` UDF-PCA descriptors (or ``(..., E)``).

        Returns:
            ``(S, n)`` shape embeddings (``(..., n)``).
        """
        desc = as_tensor_like(desc, "desc", self._reference)
        check_last(desc, self.descriptor_dim, "desc", f"(S, {self.descriptor_dim})")
        batch = desc.shape[:-1]
        return self.mlp_pca(desc.reshape(-1, self.descriptor_dim)).reshape(*batch, self.width)

    def embed(self, points: torch.Tensor, shape_emb: torch.Tensor) -> torch.Tensor:
        """Point embeddings with full broadcasting of the batch dims.

        Args:
            points: ``(..., 3)`` canonical coordinates.
            shape_emb: ``(..., n)`` shape embeddings, batch dims broadcastable with ``points``'.

        Returns:
            ``(..., n)`` point embeddings ``e_p`` over the broadcast batch shape.
        """
        points = self._points(points, "points", "(..., 3)")
        shape_emb = self._shape_emb(shape_emb, "shape_emb", "(..., n)")
        batch = broadcast_batch(points.shape[:-1], shape_emb.shape[:-1], "points and shape_emb")
        rows = self._embed_rows(
            points.expand(*batch, 3).reshape(-1, 3),
            shape_emb.expand(*batch, self.width).reshape(-1, self.width),
        )
        return rows.reshape(*batch, self.width)

    def point_embedding(self, points: torch.Tensor, shape_emb: torch.Tensor) -> torch.Tensor:
        """Fused point embeddings ``e_p``, cacheable per point.

        Args:
            points: ``(..., P, 3)`` canonical coordinates of ``P`` points per shape.
            shape_emb: ``(..., n)`` the embedding of the shape the points lie on (batch dims
                broadcastable against ``points.shape[:-2]``).

        Returns:
            ``(..., P, n)``.
        """
        points = self._points(points, "points", "(..., P, 3)")
        if points.ndim < 2:
            raise ArrayShapeError(f"points must have shape (..., P, 3), got {tuple(points.shape)}")
        shape_emb = self._shape_emb(shape_emb, "shape_emb", "(..., n)")
        return self.embed(points, shape_emb.unsqueeze(-2))

    def head(self, e_src: torch.Tensor, e_dst: torch.Tensor) -> torch.Tensor:
        """The per-pair part of the network.

        Args:
            e_src: ``(..., n)`` source point embeddings.
            e_dst: ``(..., n)`` destination point embeddings, broadcastable against ``e_src``.

        Returns:
            ``(...)`` outputs over the broadcast batch shape (target units, ≥ 0).
        """
        e_src = self._shape_emb(e_src, "e_src", "(..., n)")
        e_dst = self._shape_emb(e_dst, "e_dst", "(..., n)")
        batch = broadcast_batch(e_src.shape[:-1], e_dst.shape[:-1], "e_src and e_dst")
        diff = (e_src - e_dst).expand(*batch, self.width)
        return self._head_rows(diff.reshape(-1, self.width)).reshape(batch)

    def _pair(self, e_src: torch.Tensor, e_dst: torch.Tensor, symmetric: bool) -> torch.Tensor:
        out = self.head(e_src, e_dst)
        if symmetric:
            out = 0.5 * (out + self.head(e_dst, e_src))
        return out

    def distance(
        self,
        src: torch.Tensor,
        dst: torch.Tensor,
        shape_emb_src: torch.Tensor,
        shape_emb_dst: torch.Tensor | None = None,
        *,
        symmetric: bool = False,
    ) -> torch.Tensor:
        """Outputs for matched (source, destination) pairs with broadcasting.

        Args:
            src: ``(..., 3)`` source points (canonical).
            dst: ``(..., 3)`` destination points (canonical).
            shape_emb_src: ``(..., n)`` embedding of the source shape(s).
            shape_emb_dst: ``(..., n)`` of the destination shape(s); ``None``: the same.
            symmetric: average ``G(s, d)`` and ``G(d, s)`` (spec §10 item 11; off in the
                reference).

        Returns:
            ``(...)`` outputs over the broadcast batch shape; differentiable in ``src`` and
            ``dst`` (path tracing).
        """
        e_src = self.embed(src, shape_emb_src)
        e_dst = self.embed(dst, shape_emb_src if shape_emb_dst is None else shape_emb_dst)
        return self._pair(e_src, e_dst, symmetric)

    def pairwise(
        self,
        points_a: torch.Tensor,
        points_b: torch.Tensor,
        shape_emb_a: torch.Tensor,
        shape_emb_b: torch.Tensor | None = None,
        *,
        symmetric: bool = False,
    ) -> torch.Tensor:
        """All pairs between two point sets per shape (``forward_multi_sources_alldest``).

        Every point is embedded once; only the head runs on the ``S·Pa·Pb`` pairs (memory
        ``S·Pa·Pb·2n`` floats in the head: split large queries along ``Pa``).

        Args:
            points_a: ``(S, Pa, 3)`` sources (canonical coordinates).
            points_b: ``(S, Pb, 3)`` destinations.
            shape_emb_a: ``(S, n)`` embeddings of the source shapes.
            shape_emb_b: ``(S, n)`` of the destination shapes; ``None``: the same.
            symmetric: average both directions.

        Returns:
            ``(S, Pa, Pb)`` outputs, ``[s, i, j] = G(a_si, b_sj)``.
        """
        points_a = self._points(points_a, "points_a", "(S, Pa, 3)", ndim=3)
        points_b = self._points(points_b, "points_b", "(S, Pb, 3)", ndim=3)
        shape_emb_a = self._shape_emb(shape_emb_a, "shape_emb_a", "(S, n)", ndim=2)
        shape_emb_b = (
            shape_emb_a
            if shape_emb_b is None
            else self._shape_emb(shape_emb_b, "shape_emb_b", "(S, n)", ndim=2)
        )
        e_a = self.point_embedding(points_a, shape_emb_a)  # (S, Pa, n)
        e_b = self.point_embedding(points_b, shape_emb_b)  # (S, Pb, n)
        return self._pair(e_a.unsqueeze(2), e_b.unsqueeze(1), symmetric)

    def gathered(
        self,
        points_a: torch.Tensor,
        candidates: torch.Tensor,
        shape_emb_a: torch.Tensor,
        shape_emb_b: torch.Tensor | None = None,
        *,
        symmetric: bool = False,
    ) -> torch.Tensor:
        """Each source against its own ``K`` candidates (``forward_multi_sources``).

        Used by the coarse-to-fine search. When the candidates come from a fixed point set,
        embed that set once with :meth:`point_embedding`, gather the rows and call
        :meth:`head` instead.

        Args:
            points_a: ``(S, Q, 3)`` sources (canonical coordinates).
            candidates: ``(S, Q, K, 3)`` destinations per source.
            shape_emb_a: ``(S, n)`` embeddings of the source shapes.
            shape_emb_b: ``(S, n)`` of the candidate shapes; ``None``: the same.
            symmetric: average both directions.

        Returns:
            ``(S, Q, K)`` outputs, ``[s, q, k] = G(a_sq, c_sqk)``.
        """
        points_a = self._points(points_a, "points_a", "(S, Q, 3)", ndim=3)
        candidates = self._points(candidates, "candidates", "(S, Q, K, 3)", ndim=4)
        if candidates.shape[:2] != points_a.shape[:2]:
            raise ArrayShapeError(
                f"candidates must have shape ({points_a.shape[0]}, {points_a.shape[1]}, K, 3), "
                f"got {tuple(candidates.shape)}"
            )
        shape_emb_a = self._shape_emb(shape_emb_a, "shape_emb_a", "(S, n)", ndim=2)
        shape_emb_b = (
            shape_emb_a
            if shape_emb_b is None
            else self._shape_emb(shape_emb_b, "shape_emb_b", "(S, n)", ndim=2)
        )
        e_a = self.point_embedding(points_a, shape_emb_a)  # (S, Q, n)
        e_c = self.point_embedding(candidates, shape_emb_b.unsqueeze(1))  # (S, Q, K, n)
        return self._pair(e_a.unsqueeze(2), e_c, symmetric)


def matching_net(output: OutputKind = "abs") -> GeodesicNet:
    """The shape-matching network: :class:`GeodesicNet` at ``n = 400``, ``E = 400``.

    Used with two descriptors: ``net(src_on_X, dst_on_Y, z_X, z_Y)``; no Euclidean residual
    (:func:`matching_target`, :func:`geodesic_from_output`)."""
    return GeodesicNet(MATCHING_WIDTH, MATCHING_DESCRIPTOR_DIM, output)


# ---------------------------------------------------------------------- target scaling


def _clip_at_zero(value: Any) -> Any:
    if isinstance(value, torch.Tensor):
        return value.clamp_min(0.0)
    return np.maximum(value, 0.0)


def residual_target(geodesic: Any, euclidean: Any, *, clip: bool = True) -> Any:
    """Regression training target ``max(1.42·(g − e), 0)`` (spec §3.3).

    Args:
        geodesic: geodesic distances ``g`` in canonical units (tensor, array or float).
        euclidean: ``‖s − d‖`` on the un-normalized canonical coordinates, same shape.
        clip: clip negative residuals (solver error, rounding) to 0, as the reference does.
    """
    target = TARGET_SCALE * (geodesic - euclidean)
    return _clip_at_zero(target) if clip else target


def geodesic_from_residual(output: Any, euclidean: Any) -> Any:
    """Regression prediction in canonical units: ``output/1.42 + ‖s − d‖``."""
    return output / TARGET_SCALE + euclidean


def matching_target(geodesic_x: Any, geodesic_y: Any) -> Any:
    """Matching training target ``1.42·(g_X + g_Y)/2`` (unit-area canonical units, §3.4)."""
    return TARGET_SCALE * 0.5 * (geodesic_x + geodesic_y)


def geodesic_from_output(output: Any) -> Any:
    """Non-residual prediction in canonical units: ``output/1.42`` (matching network)."""
    return output / TARGET_SCALE


def predict_geodesic(
    net: GeodesicNet,
    src: torch.Tensor,
    dst: torch.Tensor,
    shape_emb_src: torch.Tensor,
    shape_emb_dst: torch.Tensor | None = None,
    *,
    residual: bool = True,
    symmetric: bool = False,
) -> torch.Tensor:
    """Predicted geodesic distance in canonical units (differentiable in ``src``, ``dst``).

    Args:
        net: the network (in eval mode for inference).
        src: ``(..., 3)`` source points, canonical coordinates.
        dst: ``(..., 3)`` destination points, canonical coordinates.
        shape_emb_src: ``(..., n)`` from :meth:`GeodesicNet.shape_embedding`.
        shape_emb_dst: ``(..., n)``, ``None``: the same shape.
        residual: regression network (adds ``‖src − dst‖``); ``False`` for matching.
        symmetric: average both directions.

    Returns:
        ``(...)`` geodesic distances in canonical units.
    """
    output = net.distance(src, dst, shape_emb_src, shape_emb_dst, symmetric=symmetric)
    if not residual:
        return geodesic_from_output(output)
    src_t = src.to(output.dtype)
    dst_t = dst.to(output.dtype)
    return geodesic_from_residual(output, torch.linalg.vector_norm(src_t - dst_t, dim=-1))


__all__ = [
    "MATCHING_DESCRIPTOR_DIM",
    "MATCHING_WIDTH",
    "OUTPUT_KINDS",
    "REGRESSION_DESCRIPTOR_DIM",
    "REGRESSION_WIDTH",
    "TARGET_SCALE",
    "GeodesicNet",
    "OutputKind",
    "apply_output",
    "geodesic_from_output",
    "geodesic_from_residual",
    "matching_net",
    "matching_target",
    "predict_geodesic",
    "residual_target",
]
