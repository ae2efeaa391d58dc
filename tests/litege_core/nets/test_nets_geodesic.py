"""GeodesicNet: architecture, entry-point equivalence, normalization chain rule, target scale."""

import numpy as np
import pytest
import torch

from litege_core.errors import ArrayShapeError, EmptyShapeError, InputError, NonFiniteError
from litege_core.nets import (
    TARGET_SCALE,
    GeodesicNet,
    geodesic_from_output,
    geodesic_from_residual,
    matching_net,
    matching_target,
    predict_geodesic,
    residual_target,
)

# Regression constants of the reference (SMAL), spec §1 table: a strongly anisotropic std.
MEAN = [0.084522, -0.080156, -3.92e-5]
STD = [0.312628, 0.189539, 0.076368]


def n_parameters(module: torch.nn.Module) -> int:
    return sum(p.numel() for p in module.parameters())


def eval_net(
    width: int = 200,
    descriptor_dim: int = 240,
    output: str = "abs",
    dtype: torch.dtype = torch.float32,
    seed: int = 0,
) -> GeodesicNet:
    """An eval-mode net whose BatchNorm layers are not the identity (random running stats)."""
    torch.manual_seed(seed)
    net = GeodesicNet(width, descriptor_dim, output).to(dtype)
    net.set_coord_normalization(MEAN, STD)
    with torch.no_grad():
        for module in net.modules():
            if isinstance(module, torch.nn.BatchNorm1d):
                module.running_mean.uniform_(-0.2, 0.2)
                module.running_var.uniform_(0.5, 2.0)
                module.weight.uniform_(0.5, 1.5)
                module.bias.uniform_(-0.1, 0.1)
    return net.eval()


def canonical_points(*shape: int, dtype: torch.dtype = torch.float32) -> torch.Tensor:
    """Random points spread like canonical coordinates (mean MEAN, std STD)."""
    return torch.randn(*shape, 3, dtype=dtype) * torch.tensor(STD, dtype=dtype) + torch.tensor(
        MEAN, dtype=dtype
    )


# --------------------------------------------------------------------------- architecture


def test_regression_parameter_count_is_the_reference_613801() -> None:
    assert n_parameters(GeodesicNet(200, 240)) == 613_801
    assert n_parameters(GeodesicNet()) == 613_801


def test_matching_parameter_count_is_the_reference_2411601() -> None:
    net = matching_net()
    assert (net.width, net.descriptor_dim) == (400, 400)
    assert n_parameters(net) == 2_411_601
    assert n_parameters(GeodesicNet(400, 400)) == 2_411_601


def test_layer_layout_matches_the_spec_table() -> None:
    net = GeodesicNet(8, 5)
    linears = {
        name: (m.in_features, m.out_features, m.bias is not None)
        for name, m in net.named_modules()
        if isinstance(m, torch.nn.Linear)
    }
    assert linears == {
        "mlp_coord.0": (3, 8, False),
        "mlp_coord.3": (8, 8, False),
        "mlp_pca.0": (5, 8, False),
        "mlp_pca.3": (8, 8, False),
        "mlp_pca.6": (8, 8, False),
        "project_down_pcacoord": (16, 8, True),
        "mlp_pcacoord.0": (8, 8, False),
        "mlp_pcacoord.3": (8, 8, False),
        "project_embed": (8, 8, True),
        "final_layers.0": (8, 16, False),
        "final_layers.3": (16, 16, False),
        "final_linear": (16, 1, True),
    }
    # Every bias-free Linear is followed by BatchNorm1d and ReLU (a BN-block).
    for seq in (net.mlp_coord, net.mlp_pca, net.mlp_pcacoord, net.final_layers):
        kinds = [type(m) for m in seq]
        assert kinds == [torch.nn.Linear, torch.nn.BatchNorm1d, torch.nn.ReLU] * (len(seq) // 3)


def test_fusion_puts_the_shape_embedding_first() -> None:
    net = eval_net(8, 5)
    src, dst = canonical_points(4), canonical_points(4)
    desc = torch.randn(4, 5)
    with torch.no_grad():
        # Zero the coordinate half of the fusion layer: the output must stop depending on xyz.
        net.project_down_pcacoord.weight[:, 8:] = 0.0
        out = net(src, dst, desc)
        moved = net(src + 1.0, dst - 1.0, desc)
    torch.testing.assert_close(out, moved)


def test_normalization_buffers_are_state_not_parameters() -> None:
    net = GeodesicNet()
    names = {name for name, _ in net.named_parameters()}
    assert "coord_mean" not in names and "coord_std" not in names
    state = net.state_dict()
    assert state["coord_mean"].shape == (3,) and state["coord_std"].shape == (3,)
    torch.testing.assert_close(net.coord_mean, torch.zeros(3))
    torch.testing.assert_close(net.coord_std, torch.ones(3))


def test_init_is_deterministic_under_manual_seed() -> None:
    torch.manual_seed(123)
    a = GeodesicNet(16, 7)
    torch.manual_seed(123)
    b = GeodesicNet(16, 7)
    torch.manual_seed(124)
    c = GeodesicNet(16, 7)
    for (name, x), y in zip(a.state_dict().items(), b.state_dict().values(), strict=True):
        assert torch.equal(x, y), name
    assert not torch.equal(a.final_linear.weight, c.final_linear.weight)


def test_config_round_trip_and_bad_arguments() -> None:
    net = GeodesicNet(12, 9, "softplus")
    assert net.config() == {"width": 12, "descriptor_dim": 9, "output": "softplus"}
    again = GeodesicNet.from_config(net.config())
    assert again.config() == net.config()
    with pytest.raises(InputError):
        GeodesicNet(output="relu")  # type: ignore[arg-type]
    with pytest.raises(InputError):
        GeodesicNet(width=0)
    with pytest.raises(InputError):
        GeodesicNet.from_config({"width": 3, "depth": 2})


# --------------------------------------------------------------------------- entry points


@pytest.mark.parametrize("output", ["abs", "softplus"])
def test_all_entry_points_equal_forward_in_eval_mode(output: str) -> None:
    net = eval_net(output=output)
    S, Pa, Pb, K = 2, 5, 4, 3
    desc = torch.randn(S, 240)
    a, b = canonical_points(S, Pa), canonical_points(S, Pb)
    with torch.no_grad():
        emb = net.shape_embedding(desc)  # (S, n)
        assert emb.shape == (S, 200)

        # Reference: forward on every (s, i, j) pair, flattened.
        src = a[:, :, None, :].expand(S, Pa, Pb, 3).reshape(-1, 3)
        dst = b[:, None, :, :].expand(S, Pa, Pb, 3).reshape(-1, 3)
        d = desc[:, None, None, :].expand(S, Pa, Pb, 240).reshape(-1, 240)
        reference = net(src, dst, d, d).reshape(S, Pa, Pb)
        assert (net(src, dst, d).reshape(S, Pa, Pb) == reference).all()  # desc_dst=None

        e_a, e_b = net.point_embedding(a, emb), net.point_embedding(b, emb)
        assert e_a.shape == (S, Pa, 200) and e_b.shape == (S, Pb, 200)
        via_head = net.head(e_a[:, :, None], e_b[:, None])
        pairwise = net.pairwise(a, b, emb, emb)
        distance = net.distance(a[:, :, None], b[:, None], emb[:, None, None])
        for result in (via_head, pairwise, distance):
            assert result.shape == (S, Pa, Pb)
            torch.testing.assert_close(result, reference, rtol=1e-5, atol=1e-5)

        # gathered: candidate k of source q is b[:, (q + k) % Pb].
        index = (torch.arange(Pa)[:, None] + torch.arange(K)[None, :]) % Pb  # (Pa, K)
        candidates = b[:, index]  # (S, Pa, K, 3)
        gathered = net.gathered(a, candidates, emb)
        assert gathered.shape == (S, Pa, K)
        expected = torch.gather(reference, 2, index.expand(S, Pa, K))
        torch.testing.assert_close(gathered, expected, rtol=1e-5, atol=1e-5)


def test_matching_entry_points_with_two_descriptors() -> None:
    net = eval_net(16, 11)
    S, Pa, Pb = 3, 4, 6
    desc_x, desc_y = torch.randn(S, 11), torch.randn(S, 11)
    a, b = canonical_points(S, Pa), canonical_points(S, Pb)
    with torch.no_grad():
        emb_x, emb_y = net.shape_embedding(desc_x), net.shape_embedding(desc_y)
        src = a[:, :, None, :].expand(S, Pa, Pb, 3).reshape(-1, 3)
        dst = b[:, None, :, :].expand(S, Pa, Pb, 3).reshape(-1, 3)
        dx = desc_x[:, None, None].expand(S, Pa, Pb, 11).reshape(-1, 11)
        dy = desc_y[:, None, None].expand(S, Pa, Pb, 11).reshape(-1, 11)
        reference = net(src, dst, dx, dy).reshape(S, Pa, Pb)
        torch.testing.assert_close(
            net.pairwise(a, b, emb_x, emb_y), reference, rtol=1e-5, atol=1e-5
        )
        gathered = net.gathered(a, b[:, None].expand(S, Pa, Pb, 3), emb_x, emb_y)
        torch.testing.assert_close(gathered, reference, rtol=1e-5, atol=1e-5)
        # The shape embedding matters: swapping the descriptors changes the answer.
        assert not torch.allclose(net.pairwise(a, b, emb_y, emb_x), reference)


def test_shape_embedding_accepts_extra_batch_dims() -> None:
    net = eval_net(16, 11)
    desc = torch.randn(2, 3, 11)
    with torch.no_grad():
        torch.testing.assert_close(
            net.shape_embedding(desc), net.shape_embedding(desc.reshape(6, 11)).reshape(2, 3, 16)
        )


def test_symmetric_flag_averages_both_directions() -> None:
    net = eval_net(16, 11)
    emb = net.shape_embedding(torch.randn(1, 11)).detach()
    a, b = canonical_points(1, 5), canonical_points(1, 4)
    with torch.no_grad():
        forward = net.pairwise(a, b, emb)
        backward = net.pairwise(b, a, emb).transpose(1, 2)
        assert not torch.allclose(forward, backward)  # the network is not symmetric
        symmetric = net.pairwise(a, b, emb, symmetric=True)
        torch.testing.assert_close(symmetric, 0.5 * (forward + backward))
        square = net.pairwise(a, a, emb, symmetric=True)
        torch.testing.assert_close(square, square.transpose(1, 2))
        cand = b[:, None].expand(1, 5, 4, 3)
        torch.testing.assert_close(net.gathered(a, cand, emb, symmetric=True), symmetric)
        dist = net.distance(a[0, :, None], b[0, None], emb[0], symmetric=True)
        torch.testing.assert_close(dist, symmetric[0])


def test_training_forward_normalizes_over_stacked_rows() -> None:
    torch.manual_seed(0)
    net = GeodesicNet(8, 5).train()
    net.set_coord_normalization(MEAN, STD)
    coord_bn, shape_bn = net.mlp_coord[1], net.mlp_pca[1]
    coord_bn.momentum = shape_bn.momentum = 1.0  # running stats := the last batch stats
    B = 6
    src, dst = canonical_points(B), canonical_points(B)
    desc_a, desc_b = torch.randn(B, 5), torch.randn(B, 5)
    net(src, dst, desc_a)
    stacked = net.normalize_coords(torch.cat((src, dst)))  # (2B, 3)
    with torch.no_grad():
        torch.testing.assert_close(coord_bn.running_mean, net.mlp_coord[0](stacked).mean(0))
        torch.testing.assert_close(shape_bn.running_mean, net.mlp_pca[0](desc_a).mean(0))
        net(src, dst, desc_a, desc_b)  # the shape MLP runs on each descriptor set alone
        torch.testing.assert_close(shape_bn.running_mean, net.mlp_pca[0](desc_b).mean(0))


@pytest.mark.parametrize("output", ["abs", "softplus"])
@pytest.mark.parametrize("train", [True, False])
def test_output_is_non_negative(output: str, train: bool) -> None:
    net = eval_net(16, 11, output=output).train(train)
    torch.manual_seed(3)
    out = net(canonical_points(64) * 5, canonical_points(64) * 5, torch.randn(64, 11) * 10)
    assert out.shape == (64,)
    assert (out >= 0).all()
    if output == "softplus":
        assert (out > 0).all()


# --------------------------------------------------------------------------- normalization


def test_normalization_is_applied_inside_the_network() -> None:
    net = eval_net(16, 11)
    identity = eval_net(16, 11)
    identity.set_coord_normalization([0, 0, 0], [1, 1, 1])
    src, dst, desc = canonical_points(7), canonical_points(7), torch.randn(7, 11)
    mean, std = torch.tensor(MEAN), torch.tensor(STD)
    with torch.no_grad():
        torch.testing.assert_close(
            net(src, dst, desc), identity((src - mean) / std, (dst - mean) / std, desc)
        )


def test_fit_coord_normalization_uses_the_population_std() -> None:
    rng = np.random.default_rng(0)
    points = rng.normal(MEAN, STD, size=(2, 500, 3))
    net = GeodesicNet(8, 5)
    mean, std = net.fit_coord_normalization(points)
    np.testing.assert_allclose(mean, points.reshape(-1, 3).mean(0))
    np.testing.assert_allclose(std, points.reshape(-1, 3).std(0, ddof=0))
    torch.testing.assert_close(net.coord_std, torch.tensor(std, dtype=torch.float32))
    net.fit_coord_normalization(torch.as_tensor(points))  # tensors are accepted too
    torch.testing.assert_close(net.coord_mean, torch.tensor(mean, dtype=torch.float32))


def test_set_coord_normalization_rejects_bad_values() -> None:
    net = GeodesicNet(8, 5)
    with pytest.raises(ArrayShapeError):
        net.set_coord_normalization([0, 0], [1, 1, 1])
    with pytest.raises(InputError):
        net.set_coord_normalization([0, 0, 0], [1, 0, 1])
    with pytest.raises(NonFiniteError):
        net.set_coord_normalization([0, np.nan, 0], [1, 1, 1])
    with pytest.raises(ArrayShapeError):
        net.set_coord_normalization("abc", [1, 1, 1])
    with pytest.raises(EmptyShapeError):
        net.fit_coord_normalization(np.zeros((1, 3)))
    torch.testing.assert_close(net.coord_std, torch.ones(3))  # nothing was half-set


def test_destination_gradient_flows_through_the_normalization() -> None:
    """Guards the authors' chain-rule bug (spec §6): d/dp_canonical = d/dp_normalized / std."""
    net = eval_net(32, 11, dtype=torch.float64)
    torch.manual_seed(5)
    emb = net.shape_embedding(torch.randn(1, 11, dtype=torch.float64)).detach()[0]
    src = canonical_points(4, dtype=torch.float64)
    dst = canonical_points(4, dtype=torch.float64).requires_grad_(True)

    for residual in (True, False):
        (grad,) = torch.autograd.grad(
            predict_geodesic(net, src, dst, emb, residual=residual).sum(), dst
        )
        h = 1e-6
        finite_difference = torch.zeros_like(grad)
        with torch.no_grad():
            for axis in range(3):
                step = torch.zeros(3, dtype=torch.float64)
                step[axis] = h
                plus = predict_geodesic(net, src, dst + step, emb, residual=residual)
                minus = predict_geodesic(net, src, dst - step, emb, residual=residual)
                finite_difference[:, axis] = (plus - minus) / (2 * h)
        torch.testing.assert_close(grad, finite_difference, rtol=1e-5, atol=1e-7)

    # The reference's conversion (gradient w.r.t. the normalized input, times std) is off by
    # std² per axis: far from the true gradient with this anisotropic std.
    dst_n = net.normalize_coords(dst.detach()).requires_grad_(True)
    identity = eval_net(32, 11, dtype=torch.float64)
    identity.load_state_dict(net.state_dict())
    identity.set_coord_normalization([0, 0, 0], [1, 1, 1])
    (grad_n,) = torch.autograd.grad(
        identity.distance(net.normalize_coords(src), dst_n, emb).sum(), dst_n
    )
    std = torch.tensor(STD, dtype=torch.float64)
    (grad_output,) = torch.autograd.grad(net.distance(src, dst, emb).sum(), dst)
    torch.testing.assert_close(grad_n / std, grad_output)
    assert not torch.allclose(grad_n * std, grad_output, rtol=0.1)


# --------------------------------------------------------------------------- target scale


def test_residual_target_and_prediction_round_trip() -> None:
    geodesic = torch.tensor([1.0, 0.5, 0.3])
    euclidean = torch.tensor([0.4, 0.5, 0.31])
    target = residual_target(geodesic, euclidean)
    torch.testing.assert_close(target, torch.tensor([1.42 * 0.6, 0.0, 0.0]))
    unclipped = residual_target(geodesic, euclidean, clip=False)
    assert unclipped[2] < 0
    torch.testing.assert_close(geodesic_from_residual(unclipped, euclidean), geodesic)
    np.testing.assert_allclose(
        residual_target(np.array([2.0, 0.1]), np.array([1.0, 0.2])), [1.42, 0.0]
    )
    assert geodesic_from_residual(1.42, 1.0) == pytest.approx(2.0)
    assert TARGET_SCALE == 1.42


def test_matching_target_and_prediction() -> None:
    target = matching_target(torch.tensor([1.0]), torch.tensor([2.0]))
    torch.testing.assert_close(target, torch.tensor([1.42 * 1.5]))
    torch.testing.assert_close(geodesic_from_output(target), torch.tensor([1.5]))


def test_predict_geodesic_applies_the_scale_once() -> None:
    net = eval_net(16, 11)
    emb = net.shape_embedding(torch.randn(1, 11)).detach()[0]
    src, dst = canonical_points(5), canonical_points(5)
    with torch.no_grad():
        raw = net.distance(src, dst, emb)
        euclid = (src - dst).norm(dim=-1)
        torch.testing.assert_close(predict_geodesic(net, src, dst, emb), raw / 1.42 + euclid)
        torch.testing.assert_close(
            predict_geodesic(net, src, dst, emb, emb, residual=False), raw / 1.42
        )


# --------------------------------------------------------------------------- validation


def test_bad_shapes_raise_array_shape_errors() -> None:
    net = eval_net(16, 11)
    p3, d = canonical_points(4), torch.randn(4, 11)
    emb = torch.randn(2, 16)
    with pytest.raises(ArrayShapeError):
        net(torch.randn(4, 2), p3, d)
    with pytest.raises(ArrayShapeError):
        net(p3, canonical_points(5), d)
    with pytest.raises(ArrayShapeError):
        net(p3, p3, torch.randn(4, 12))
    with pytest.raises(ArrayShapeError):
        net(p3, p3, d, torch.randn(3, 11))
    with pytest.raises(ArrayShapeError):
        net.shape_embedding(torch.randn(2, 10))
    with pytest.raises(ArrayShapeError):
        net.point_embedding(torch.randn(3), emb)
    with pytest.raises(ArrayShapeError):
        net.point_embedding(canonical_points(3, 5), emb)  # 3 shapes, 2 embeddings
    with pytest.raises(ArrayShapeError):
        net.head(torch.randn(3, 16), torch.randn(4, 16))
    with pytest.raises(ArrayShapeError):
        net.pairwise(canonical_points(5), canonical_points(2, 5), emb)
    with pytest.raises(ArrayShapeError):
        net.gathered(canonical_points(2, 5), canonical_points(2, 4, 3), emb)
    with pytest.raises(ArrayShapeError):
        net.pairwise(canonical_points(2, 5), canonical_points(2, 5), torch.randn(2, 15))
    with pytest.raises(InputError):
        net(p3.numpy(), p3, d)  # type: ignore[arg-type]


def test_float64_inputs_are_cast_to_the_network_dtype() -> None:
    net = eval_net(16, 11)
    src, dst, desc = canonical_points(3), canonical_points(3), torch.randn(3, 11)
    with torch.no_grad():
        out = net(src.double(), dst.double(), desc.double())
    assert out.dtype == torch.float32
    torch.testing.assert_close(out, net(src, dst, desc).detach())
