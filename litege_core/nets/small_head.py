"""A distilled small distance head (issue 17): the same per-pair convention as the trained
head of :class:`~litege_core.nets.GeodesicNet`, at a fraction of its cost per pair.

The trained head (width ``n``) evaluates, per pair, ``relu(f_s − f_d + b₁)`` → a ``2n × 2n``
product → ReLU → a dot product → ``abs``: ``4n² ≈ 160K`` multiply-adds at ``n = 200``, all of
a 1K × 1K matrix's cost. The student keeps the teacher's point embeddings ``e_p`` (``n``-d, the
output of ``project_embed``, computed once per point) and replaces the head::

    g_p   = A e_p                                   (m-d, once per point)
    out   = |w₃ · relu(W₂ relu(g_s − g_d + b₁) + b₂) + b₃|     (per pair: m·k + k mult-adds)

with ``A`` ``(m, n)``, ``W₂`` ``(k, m)``, ``w₃`` ``(k,)``. A per-point bias ``c`` in
``g_p = A e_p + c`` would cancel in ``g_s − g_d``, so the bias sits after the difference
(``b₁``), as in the teacher's first layer. The output convention (``abs`` or ``softplus``) is the
teacher's, so the predictor's residual rule (``output / 1.42 + ‖s − d‖``) applies unchanged.

Why ``e_p`` and not the teacher's head features ``f_p = W₁ e_p``: ``f_p`` is a linear image of
``e_p`` (no bias, no activation between them), so ``A' f_p`` can express nothing that ``A e_p``
cannot, and ``e_p`` is half as wide. At inference ``A`` is folded into ``project_embed``
(``g_p = (A W_e) h_p + A b_e`` with ``h_p`` the last hidden layer of the point MLP), so a point
costs ``n·m`` multiply-adds after the point MLP instead of the teacher's ``n·2n``.

:class:`SmallHead` is the trainable module (distillation: :mod:`litege_core.train.distill`);
:class:`FoldedSmallHead` its inference form on top of a :class:`FoldedGeodesicNet`, with the
same entry points as the teacher's (``point_features``, ``head``, ``pair_head``) so the
predictor can use either.
"""

from __future__ import annotations

from typing import Any

import torch
from torch import nn

from litege_core.errors import InputError
from litege_core.nets.folded import FoldedGeodesicNet, pack_int8, runs_int8
from litege_core.nets.geodesic import OUTPUT_KINDS, apply_output

SMALL_PAIR_TILE = 8192
"""Pairs per tile of :meth:`FoldedSmallHead.pair_head`: ``8192 × m`` float32 differences
(4 MB at ``m = 128``) plus ``8192 × k`` hidden activations."""


class SmallHead(nn.Module):
    """The student head (see the module docstring).

    Args:
        width: ``n``, the teacher's embedding width.
        features: ``m``, width of the student point features ``g_p``.
        hidden: ``k``, width of the hidden layer.
        output: the teacher's output convention, ``"abs"`` or ``"softplus"``.
    """

    def __init__(
        self, width: int, features: int = 128, hidden: int = 64, output: str = "abs"
    ) -> None:
        super().__init__()
        for name, value in (("width", width), ("features", features), ("hidden", hidden)):
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise InputError(f"{name} must be a positive integer, got {value!r}")
        if output not in OUTPUT_KINDS:
            raise InputError(f"output must be one of {list(OUTPUT_KINDS)}, got {output!r}")
        self.width, self.features, self.hidden_width, self.output = width, features, hidden, output
        self.point = nn.Linear(width, features, bias=False)  # A
        self.bias = nn.Parameter(torch.zeros(features))  # b₁, after the difference
        self.hidden = nn.Linear(features, hidden)  # W₂, b₂
        self.final = nn.Linear(hidden, 1)  # w₃, b₃

    def config(self) -> dict[str, Any]:
        """Constructor arguments (stored beside the weights)."""
        return {
            "width": self.width,
            "features": self.features,
            "hidden": self.hidden_width,
            "output": self.output,
        }

    @classmethod
    def from_config(cls, config: dict[str, Any]) -> SmallHead:
        return cls(
            int(config["width"]),
            int(config["features"]),
            int(config["hidden"]),
            str(config.get("output", "abs")),
        )

    def point_features(self, embeddings: torch.Tensor) -> torch.Tensor:
        """``(R, n)`` teacher point embeddings ``e_p`` → ``(R, m)`` student features ``g_p``."""
        return self.point(embeddings)

    def head(self, diff: torch.Tensor) -> torch.Tensor:
        """``(R, m)`` feature differences ``g_s − g_d`` → ``(R,)`` outputs (≥ 0)."""
        h = torch.relu(diff + self.bias)
        return apply_output(self.final(torch.relu(self.hidden(h))).squeeze(-1), self.output)

    def forward(self, src: torch.Tensor, dst: torch.Tensor) -> torch.Tensor:
        """Matched pairs of teacher embeddings ``(R, n)``, ``(R, n)`` → ``(R,)`` outputs."""
        return self.head(self.point_features(src) - self.point_features(dst))

    def multiply_adds(self) -> dict[str, int]:
        """Multiply-adds per pair (``m·k + k``, plus ``m`` subtractions) and per point
        (``n·m``, on top of the point MLP)."""
        m, k = self.features, self.hidden_width
        return {"per_pair": m * k + k, "per_point": self.width * m}


class FoldedSmallHead:
    """A :class:`SmallHead` folded onto its teacher for inference (no BatchNorm to fold: the
    student's only fold is ``A`` into the teacher's ``project_embed``).

    Entry points mirror :class:`FoldedGeodesicNet`: :meth:`point_features` ``(R, 3) → (R, m)``,
    :meth:`head` ``(R, m) → (R,)`` and :meth:`pair_head` ``(S, m), (T, m) → (S, T)``. Network
    outputs only; the predictor applies the target scale and the residual.

    Args:
        head: the trained student (its ``width`` must be the teacher's).
        teacher: the folded teacher whose point MLP the student reads.
        dtype: of the folded tensors.
        precision: arithmetic of the per-pair ``m → k`` product without autograd:
            ``"int8"`` on a CPU: the quantized engine's dynamic linear on blocks of
            :data:`~litege_core.nets.folded.INT8_MIN_ROWS` pairs or more, as the teacher's
            int8 point MLP (smaller blocks run float32); anything else, or a GPU: float32
            (the product is too small for bfloat16 to gain).

    Raises:
        InputError: the student does not fit the teacher (width or output convention).
    """

    def __init__(
        self,
        head: SmallHead,
        teacher: FoldedGeodesicNet,
        dtype: torch.dtype = torch.float32,
        precision: str = "float32",
    ) -> None:
        if head.width != teacher.width or head.output != teacher.output:
            raise InputError(
                f"small head (width {head.width}, output {head.output!r}) does not fit the "
                f"network (width {teacher.width}, output {teacher.output!r})"
            )
        self.teacher = teacher
        self.device = teacher.device
        self.output = head.output
        self.features = head.features
        self.hidden = head.hidden_width
        with torch.no_grad():
            a = head.point.weight.double()  # (m, n)
            e_w = teacher.e_wt.double().T  # (n, n), float32 fold of project_embed
            e_b = teacher.e_b.double()

            def put(t: torch.Tensor) -> torch.Tensor:
                return t.to(device=self.device, dtype=dtype).contiguous()

            self.g_wt, self.g_b = put((a @ e_w).T), put(a @ e_b)  # (n, m), (m,)
            self.b1 = put(head.bias.double())
            self.h_wt, self.h_b = put(head.hidden.weight.double().T), put(head.hidden.bias)
            self.f_w = put(head.final.weight.double()[0])  # (k,)
            self.f_b = put(head.final.bias.double()[0])
            self._packed = None
            if precision == "int8" and self.device.type == "cpu":
                self._packed = pack_int8(head.hidden.weight.double(), head.hidden.bias.double())
            # after the teacher's int8 point MLP, its n → m product goes on in int8
            self._packed_features: object | None = None
            if teacher.embed_precision == "int8":
                self._packed_features = pack_int8(a @ e_w, a @ e_b)
            # after the teacher's bfloat16 point MLP, its n → m product is bfloat16 too (the
            # bias cancels in every difference g_s − g_d, so it stays float32)
            self._g_wt_bf16 = None
            if teacher.embed_precision == "bfloat16":
                self._g_wt_bf16 = self.g_wt.to(torch.bfloat16)

    def point_features(self, points: torch.Tensor, shape_bias: torch.Tensor) -> torch.Tensor:
        """``(R, 3)`` canonical coordinates → ``(R, m)`` student features
        ``A e_p`` (through the teacher's point MLP; differentiable in ``points``; with the
        teacher's ``embed_precision="int8"`` or ``"bfloat16"``, the ``n → m`` product runs
        in that arithmetic too where its point MLP's do)."""
        hidden = self.teacher.hidden(points, shape_bias)
        if hidden.dtype == torch.bfloat16:
            assert self._g_wt_bf16 is not None  # the teacher's embed_precision says so
            return (hidden @ self._g_wt_bf16).float().add_(self.g_b)
        if runs_int8(self._packed_features, points, shape_bias):
            return torch.ops.quantized.linear_dynamic(hidden, self._packed_features, False)
        return torch.addmm(self.g_b, hidden, self.g_wt)

    def _finish(self, out: torch.Tensor) -> torch.Tensor:
        return apply_output(out + self.f_b, self.output)

    def head(self, diff: torch.Tensor, *, inplace: bool = False) -> torch.Tensor:
        """``(R, m)`` differences ``g_s − g_d`` → ``(R,)`` outputs (≥ 0); ``inplace=True``
        reuses ``diff`` as scratch memory (not with autograd)."""
        h = diff.add_(self.b1).relu_() if inplace else (diff + self.b1).relu()
        if runs_int8(self._packed, h):
            return self._finish(self._hidden_int8(h) @ self.f_w)
        h = torch.addmm(self.h_b, h, self.h_wt)
        h = h.relu_() if inplace else h.relu()
        return self._finish(h @ self.f_w)

    def _hidden_int8(self, activations: torch.Tensor) -> torch.Tensor:
        """``relu(activations · Hᵀ + h_b)`` ``(R, k)`` by the quantized engine (int8)."""
        return torch.ops.quantized.linear_relu_dynamic(activations, self._packed, False)

    def pair_head(
        self, src: torch.Tensor, dst: torch.Tensor, *, tile_pairs: int = SMALL_PAIR_TILE
    ) -> torch.Tensor:
        """Outputs of every pair: ``(S, m)`` and ``(T, m)`` → ``(S, T)``,
        ``[i, j] = head(src[i] − dst[j])``, in tiles of about ``tile_pairs`` pairs (the
        ``(S·T, m)`` differences are never materialised; the first bias is added to the sources
        once, so results equal :meth:`head` up to float32 rounding); with autograd, one
        :meth:`head` call."""
        n_src, n_dst, width = src.shape[0], dst.shape[0], src.shape[1]
        if torch.is_grad_enabled() and (src.requires_grad or dst.requires_grad):
            diff = (src[:, None, :] - dst[None, :, :]).reshape(-1, width)
            return self.head(diff).reshape(n_src, n_dst)
        out = torch.empty((n_src, n_dst), dtype=src.dtype, device=src.device)
        if out.numel() == 0:
            return out
        cols = min(n_dst, max(1, int(tile_pairs)))
        rows = min(n_src, max(1, int(tile_pairs) // cols))
        scratch = torch.empty(rows * cols * width, dtype=src.dtype, device=src.device)
        hidden = torch.empty(rows * cols * self.hidden, dtype=src.dtype, device=src.device)
        biased = src + self.b1
        for i0 in range(0, n_src, rows):
            a = biased[i0 : i0 + rows]
            for j0 in range(0, n_dst, cols):
                c = dst[j0 : j0 + cols]
                pairs = a.shape[0] * c.shape[0]
                diff = scratch[: pairs * width].view(a.shape[0], c.shape[0], width)
                torch.sub(a[:, None, :], c[None, :, :], out=diff)
                active = diff.view(pairs, width).relu_()
                if runs_int8(self._packed, active):
                    value = self._hidden_int8(active) @ self.f_w
                else:
                    h = hidden[: pairs * self.hidden].view(pairs, self.hidden)
                    value = torch.addmm(self.h_b, active, self.h_wt, out=h).relu_() @ self.f_w
                out[i0 : i0 + rows, j0 : j0 + cols] = value.view(a.shape[0], c.shape[0])
        if self.output == "abs":  # in place on the (S, T) block: no copy of it
            return out.add_(self.f_b).abs_()
        return apply_output(out.add_(self.f_b), self.output)


__all__ = ["SMALL_PAIR_TILE", "FoldedSmallHead", "SmallHead"]
