"""A trained :class:`~litege_core.nets.GeodesicNet` folded, in eval mode and float64, into
plain affine maps for inference (the learned-geodesic predictor and the matching search).

Each BatchNorm is folded into the preceding linear layer, the coordinate z-score into the first
layer, the shape half of the fusion layer into a per-shape bias, and the head's first linear
layer (``W (e_s − e_d) = W e_s − W e_d``) into per-point features ``f_p = a ⊙ (W e_p)``. A pair
then costs one subtraction, a ReLU, one ``2n × 2n`` matrix product and a dot product; results
equal ``GeodesicNet.forward`` to float32 rounding (tested to 1e-5).

**Reduced precision** (issue 17, opt-in; the default is float32 everywhere). The per-pair cost
is the head's ``2n × 2n`` product, and the per-point cost the point MLP; both can run in lower
precision when no gradient is needed (the path tracer's autograd calls always run float32):

* ``precision="bfloat16"``: the head's ``2n × 2n`` product and final dot take bfloat16 operands
  with float32 accumulation (oneDNN, AMX tiles on recent Xeons; tensor cores on CUDA); the
  feature difference and the first bias + ReLU stay float32. ``"int8"``: per-output-channel
  symmetric int8 weights, per-row dynamic int8 activations (the activations are ≥ 0 after
  the ReLU), int32 accumulation (``torch._int_mm``).
* ``embed_precision="bfloat16"``: the point MLP and the head-feature product in bfloat16
  (float32 accumulation) on blocks of :data:`BF16_MIN_ROWS` points or more on a CPU; the
  features are returned float32, the hidden layer (:meth:`FoldedGeodesicNet.hidden`, which the
  small head reads) bfloat16. ~3× faster products on a Xeon with AMX tiles, slower on an AVX2
  CPU (BENCHMARKS "bf16-point-mlp"). ``"int8"`` (CPU): the point
  MLP's three ``n × n`` products with per-output-channel symmetric int8 weights and int8
  activations quantized per call, int32 accumulation (the CPU quantized engine's dynamic
  linear: ``torch.ops.quantized.linear_dynamic``, oneDNN where available), and the
  head-feature product after them (``n → 2n``, or the small head's ``n → m``) the same way;
  the ``3 → n`` first layer stays float32. The products run ~1.3–1.6× faster
  than float32 on an AVX2 CPU from 512 rows up, where bfloat16 is slower (BENCHMARKS
  "int8-point-mlp").
* ``head_rank=r``: the ``2n × 2n`` product replaced by its best rank-``r`` approximation
  (truncated SVD, no retraining): ``2 · 2n · r`` instead of ``(2n)²`` multiply-adds per pair;
  it applies to every call, gradients included (it is a different, smaller head).

Speed and accuracy of each are measured side by side by ``scripts/bench_predictor.py
--accuracy`` (BENCHMARKS.md, section ``predictor-accuracy``).
"""

from __future__ import annotations

import warnings
from typing import Literal

import torch
from torch import nn

from litege_core.errors import ArrayShapeError, ArtifactError, InputError
from litege_core.nets.geodesic import GeodesicNet, apply_output

Precision = Literal["float32", "bfloat16", "int8"]
PRECISIONS: tuple[str, ...] = ("float32", "bfloat16", "int8")
"""Values of :class:`FoldedGeodesicNet`'s ``precision`` and ``embed_precision``."""

INT8_MIN_ROWS = 512
"""Fewest rows an int8 product quantizes (the point MLP's points, the small head's pairs; fewer
run float32): the dynamic linear's fixed cost per call exceeds its saving below ~256 rows of a
``200 × 200`` product (2-core AMD EPYC, 2026-11-30: 1 row 0.10 ms against 0.015 ms float32;
2000 rows 2.2 ms against 3.0 ms)."""

INT8_ENGINES = ("onednn", "x86", "fbgemm", "qnnpack")
"""CPU quantized engines int8 products pack their weights for, the first supported one
(oneDNN's dynamic linear was 1.3x faster than fbgemm's on a 2-core AMD EPYC, 2026-11-30)."""

BF16_MIN_ROWS = 128
"""Fewest points a CPU's bfloat16 point MLP takes (fewer run float32): its conversions and
oneDNN calls cost ~0.12 ms per block, more than float32's products below ~100 rows
(2-core Xeon with AMX, 2026-12-01: 16 rows 0.13 ms against 0.05 ms float32; 2000 rows 1.5 ms
against 4.6 ms)."""

_INT_MM_MIN_ROWS = 17  # torch._int_mm needs more than 16 rows

PAIR_TILE = 4096
"""Pairs per tile of :meth:`FoldedGeodesicNet.pair_head`: ``4096 × 2n`` float32 activations
(6.6 MB at ``n = 200``, within the L2 + L3 share of a core); tiles of 2048 and 16384 pairs
were 5–15 % slower in bfloat16 (2-core Xeon with AMX, 2026-11-24), float32 was flat."""


def _fused_linear_relu_available(device: torch.device) -> bool:
    """Whether oneDNN's fused bfloat16 linear + ReLU runs here (CPU builds with mkldnn)."""
    if device.type != "cpu" or not torch.backends.mkldnn.is_available():
        return False
    try:
        x = torch.ones((2, 8), dtype=torch.bfloat16)
        w = torch.ones((8, 8), dtype=torch.bfloat16)
        out = torch.ops.mkldnn._linear_pointwise(x, w, w[0], "relu", [], "")
    except (AttributeError, RuntimeError, NotImplementedError):
        return False
    return bool(out.shape == (2, 8) and float(out[0, 0]) == 9.0)


def fast_bfloat16(device: torch.device | str = "cpu") -> bool:
    """Whether bfloat16 products are faster than float32 on ``device``: a CPU with
    AVX512-BF16 or AMX tiles, or a CUDA device with native bfloat16 (compute capability ≥ 8)."""
    dev = torch.device(device)
    if dev.type == "cuda":
        return bool(torch.cuda.is_available() and torch.cuda.get_device_capability(dev)[0] >= 8)
    if dev.type != "cpu":
        return False
    cpu = getattr(torch, "cpu", None)
    checks = ("_is_amx_tile_supported", "_is_avx512_bf16_supported")
    return any(bool(getattr(cpu, name, lambda: False)()) for name in checks)


def resolve_precision(precision: str, device: torch.device | str = "cpu") -> str:
    """``"auto"`` → ``"bfloat16"`` where :func:`fast_bfloat16`, else ``"float32"``; other
    values are checked and returned."""
    if precision == "auto":
        return "bfloat16" if fast_bfloat16(device) else "float32"
    if precision not in PRECISIONS:
        raise InputError(f"precision must be 'auto' or one of {PRECISIONS}, got {precision!r}")
    return precision


def _quantize_rows(weight: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Symmetric int8 per row of ``weight`` ``(out, in)``: ``(in, out)`` int8 and ``(out,)``
    scales."""
    scale = weight.abs().amax(dim=1).clamp_min(1e-30) / 127.0
    q = torch.round(weight / scale[:, None]).clamp_(-127, 127).to(torch.int8)
    return q.T.contiguous(), scale


def int8_engine() -> str | None:
    """The CPU quantized engine the int8 point MLP uses (:data:`INT8_ENGINES`), or ``None``
    where this torch build has none."""
    supported = torch.backends.quantized.supported_engines
    return next((name for name in INT8_ENGINES if name in supported), None)


def runs_int8(packed: object, activations: torch.Tensor, *inputs: torch.Tensor) -> bool:
    """Whether a product with ``packed`` int8 weights (``None``: none packed) runs in
    int8 on these ``(R, ·)`` activations: :data:`INT8_MIN_ROWS` rows or more, and no gradient
    needed through them or ``inputs`` (the other tensors the result depends on)."""
    return (
        packed is not None
        and activations.shape[0] >= INT8_MIN_ROWS
        and not _needs_grad(activations, *inputs)
    )


def pack_int8(weight: torch.Tensor, bias: torch.Tensor | None) -> object:
    """``x Wᵀ + b`` packed for the quantized engine's dynamic linear: ``weight`` ``(out, in)``
    as per-output-channel symmetric int8, ``bias`` ``(out,)`` float32 or ``None``.

    Raises:
        InputError: this torch build has no CPU quantized engine.
    """
    engine = int8_engine()
    if engine is None:
        raise InputError("this torch build has no quantized CPU engine for int8 products")
    weight = weight.to(torch.float32).contiguous()
    scale = (weight.abs().amax(dim=1).clamp_min(1e-30) / 127.0).double()
    zero = torch.zeros(weight.shape[0], dtype=torch.long)
    previous = torch.backends.quantized.engine
    with warnings.catch_warnings():  # quantized tensors are deprecated; torch is pinned
        warnings.simplefilter("ignore", UserWarning)
        try:
            torch.backends.quantized.engine = engine  # the packing follows the engine
            q = torch.quantize_per_channel(weight, scale, zero, 0, torch.qint8)
            return torch.ops.quantized.linear_prepack(
                q, None if bias is None else bias.to(torch.float32).contiguous()
            )
        finally:
            torch.backends.quantized.engine = previous


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
        precision: arithmetic of the head's per-pair product without autograd:
            ``"float32"`` (default), ``"bfloat16"`` or ``"int8"`` (module docstring).
        embed_precision: arithmetic of the point MLP without autograd: ``"float32"``
            (default), ``"bfloat16"`` or ``"int8"`` (CPU only; module docstring).
        head_rank: replace the head's ``2n × 2n`` product by its rank-``head_rank`` SVD
            truncation (``None``: full rank, the trained head).

    Attributes:
        width: ``n``.
        output: ``"abs"`` or ``"softplus"``.
        precision, embed_precision, head_rank: as given.
    """

    def __init__(
        self,
        net: GeodesicNet,
        device: torch.device | str = "cpu",
        dtype: torch.dtype = torch.float32,
        *,
        precision: str = "float32",
        embed_precision: str = "float32",
        head_rank: int | None = None,
    ) -> None:
        if precision not in PRECISIONS:
            raise InputError(f"precision must be one of {PRECISIONS}, got {precision!r}")
        if embed_precision not in PRECISIONS:
            raise InputError(
                f"embed_precision must be one of {PRECISIONS}, got {embed_precision!r}"
            )
        if embed_precision == "int8" and torch.device(device).type != "cpu":
            raise InputError("the int8 point MLP runs on a CPU only (use bfloat16 on a GPU)")
        if head_rank is not None and (
            isinstance(head_rank, bool) or not 1 <= int(head_rank) <= 2 * net.width
        ):
            raise InputError(f"head_rank must be in [1, {2 * net.width}], got {head_rank!r}")
        self.precision = precision
        self.embed_precision = embed_precision
        self.head_rank = None if head_rank is None else int(head_rank)
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
            # project_embed and the head's first product are both linear: one (n, 2n) map
            self.pf_wt, self.pf_b = put((h1_w @ e_w).T), put(h1_w @ e_b)
            self.h2_wt, self.h2_b = put(h2_w.T), put(h2_b)  # (2n, 2n), (2n,)
            self.f_w, self.f_b = put(f_w[:, None]), put(f_b)  # (2n, 1), ()
            self._shape_w = put(self._shape_w)
            self._shape_b = put(self._shape_b)
            self._low_rank: tuple[torch.Tensor, torch.Tensor] | None = None
            if self.head_rank is not None:
                u, sv, vh = torch.linalg.svd(h2_w)  # h2_w (out, in) = U S Vᴴ
                r = self.head_rank
                # x Wᵀ ≈ (x V_r) (S_r U_rᵀ)
                self._low_rank = (put(vh[:r].T), put(sv[:r, None] * u[:, :r].T))
            self._fused = _fused_linear_relu_available(self.device)
            self._bf16: dict[str, torch.Tensor] = {}
            if precision == "bfloat16" or embed_precision == "bfloat16":
                self._bf16 = self._bfloat16_weights(
                    h2_w,
                    h2_b,
                    f_w,
                    [c1_w, w2, p1_w, w4, e_w, h1_w, h1_w @ e_w],
                    [c1_b, b2, b4, e_b, h1_w @ e_b],
                )
            self._int8: tuple[torch.Tensor, torch.Tensor] | None = None
            if precision == "int8":
                q, scale = _quantize_rows(h2_w)
                self._int8 = (q.to(self.device), scale.to(self.device, torch.float32))
            self._packed: dict[str, object] | None = None
            if embed_precision == "int8":
                self._packed = {
                    "c2": pack_int8(w2, b2),
                    "p1": pack_int8(p1_w, None),
                    "p2": pack_int8(w4, b4),
                    "pf": pack_int8(h1_w @ e_w, h1_w @ e_b),
                }

    def _bfloat16_weights(
        self,
        h2_w: torch.Tensor,
        h2_b: torch.Tensor,
        f_w: torch.Tensor,
        embed_w: list[torch.Tensor],
        embed_b: list[torch.Tensor],
    ) -> dict[str, torch.Tensor]:
        def bf(t: torch.Tensor) -> torch.Tensor:
            return t.to(device=self.device, dtype=torch.bfloat16).contiguous()

        weights = {"h2_b": bf(h2_b)}
        names = ["h2", "f", "c1", "c2", "p1", "p2", "e", "h1", "pf"]
        matrices = [h2_w, f_w[None, :], *embed_w]
        if self._low_rank is not None:  # (in, r) and (r, out) → oneDNN's (out, in)
            names += ["v", "us"]
            matrices += [self._low_rank[0].T, self._low_rank[1].T]
        for name, w in zip(names, matrices, strict=True):
            weights[f"{name}_w"] = bf(w)  # (out, in): oneDNN's layout
            weights[f"{name}_wt"] = bf(w.T)
        for name, b in zip(("c1", "c2", "p2", "e", "pf"), embed_b, strict=True):
            weights[f"{name}_b"] = bf(b)
        return weights

    def _linear(
        self, x: torch.Tensor, name: str, bias: torch.Tensor | None, relu: bool
    ) -> torch.Tensor:
        """bfloat16 ``x Wᵀ + b`` (ReLU), fused by oneDNN where available."""
        w = self._bf16[f"{name}_w"]
        if self._fused and x.shape[0] > 0:
            return torch.ops.mkldnn._linear_pointwise(
                x, w, bias, "relu" if relu else "none", [], ""
            )
        out = x @ self._bf16[f"{name}_wt"]
        if bias is not None:
            out = out + bias
        return out.relu_() if relu else out

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
        if self._runs_bf16(points, shape_bias):
            return self._embed_bf16(points, shape_bias)
        return torch.addmm(self.e_b, self.hidden(points, shape_bias), self.e_wt)

    def _hidden_int8(self, points: torch.Tensor, shape_bias: torch.Tensor) -> torch.Tensor:
        """:meth:`hidden` with the three ``n × n`` products in dynamic int8 (float32 in and
        out; module docstring)."""
        linear, linear_relu = (
            torch.ops.quantized.linear_dynamic,
            torch.ops.quantized.linear_relu_dynamic,
        )
        packed = self._packed
        assert packed is not None  # runs_int8 said so
        h = torch.addmm(self.c1_b, points, self.c1_wt).relu_()
        h = linear_relu(h, packed["c2"], False)
        h = linear(h, packed["p1"], False).add_(shape_bias).relu_()
        return linear_relu(h, packed["p2"], False)

    def _runs_bf16(self, points: torch.Tensor, shape_bias: torch.Tensor) -> bool:
        """Whether the point MLP runs in bfloat16 on these ``(R, 3)`` points: with
        ``embed_precision="bfloat16"``, no gradient needed, and on a CPU
        :data:`BF16_MIN_ROWS` rows or more."""
        if self.embed_precision != "bfloat16" or _needs_grad(points, shape_bias):
            return False
        return self.device.type != "cpu" or points.shape[0] >= BF16_MIN_ROWS

    def _hidden_bf16(self, points: torch.Tensor, shape_bias: torch.Tensor) -> torch.Tensor:
        """:meth:`hidden` with bfloat16 products and float32 accumulation (the first layer,
        ``3 → n``, stays float32: it is cheap and sees the raw coordinates; the per-shape bias
        is added in float32). Returns bfloat16."""
        bf = self._bf16
        h = torch.addmm(self.c1_b, points, self.c1_wt).relu_().to(torch.bfloat16)
        h = self._linear(h, "c2", bf["c2_b"], relu=True)
        h = (self._linear(h, "p1", None, relu=False).float() + shape_bias).relu_()
        return self._linear(h.to(torch.bfloat16), "p2", bf["p2_b"], relu=True)

    def _embed_bf16(self, points: torch.Tensor, shape_bias: torch.Tensor) -> torch.Tensor:
        """:meth:`embed` with bfloat16 products (:meth:`_hidden_bf16`). Returns bfloat16."""
        return self._linear(self._hidden_bf16(points, shape_bias), "e", self._bf16["e_b"], False)

    def point_features(self, points: torch.Tensor, shape_bias: torch.Tensor) -> torch.Tensor:
        """``(R, 3)`` canonical coordinates → ``(R, 2n)`` head features, as
        ``features(embed(points, shape_bias))`` with the two linear maps between the last
        ReLU and the features folded into one (one ``n × n`` product less per point; equal to
        float32 rounding). Differentiable in ``points``."""
        if self._runs_bf16(points, shape_bias):
            hidden = self._hidden_bf16(points, shape_bias)
            return self._linear(hidden, "pf", self._bf16["pf_b"], relu=False).float()
        if runs_int8(self._packed, points, shape_bias):
            assert self._packed is not None  # runs_int8 said so
            hidden = self._hidden_int8(points, shape_bias)
            return torch.ops.quantized.linear_dynamic(hidden, self._packed["pf"], False)
        return torch.addmm(self.pf_b, self.hidden(points, shape_bias), self.pf_wt)

    def hidden(self, points: torch.Tensor, shape_bias: torch.Tensor) -> torch.Tensor:
        """``(R, 3)`` canonical coordinates → ``(R, n)`` last hidden layer of the point MLP
        (after its last ReLU, before ``project_embed``), float32; the input of every linear
        map a head reads (the distilled head folds its own into it,
        :class:`~litege_core.nets.small_head.FoldedSmallHead`). Differentiable in ``points``
        (with ``embed_precision="int8"``, the int8 products run only where no gradient is
        needed; with ``"bfloat16"``, the products run in bfloat16 there and the result is
        bfloat16)."""
        if self._runs_bf16(points, shape_bias):
            return self._hidden_bf16(points, shape_bias)
        if runs_int8(self._packed, points, shape_bias):
            return self._hidden_int8(points, shape_bias)
        h = torch.addmm(self.c1_b, points, self.c1_wt).relu()
        h = torch.addmm(self.c2_b, h, self.c2_wt).relu()
        h = (h @ self.p1_wt + shape_bias).relu()
        return torch.addmm(self.p2_b, h, self.p2_wt).relu()

    def features(self, embeddings: torch.Tensor) -> torch.Tensor:
        """``(R, n)`` point embeddings → ``(R, 2n)`` head features ``f_p = a ⊙ (W₁ e_p)``
        (float32; bfloat16 embeddings from ``embed_precision="bfloat16"`` are multiplied in
        bfloat16)."""
        if embeddings.dtype == torch.bfloat16:
            return self._linear(embeddings, "h1", None, relu=False).float()
        return embeddings @ self.h1_wt

    def head(self, diff: torch.Tensor, *, inplace: bool = False) -> torch.Tensor:
        """``(R, 2n)`` feature differences ``f_s − f_d`` → ``(R,)`` network outputs (≥ 0).

        ``inplace=True`` reuses ``diff`` as scratch memory (not with autograd). Without
        autograd, the ``2n × 2n`` product runs in :attr:`precision`.
        """
        h = diff.add_(self.h1_b).relu_() if inplace else (diff + self.h1_b).relu()
        return self._head_rest(h, inplace, self.precision != "float32" and not _needs_grad(diff))

    def _head_rest(self, h: torch.Tensor, inplace: bool, reduced: bool) -> torch.Tensor:
        """The head after its first ReLU: ``(R, 2n)`` activations → ``(R,)`` outputs."""
        if reduced:
            out = self._head_reduced(h)
        else:
            if self._low_rank is not None:
                v, us = self._low_rank
                h = torch.addmm(self.h2_b, h @ v, us)
            else:
                h = torch.addmm(self.h2_b, h, self.h2_wt)
            h = h.relu_() if inplace else h.relu()
            out = (h @ self.f_w).squeeze(-1)
        out = out + self.f_b
        return apply_output(out, self.output)

    def pair_head(
        self, src: torch.Tensor, dst: torch.Tensor, *, tile_pairs: int = PAIR_TILE
    ) -> torch.Tensor:
        """Network outputs of every pair: ``(S, 2n)`` source and ``(T, 2n)`` target features
        → ``(S, T)``, ``[i, j] = head(src[i] − dst[j])``.

        The same operations as :meth:`head` on the broadcast differences (in float32 equal up
        to the matrix kernel's rounding, which may vary with the number of rows; in reduced
        precision the first bias is added to the sources first), in tiles of about
        ``tile_pairs`` pairs whose activations stay in the CPU cache (the ``(S·T, 2n)``
        differences are never materialised); with autograd, one :meth:`head` call.
        """
        n_src, n_dst, width = src.shape[0], dst.shape[0], src.shape[1]
        if _needs_grad(src, dst):
            diff = (src[:, None, :] - dst[None, :, :]).reshape(-1, width)
            return self.head(diff).reshape(n_src, n_dst)
        out = torch.empty((n_src, n_dst), dtype=src.dtype, device=src.device)
        if out.numel() == 0:
            return out
        cols = min(n_dst, max(1, int(tile_pairs)))
        rows = max(1, int(tile_pairs) // cols)
        scratch = torch.empty(min(rows, n_src) * cols * width, dtype=src.dtype, device=src.device)
        # reduced precision: the first bias goes into the sources once (one pass less per
        # tile); float32 keeps head()'s order of operations
        reduced = self.precision != "float32"
        if reduced:
            src = src + self.h1_b
        for i0 in range(0, n_src, rows):
            a = src[i0 : i0 + rows]
            for j0 in range(0, n_dst, cols):
                c = dst[j0 : j0 + cols]
                diff = scratch[: a.shape[0] * c.shape[0] * width].view(a.shape[0], c.shape[0], -1)
                torch.sub(a[:, None, :], c[None, :, :], out=diff)
                flat = diff.view(-1, width)
                if reduced:
                    head = self._head_rest(flat.relu_(), True, True)
                else:
                    head = self.head(flat, inplace=True)
                out[i0 : i0 + rows, j0 : j0 + cols] = head.view(a.shape[0], c.shape[0])
        return out

    def _head_reduced(self, h: torch.Tensor) -> torch.Tensor:
        """``(R, 2n)`` first-layer activations (float32, ≥ 0) → ``(R,)`` final dot without
        its bias, with the ``2n × 2n`` product in bfloat16 or int8."""
        if self.precision == "bfloat16":
            hb = h.to(torch.bfloat16)
            if self._low_rank is not None:
                hb = self._linear(hb, "v", None, relu=False)
                hb = self._linear(hb, "us", self._bf16["h2_b"], relu=True)
            else:
                hb = self._linear(hb, "h2", self._bf16["h2_b"], relu=True)
            return self._linear(hb, "f", None, relu=False).squeeze(-1).float()
        assert self._int8 is not None
        q_w, w_scale = self._int8
        rows = h.shape[0]
        a_scale = h.amax(dim=1, keepdim=True).clamp_min_(1e-30) / 127.0
        q = torch.round(h / a_scale).to(torch.int8)
        if rows < _INT_MM_MIN_ROWS:
            q = torch.cat([q, q.new_zeros((_INT_MM_MIN_ROWS - rows, q.shape[1]))])
        acc = torch._int_mm(q, q_w)[:rows]
        z = torch.addcmul(self.h2_b, acc.float(), a_scale * w_scale)
        return (z.relu_() @ self.f_w).squeeze(-1)


def _needs_grad(*tensors: torch.Tensor) -> bool:
    return torch.is_grad_enabled() and any(t.requires_grad for t in tensors)


class FoldedShapeMlp:
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
    "INT8_ENGINES",
    "INT8_MIN_ROWS",
    "PAIR_TILE",
    "PRECISIONS",
    "FoldedGeodesicNet",
    "FoldedShapeMlp",
    "Precision",
    "fast_bfloat16",
    "int8_engine",
    "pack_int8",
    "resolve_precision",
    "runs_int8",
]
