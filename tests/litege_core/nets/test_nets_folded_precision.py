"""FoldedGeodesicNet: the tiled all-pairs head and the reduced-precision / low-rank options
(issue 17), each against the float32 folding and the network's own forward."""

from __future__ import annotations

import pytest
import torch

from litege_core.errors import InputError
from litege_core.nets import FoldedGeodesicNet, GeodesicNet
from litege_core.nets.folded import (
    BF16_MIN_ROWS,
    INT8_MIN_ROWS,
    PRECISIONS,
    fast_bfloat16,
    int8_engine,
    resolve_precision,
)

WIDTH = 32
K = 12


@pytest.fixture(scope="module")
def net() -> GeodesicNet:
    """A small network with non-trivial BatchNorm statistics, in eval mode."""
    torch.manual_seed(0)
    net = GeodesicNet(width=WIDTH, descriptor_dim=K)
    net.set_coord_normalization([0.0, 0.1, 0.0], [0.3, 0.2, 0.1])
    net.train()
    with torch.no_grad():  # a few training-mode passes give the BatchNorms running statistics
        for _ in range(5):
            points = torch.rand(256, 3) - 0.5
            net(points, points.flip(0), torch.randn(256, K), None)
    return net.eval()


@pytest.fixture(scope="module")
def inputs(net: GeodesicNet) -> tuple[torch.Tensor, torch.Tensor]:
    """Head features of 40 sources and 70 targets on one shape."""
    folded = FoldedGeodesicNet(net)
    generator = torch.Generator().manual_seed(1)
    points = torch.rand(110, 3, generator=generator) - 0.5
    with torch.no_grad():
        bias = folded.shape_bias(net.shape_embedding(torch.randn(1, K, generator=generator))[0])
        features = folded.features(folded.embed(points, bias))
    return features[:40], features[40:]


def _all_pairs(folded: FoldedGeodesicNet, src: torch.Tensor, dst: torch.Tensor) -> torch.Tensor:
    diff = (src[:, None, :] - dst[None, :, :]).reshape(-1, src.shape[1])
    with torch.no_grad():
        return folded.head(diff).reshape(src.shape[0], dst.shape[0])


@pytest.mark.parametrize("tile", [1, 7, 40, 69, 2048])
def test_pair_head_is_the_head_on_every_difference(net, inputs, tile) -> None:
    folded = FoldedGeodesicNet(net)
    src, dst = inputs
    with torch.no_grad():
        got = folded.pair_head(src, dst, tile_pairs=tile)
    assert got.shape == (40, 70) and got.dtype == torch.float32
    # the same operations; only the matrix kernel's rounding may differ with the row count
    torch.testing.assert_close(got, _all_pairs(folded, src, dst), rtol=1e-6, atol=1e-7)


def test_pair_head_with_autograd_and_empty_inputs(net, inputs) -> None:
    folded = FoldedGeodesicNet(net, precision="bfloat16")
    src, dst = inputs
    src = src[:3].clone().requires_grad_(True)
    out = folded.pair_head(src, dst[:5])
    assert out.requires_grad and out.shape == (3, 5)
    (grad,) = torch.autograd.grad(out.sum(), src)
    assert torch.isfinite(grad).all()
    reference = FoldedGeodesicNet(net)  # with autograd every precision runs float32
    torch.testing.assert_close(out.detach(), _all_pairs(reference, src.detach(), dst[:5]))
    with torch.no_grad():
        assert folded.pair_head(src[:0], dst).shape == (0, 70)


@pytest.mark.parametrize("precision", ["bfloat16", "int8"])
def test_reduced_precision_head_stays_close_to_float32(net, inputs, precision) -> None:
    src, dst = inputs
    exact = _all_pairs(FoldedGeodesicNet(net), src, dst)
    folded = FoldedGeodesicNet(net, precision=precision)
    reduced = _all_pairs(folded, src, dst)
    with torch.no_grad():
        tiled = folded.pair_head(src, dst, tile_pairs=64)
    scale = exact.abs().mean()
    # bfloat16 keeps 8 significant bits, int8 7: well under 2 % of the typical output
    assert (reduced - exact).abs().mean() < 0.01 * scale
    assert (reduced - exact).abs().max() < 0.05 * scale
    torch.testing.assert_close(tiled, reduced, rtol=1e-2, atol=1e-2 * float(scale))
    assert (reduced >= 0).all()


def test_bfloat16_embeddings_stay_close_to_float32(net) -> None:
    exact = FoldedGeodesicNet(net)
    folded = FoldedGeodesicNet(net, embed_precision="bfloat16")
    points = torch.rand(300, 3) - 0.5
    with torch.no_grad():
        bias = exact.shape_bias(net.shape_embedding(torch.randn(1, K))[0])
        want = exact.features(exact.embed(points, bias))
        got = folded.features(folded.embed(points, bias))
    assert got.dtype == torch.float32
    assert (got - want).abs().max() < 0.02 * want.abs().max()
    # with autograd the float32 path runs (the path tracer's gradient)
    positions = points[:4].clone().requires_grad_(True)
    grad_features = folded.features(folded.embed(positions, bias))
    torch.testing.assert_close(grad_features.detach(), want[:4], rtol=1e-5, atol=1e-5)


def test_bfloat16_point_mlp_stays_close_to_float32_on_large_batches_only(net) -> None:
    """The bfloat16 point MLP answers every entry point within a few per cent of float32
    (the hidden layer in bfloat16, embeddings and head features float32) on a CPU batch of
    BF16_MIN_ROWS points or more without autograd; smaller batches run float32, exactly."""
    exact = FoldedGeodesicNet(net)
    folded = FoldedGeodesicNet(net, embed_precision="bfloat16")
    points = torch.rand(BF16_MIN_ROWS + 50, 3, generator=torch.Generator().manual_seed(3)) - 0.5
    with torch.no_grad():
        bias = exact.shape_bias(net.shape_embedding(torch.randn(1, K))[0])
        for method in ("hidden", "embed", "point_features"):
            want = getattr(exact, method)(points, bias)
            got = getattr(folded, method)(points, bias)
            kept = torch.bfloat16 if method != "point_features" else torch.float32
            assert got.dtype == kept and got.shape == want.shape, method
            got = got.float()
            assert (got - want).abs().mean() < 0.02 * want.abs().mean(), method
            assert (got - want).abs().max() < 0.05 * want.abs().max(), method
            small = getattr(folded, method)(points[: BF16_MIN_ROWS - 1], bias)
            assert small.dtype == torch.float32, method
            torch.testing.assert_close(small, want[: BF16_MIN_ROWS - 1], rtol=1e-5, atol=1e-6)
    positions = points.clone().requires_grad_(True)  # the path tracer's gradient: float32
    traced = folded.point_features(positions, bias)
    torch.testing.assert_close(traced.detach(), exact.point_features(points, bias))


@pytest.mark.skipif(int8_engine() is None, reason="this torch build has no quantized engine")
def test_int8_point_mlp_stays_close_to_float32_on_large_batches_only(net) -> None:
    """The int8 point MLP answers every entry point (hidden layer, embeddings, head
    features) within a few per cent of float32, and runs only where it pays: batches of
    INT8_MIN_ROWS points or more, without autograd; elsewhere the float32 path, exactly."""
    exact = FoldedGeodesicNet(net)
    folded = FoldedGeodesicNet(net, embed_precision="int8")
    points = torch.rand(INT8_MIN_ROWS + 88, 3, generator=torch.Generator().manual_seed(2)) - 0.5
    with torch.no_grad():
        bias = exact.shape_bias(net.shape_embedding(torch.randn(1, K))[0])
        for method in ("hidden", "embed", "point_features"):
            want = getattr(exact, method)(points, bias)
            got = getattr(folded, method)(points, bias)
            assert got.dtype == torch.float32 and got.shape == want.shape
            assert not torch.equal(got, want), method  # the int8 products ran
            assert (got - want).abs().mean() < 0.03 * want.abs().mean(), method
            assert (got - want).abs().max() < 0.1 * want.abs().max(), method
            small = getattr(folded, method)(points[: INT8_MIN_ROWS - 1], bias)
            torch.testing.assert_close(small, want[: INT8_MIN_ROWS - 1], rtol=1e-5, atol=1e-6)
    positions = points.clone().requires_grad_(True)  # the path tracer's gradient: float32
    traced = folded.point_features(positions, bias)
    torch.testing.assert_close(traced.detach(), exact.point_features(points, bias))
    traced.sum().backward()
    assert positions.grad is not None and torch.isfinite(positions.grad).all()


def test_full_rank_head_equals_the_trained_head_and_low_rank_is_the_svd(net, inputs) -> None:
    src, dst = inputs
    exact = _all_pairs(FoldedGeodesicNet(net), src, dst)
    full = _all_pairs(FoldedGeodesicNet(net, head_rank=2 * WIDTH), src, dst)
    torch.testing.assert_close(full, exact, rtol=1e-4, atol=1e-4 * float(exact.abs().max()))
    small = FoldedGeodesicNet(net, head_rank=5)
    v, us = small._low_rank  # type: ignore[misc]
    assert v.shape == (2 * WIDTH, 5) and us.shape == (5, 2 * WIDTH)
    assert torch.linalg.matrix_rank(v @ us) == 5
    # the truncation is the best rank-5 approximation of the folded product
    reference = FoldedGeodesicNet(net).h2_wt  # (in, out)
    u, s, vh = torch.linalg.svd(reference.double())
    best = (u[:, :5] * s[:5]) @ vh[:5]
    torch.testing.assert_close((v @ us).double(), best, rtol=1e-4, atol=1e-5)


def test_options_are_checked(net) -> None:
    with pytest.raises(InputError):
        FoldedGeodesicNet(net, precision="float16")
    with pytest.raises(InputError):
        FoldedGeodesicNet(net, embed_precision="float16")
    with pytest.raises(InputError, match="CPU only"):  # checked before anything moves
        FoldedGeodesicNet(net, "cuda", embed_precision="int8")
    for rank in (0, 2 * WIDTH + 1, True):
        with pytest.raises(InputError):
            FoldedGeodesicNet(net, head_rank=rank)
    assert resolve_precision("auto") in PRECISIONS[:2]
    assert resolve_precision("auto") == ("bfloat16" if fast_bfloat16() else "float32")
    assert resolve_precision("int8") == "int8"
    with pytest.raises(InputError):
        resolve_precision("fp8")


def test_point_features_fold_the_embedding_into_the_features(net) -> None:
    folded = FoldedGeodesicNet(net)
    points = torch.rand(200, 3) - 0.5
    bias = folded.shape_bias(net.shape_embedding(torch.randn(1, K))[0]).detach()
    with torch.no_grad():
        want = folded.features(folded.embed(points, bias))
        got = folded.point_features(points, bias)
    torch.testing.assert_close(got, want, rtol=1e-5, atol=1e-5 * float(want.abs().max()))
    positions = points[:5].clone().requires_grad_(True)
    (grad,) = torch.autograd.grad(folded.point_features(positions, bias).sum(), positions)
    reference = positions.detach().clone().requires_grad_(True)
    (expected,) = torch.autograd.grad(
        folded.features(folded.embed(reference, bias)).sum(), reference
    )
    torch.testing.assert_close(grad, expected, rtol=1e-4, atol=1e-4)


def test_low_rank_head_in_bfloat16_stays_close_to_its_float32(net, inputs) -> None:
    src, dst = inputs
    exact = _all_pairs(FoldedGeodesicNet(net, head_rank=20), src, dst)
    reduced = _all_pairs(FoldedGeodesicNet(net, head_rank=20, precision="bfloat16"), src, dst)
    assert (reduced - exact).abs().mean() < 0.02 * exact.abs().mean()
