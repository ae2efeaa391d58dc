"""The distilled small head (issue 17): the folded inference form against the trainable module
evaluated pair by pair (slow reference), tiled and flat, with and without autograd."""

from __future__ import annotations

import pytest
import torch

from litege_core.errors import InputError
from litege_core.nets import FoldedGeodesicNet, GeodesicNet
from litege_core.nets.folded import BF16_MIN_ROWS, INT8_MIN_ROWS, int8_engine
from litege_core.nets.small_head import FoldedSmallHead, SmallHead

WIDTH = 32
K = 6
M, H = 12, 8


@pytest.fixture(scope="module")
def net() -> GeodesicNet:
    """A small network with non-trivial BatchNorm statistics, in eval mode."""
    torch.manual_seed(0)
    net = GeodesicNet(width=WIDTH, descriptor_dim=K)
    net.set_coord_normalization([0.0, 0.1, 0.0], [0.3, 0.2, 0.1])
    net.train()
    with torch.no_grad():
        for _ in range(5):
            points = torch.rand(256, 3) - 0.5
            net(points, points.flip(0), torch.randn(256, K), None)
    return net.eval()


@pytest.fixture(scope="module")
def student() -> SmallHead:
    torch.manual_seed(3)
    head = SmallHead(WIDTH, M, H)
    with torch.no_grad():
        head.bias.normal_(0.0, 0.5)
        head.final.bias.fill_(-0.2)  # some outputs negative before abs
    return head.eval()


@pytest.fixture(scope="module")
def setting(net, student):
    """The folded teacher and student, a shape bias and 30 + 45 canonical points."""
    teacher = FoldedGeodesicNet(net)
    folded = FoldedSmallHead(student, teacher)
    generator = torch.Generator().manual_seed(1)
    points = torch.rand(75, 3, generator=generator) - 0.5
    with torch.no_grad():
        bias = teacher.shape_bias(net.shape_embedding(torch.randn(1, K, generator=generator))[0])
    return teacher, folded, bias, points


def _naive(student: SmallHead, teacher, bias, src_points, dst_points) -> torch.Tensor:
    """Slow reference: the trainable module on teacher embeddings, one pair at a time."""
    with torch.no_grad():
        e_src = teacher.embed(src_points, bias).double()
        e_dst = teacher.embed(dst_points, bias).double()
        double = SmallHead(WIDTH, M, H).double()
        double.load_state_dict(student.state_dict())
        out = torch.empty(src_points.shape[0], dst_points.shape[0], dtype=torch.float64)
        for i in range(src_points.shape[0]):
            for j in range(dst_points.shape[0]):
                out[i, j] = double(e_src[i : i + 1], e_dst[j : j + 1])[0]
    return out.float()


@pytest.mark.parametrize("tile", [1, 7, 45, 100, 8192])
def test_tiled_pair_head_equals_the_naive_per_pair_evaluation(student, setting, tile) -> None:
    teacher, folded, bias, points = setting
    src, dst = points[:30], points[30:]
    with torch.no_grad():
        g_src = folded.point_features(src, bias)
        g_dst = folded.point_features(dst, bias)
        tiled = folded.pair_head(g_src, g_dst, tile_pairs=tile)
    assert g_src.shape == (30, M) and tiled.shape == (30, 45)
    reference = _naive(student, teacher, bias, src, dst)
    assert (reference > 0).all()
    torch.testing.assert_close(tiled, reference, rtol=1e-4, atol=1e-5)


def test_flat_head_and_autograd_path_equal_the_tiled_one(setting) -> None:
    _, folded, bias, points = setting
    src, dst = points[:30], points[30:]
    with torch.no_grad():
        g_src = folded.point_features(src, bias)
        g_dst = folded.point_features(dst, bias)
        tiled = folded.pair_head(g_src, g_dst, tile_pairs=64)
        diff = (g_src[:, None, :] - g_dst[None, :, :]).reshape(-1, M)
        flat = folded.head(diff.clone(), inplace=True).reshape(30, 45)
        plain = folded.head(diff).reshape(30, 45)
    torch.testing.assert_close(flat, tiled, rtol=1e-5, atol=1e-6)
    torch.testing.assert_close(plain, flat, rtol=0, atol=0)
    positions = dst.clone().requires_grad_(True)
    features = folded.point_features(positions, bias)
    graded = folded.pair_head(g_src, features)
    torch.testing.assert_close(graded.detach(), tiled, rtol=1e-5, atol=1e-6)
    (grad,) = torch.autograd.grad(graded.sum(), positions)
    assert grad.shape == (45, 3) and torch.isfinite(grad).all() and grad.abs().sum() > 0


def test_point_features_fold_project_embed(student, setting) -> None:
    teacher, folded, bias, points = setting
    with torch.no_grad():
        folded_features = folded.point_features(points, bias)
        unfolded = student.point_features(teacher.embed(points, bias))
    torch.testing.assert_close(folded_features, unfolded, rtol=1e-4, atol=1e-5)


def test_empty_blocks_and_softplus_output(net, setting) -> None:
    teacher, _, bias, points = setting
    head = SmallHead(WIDTH, M, H, output="softplus")
    with pytest.raises(InputError, match="does not fit"):
        FoldedSmallHead(head, teacher)  # the teacher's output is abs
    folded = FoldedSmallHead(SmallHead(WIDTH, M, H), teacher)
    with torch.no_grad():
        g = folded.point_features(points, bias)
        assert folded.pair_head(g[:0], g).shape == (0, 75)
        assert folded.pair_head(g, g[:0]).shape == (75, 0)


def test_config_round_trip_and_validation() -> None:
    head = SmallHead(WIDTH, M, H)
    again = SmallHead.from_config(head.config())
    assert (
        again.config()
        == head.config()
        == {
            "width": WIDTH,
            "features": M,
            "hidden": H,
            "output": "abs",
        }
    )
    assert head.multiply_adds() == {"per_pair": M * H + H, "per_point": WIDTH * M}
    for bad in ({"features": 0}, {"hidden": True}, {"output": "relu"}):
        with pytest.raises(InputError):
            SmallHead(WIDTH, **{"features": M, "hidden": H, **bad})
    with pytest.raises(InputError, match="does not fit"):
        FoldedSmallHead(SmallHead(WIDTH + 1, M, H), FoldedGeodesicNet(GeodesicNet(WIDTH, K)))


@pytest.mark.skipif(int8_engine() is None, reason="this torch build has no quantized engine")
def test_int8_pair_product_stays_close_on_large_blocks_only(student, setting) -> None:
    """``precision="int8"``: blocks of INT8_MIN_ROWS pairs or more run the ``m → k`` product
    in int8 (a few per cent from float32), smaller tiles and the autograd path float32."""
    teacher, folded, bias, points = setting
    int8 = FoldedSmallHead(student, teacher, precision="int8")
    src, dst = points[:30], points[30:]
    with torch.no_grad():
        g_src, g_dst = folded.point_features(src, bias), folded.point_features(dst, bias)
        want = folded.pair_head(g_src, g_dst)
        got = int8.pair_head(g_src, g_dst)  # one tile of 1350 pairs
        assert not torch.equal(got, want)
        assert (got - want).abs().mean() < 0.03 * want.abs().mean()
        diff = (g_src[:, None, :] - g_dst[None, :, :]).reshape(-1, M)
        torch.testing.assert_close(int8.head(diff.clone(), inplace=True).reshape(30, 45), got)
        small = int8.pair_head(g_src, g_dst, tile_pairs=INT8_MIN_ROWS // 2)
        torch.testing.assert_close(small, want, rtol=1e-5, atol=1e-6)
    graded = int8.pair_head(g_src, folded.point_features(dst.clone().requires_grad_(True), bias))
    torch.testing.assert_close(graded.detach(), want, rtol=1e-5, atol=1e-6)


@pytest.mark.skipif(int8_engine() is None, reason="this torch build has no quantized engine")
def test_int8_teacher_runs_the_feature_product_in_int8_where_its_point_mlp_does(
    net, student, setting
) -> None:
    """A teacher with ``embed_precision="int8"``: the student's ``n → m`` feature product runs
    int8 after the teacher's int8 point MLP (batches of INT8_MIN_ROWS points or more, no
    autograd; a few per cent from float32), and float32 exactly everywhere else."""
    _, folded, bias, _ = setting
    int8 = FoldedSmallHead(student, FoldedGeodesicNet(net, embed_precision="int8"))
    points = torch.rand(INT8_MIN_ROWS + 40, 3, generator=torch.Generator().manual_seed(4)) - 0.5
    with torch.no_grad():
        want = folded.point_features(points, bias)
        got = int8.point_features(points, bias)
        hidden = int8.teacher.hidden(points, bias)  # the teacher's int8 products alone
        assert not torch.equal(got, torch.addmm(int8.g_b, hidden, int8.g_wt))  # ran in int8
        assert (got - want).abs().mean() < 0.03 * want.abs().mean()
        assert (got - want).abs().max() < 0.1 * want.abs().max()
        small = int8.point_features(points[: INT8_MIN_ROWS - 1], bias)
        torch.testing.assert_close(small, want[: INT8_MIN_ROWS - 1], rtol=1e-5, atol=1e-6)
    traced = int8.point_features(points.clone().requires_grad_(True), bias)
    torch.testing.assert_close(traced.detach(), want, rtol=1e-5, atol=1e-6)


def test_bfloat16_teacher_runs_the_feature_product_in_bfloat16_where_its_point_mlp_does(
    net, student, setting
) -> None:
    """A teacher with ``embed_precision="bfloat16"``: the student's ``n → m`` feature product
    runs bfloat16 after the teacher's bfloat16 point MLP (CPU batches of BF16_MIN_ROWS points
    or more, no autograd; float32 features within a few per cent), and float32 exactly
    everywhere else."""
    _, folded, bias, _ = setting
    bf16 = FoldedSmallHead(student, FoldedGeodesicNet(net, embed_precision="bfloat16"))
    points = torch.rand(BF16_MIN_ROWS + 40, 3, generator=torch.Generator().manual_seed(5)) - 0.5
    with torch.no_grad():
        want = folded.point_features(points, bias)
        got = bf16.point_features(points, bias)
        hidden = bf16.teacher.hidden(points, bias)
        assert hidden.dtype == torch.bfloat16
        assert got.dtype == torch.float32 and got.shape == want.shape
        assert not torch.equal(got, torch.addmm(bf16.g_b, hidden.float(), bf16.g_wt))
        assert (got - want).abs().mean() < 0.02 * want.abs().mean()
        assert (got - want).abs().max() < 0.05 * want.abs().max()
        small = bf16.point_features(points[: BF16_MIN_ROWS - 1], bias)
        torch.testing.assert_close(small, want[: BF16_MIN_ROWS - 1], rtol=1e-5, atol=1e-6)
    traced = bf16.point_features(points.clone().requires_grad_(True), bias)
    torch.testing.assert_close(traced.detach(), want, rtol=1e-5, atol=1e-6)
