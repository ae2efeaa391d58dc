"""T-Net, the 6D rotation representation, the rotation angle and the T-Net loss."""

import json
import math

import pytest
import torch
from scipy.spatial.transform import Rotation
from torch import nn

from litege_core.errors import ArrayShapeError, EmptyShapeError, InputError
from litege_core.nets import (
    POINT_LOSS_WEIGHT,
    TNet,
    align_points,
    load_state,
    rotate_points,
    rotation_angle,
    rotation_from_6d,
    state_to_tensors,
    tnet_loss,
)
from litege_core.nets.rotation import ANGLE_CLAMP_EPS
from litege_core.nets.tnet import (
    CUBE_ROTATIONS,
    REFERENCE_CONV_WIDTHS,
    REFERENCE_FC_WIDTHS,
    pca_frames,
)


def random_rotations(n: int, seed: int = 0) -> torch.Tensor:
    return torch.as_tensor(Rotation.random(n, random_state=seed).as_matrix())


def z_rotation(angle: float) -> torch.Tensor:
    c, s = math.cos(angle), math.sin(angle)
    return torch.tensor([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]], dtype=torch.float64)


# --------------------------------------------------------------------------- 6D → rotation


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_rotation_from_6d_gives_proper_rotations(dtype: torch.dtype) -> None:
    torch.manual_seed(0)
    v = torch.randn(4, 50, 6, dtype=dtype) * 3
    R = rotation_from_6d(v)
    assert R.shape == (4, 50, 3, 3) and R.dtype == dtype
    eye = torch.eye(3, dtype=dtype).expand_as(R)
    # The +1e-8 in each norm shortens a column by 1e-8/|v| relative: not exactly unit.
    tol = 1e-5 if dtype == torch.float32 else 1e-6
    torch.testing.assert_close(R.transpose(-1, -2) @ R, eye, atol=tol, rtol=0)
    torch.testing.assert_close(torch.linalg.det(R), torch.ones(4, 50, dtype=dtype))


def test_rotation_from_6d_is_gram_schmidt_with_columns() -> None:
    v = torch.tensor([[2.0, 0.0, 0.0, 5.0, 3.0, 0.0]], dtype=torch.float64)
    R = rotation_from_6d(v)[0]
    # u1 = x, u2 = y (the x part of v2 removed), u3 = z; as columns: the identity.
    torch.testing.assert_close(R, torch.eye(3, dtype=torch.float64))
    # Columns, not rows: the first column is v1 normalized.
    v = torch.tensor([[0.0, 3.0, 4.0, 1.0, 0.0, 0.0]], dtype=torch.float64)
    R = rotation_from_6d(v)[0]
    torch.testing.assert_close(R[:, 0], torch.tensor([0.0, 0.6, 0.8], dtype=torch.float64))
    torch.testing.assert_close(R[:, 1], torch.tensor([1.0, 0.0, 0.0], dtype=torch.float64))


def test_rotation_from_6d_recovers_a_rotation_from_its_first_two_columns() -> None:
    R = random_rotations(8, seed=1)
    v = torch.cat((R[..., 0], R[..., 1]), dim=-1)
    torch.testing.assert_close(rotation_from_6d(v), R)


def test_rotation_from_6d_rejects_bad_shapes() -> None:
    with pytest.raises(ArrayShapeError):
        rotation_from_6d(torch.randn(4, 5))


# --------------------------------------------------------------------------- angle


def test_rotation_angle_of_known_rotations() -> None:
    eye = torch.eye(3, dtype=torch.float64)
    for angle in (0.1, 0.7, 2.0, 3.0):
        measured = rotation_angle(z_rotation(angle), eye)
        assert float(measured) == pytest.approx(angle, abs=1e-9)
    # Invariant under a common change of frame, symmetric, batched.
    Q = random_rotations(5, seed=2)
    A = Q @ z_rotation(0.5)
    torch.testing.assert_close(rotation_angle(A, Q), torch.full((5,), 0.5, dtype=torch.float64))
    torch.testing.assert_close(rotation_angle(Q, A), rotation_angle(A, Q))


def test_rotation_angle_clamp_floor_and_exact_zero() -> None:
    R = random_rotations(3, seed=3)
    floor = math.acos(1 - ANGLE_CLAMP_EPS)
    torch.testing.assert_close(rotation_angle(R, R), torch.full((3,), floor, dtype=torch.float64))
    assert float(rotation_angle(R, R, eps=0.0).max()) < 1e-6
    with pytest.raises(ArrayShapeError):
        rotation_angle(torch.eye(3), torch.eye(2))


def test_rotate_then_align_is_the_identity() -> None:
    R = random_rotations(2, seed=4)
    points = torch.randn(2, 30, 3, dtype=torch.float64)
    rotated = rotate_points(points, R)
    torch.testing.assert_close(rotated[0, 0], R[0] @ points[0, 0])  # each point becomes R p
    torch.testing.assert_close(align_points(rotated, R), points)


# --------------------------------------------------------------------------- loss


def test_loss_vanishes_for_the_true_rotation() -> None:
    R = random_rotations(4, seed=5)
    canonical = torch.randn(4, 100, 3, dtype=torch.float64)
    rotated = rotate_points(canonical, R)
    exact = tnet_loss(R, R, canonical, rotated, eps=0.0)
    assert float(exact.total) < 1e-6
    assert float(exact.point) < 1e-12
    torch.testing.assert_close(align_points(rotated, R), canonical)
    # With the default clamp the angle term has the documented floor.
    default = tnet_loss(R, R, canonical, rotated)
    assert float(default.angle) == pytest.approx(math.acos(1 - ANGLE_CLAMP_EPS), rel=1e-6)


def test_loss_terms_for_a_known_error() -> None:
    canonical = torch.tensor([[[1.0, 0.0, 0.0], [0.0, 0.0, 2.0]]], dtype=torch.float64)
    R_gt = torch.eye(3, dtype=torch.float64)[None]
    R_pred = z_rotation(math.pi / 2)[None]
    loss = tnet_loss(R_pred, R_gt, canonical, rotate_points(canonical, R_gt))
    # aligned = canonical @ R_z: (1,0,0) -> (0,-1,0), distance √2; (0,0,2) is on the axis.
    assert float(loss.angle) == pytest.approx(math.pi / 2, abs=1e-9)
    assert float(loss.point) == pytest.approx(math.sqrt(2) / 2)
    assert float(loss.total) == pytest.approx(math.pi / 2 + POINT_LOSS_WEIGHT * math.sqrt(2) / 2)
    weighted = tnet_loss(R_pred, R_gt, canonical, canonical, point_weight=0.0)
    assert float(weighted.total) == pytest.approx(math.pi / 2, abs=1e-9)


def test_loss_rejects_mismatched_shapes() -> None:
    R = random_rotations(2)
    with pytest.raises(ArrayShapeError):
        tnet_loss(R, R, torch.randn(2, 5, 3), torch.randn(2, 6, 3))
    with pytest.raises(ArrayShapeError):
        tnet_loss(R, R[:1], torch.randn(2, 5, 3), torch.randn(2, 5, 3))


# --------------------------------------------------------------------------- network


def test_tnet_output_shape_for_variable_point_counts() -> None:
    torch.manual_seed(0)
    net = TNet().eval()
    with torch.no_grad():
        for n_points in (1, 17, 300):
            assert net(torch.randn(2, n_points, 3)).shape == (2, 6)
        single = torch.randn(1, 250, 3)
        R = net.rotation(single)
        aligned, R_again = net.align(single)
    assert R.shape == (1, 3, 3)
    torch.testing.assert_close(R, R_again)
    torch.testing.assert_close(R[0].T @ R[0], torch.eye(3), atol=1e-5, rtol=0)
    torch.testing.assert_close(aligned, single @ R)


def test_tnet_is_invariant_to_point_order_in_eval_mode() -> None:
    torch.manual_seed(1)
    net = TNet().eval()
    cloud = torch.randn(1, 64, 3)
    with torch.no_grad():
        torch.testing.assert_close(net(cloud), net(cloud[:, torch.randperm(64)]))


def test_tnet_layout() -> None:
    net = TNet()
    convs = [
        (m.in_channels, m.out_channels) for m in net.modules() if isinstance(m, torch.nn.Conv1d)
    ]
    linears = [
        (m.in_features, m.out_features) for m in net.modules() if isinstance(m, torch.nn.Linear)
    ]
    assert convs == [(3, 128), (128, 512), (512, 2048)]
    assert all(m.kernel_size == (1,) for m in net.modules() if isinstance(m, torch.nn.Conv1d))
    assert linears == [(2048, 512), (512, 128), (128, 6)]
    assert sum(isinstance(m, torch.nn.BatchNorm1d) for m in net.modules()) == 5


def test_tnet_trains_one_step() -> None:
    torch.manual_seed(2)
    net = TNet().train()
    R_gt = random_rotations(4, seed=6).float()
    canonical = torch.randn(4, 32, 3)
    rotated = rotate_points(canonical, R_gt)
    loss = tnet_loss(net.rotation(rotated), R_gt, canonical, rotated)
    loss.total.backward()
    grads = [p.grad for p in net.parameters()]
    assert all(g is not None and torch.isfinite(g).all() for g in grads)
    assert float(net.point_mlp[0].weight.grad.abs().sum()) > 0


def test_tnet_rejects_bad_input() -> None:
    net = TNet().eval()
    with pytest.raises(ArrayShapeError):
        net(torch.randn(10, 3))
    with pytest.raises(ArrayShapeError):
        net(torch.randn(1, 10, 2))
    with pytest.raises(EmptyShapeError):
        net(torch.randn(1, 0, 3))


# --------------------------------------------------------------------------- widths / config


def _conv_reference(net: TNet, points: torch.Tensor) -> torch.Tensor:
    """The textbook PointNet evaluation: Conv1d on (B, C, N), max over N."""
    return net.fc(net.point_mlp(points.transpose(1, 2)).amax(dim=2))


@pytest.mark.parametrize("mode", ["train", "eval"])
def test_tnet_linear_evaluation_equals_conv1d(mode: str) -> None:
    torch.manual_seed(3)
    net = TNet((8, 16, 32), (16, 8))
    net.train()
    with torch.no_grad():
        net(torch.randn(4, 50, 3))  # non-trivial running statistics
    getattr(net, mode)()
    cloud = torch.randn(3, 41, 3)
    with torch.no_grad():
        torch.testing.assert_close(net(cloud), _conv_reference(net, cloud), atol=1e-5, rtol=1e-5)


def test_tnet_custom_widths_layout_and_config_round_trip() -> None:
    net = TNet(conv_widths=(16, 32, 64), fc_widths=(32, 16))
    convs = [(m.in_channels, m.out_channels) for m in net.modules() if isinstance(m, nn.Conv1d)]
    linears = [(m.in_features, m.out_features) for m in net.modules() if isinstance(m, nn.Linear)]
    assert convs == [(3, 16), (16, 32), (32, 64)]
    assert linears == [(64, 32), (32, 16), (16, 6)]
    assert net.config() == {"conv_widths": [16, 32, 64], "fc_widths": [32, 16], "prealign": "none"}
    assert json.loads(json.dumps(net.config())) == net.config()
    again = TNet.from_config(net.config())
    assert again.config() == net.config()
    load_state(again, state_to_tensors(net))  # same layout: strict load works


def test_tnet_default_config_is_the_reference() -> None:
    assert TNet().config() == {
        "conv_widths": list(REFERENCE_CONV_WIDTHS),
        "fc_widths": list(REFERENCE_FC_WIDTHS),
        "prealign": "none",
    }
    assert REFERENCE_CONV_WIDTHS == (128, 512, 2048) and REFERENCE_FC_WIDTHS == (512, 128)
    assert TNet.from_config({"fc_widths": [8]}).conv_widths == REFERENCE_CONV_WIDTHS


def test_tnet_without_fc_hidden_layers() -> None:
    net = TNet((8,), ()).eval()
    assert [type(m) for m in net.fc] == [nn.Linear]
    with torch.no_grad():
        assert net(torch.randn(2, 10, 3)).shape == (2, 6)


@pytest.mark.parametrize(
    "config",
    [
        {"conv_widths": []},
        {"conv_widths": [8, 0]},
        {"conv_widths": [8, -1]},
        {"conv_widths": [8, 2.5]},
        {"conv_widths": [True]},
        {"conv_widths": "64"},
        {"fc_widths": 16},
        {"widths": [8]},
        {"prealign": "svd"},
    ],
)
def test_tnet_config_validation(config: dict) -> None:
    with pytest.raises(InputError):
        TNet.from_config(config)


def test_tnet_from_config_needs_a_dict() -> None:
    with pytest.raises(InputError):
        TNet.from_config([64, 128])  # type: ignore[arg-type]


# --------------------------------------------------------------------------- PCA pre-alignment


def _asymmetric_cloud(n: int = 400, seed: int = 0) -> torch.Tensor:
    """Anisotropic, skewed along the first two principal axes (stable PCA signs)."""
    g = torch.Generator().manual_seed(seed)
    x = torch.randn(n, 3, generator=g, dtype=torch.float64) * torch.tensor([3.0, 1.5, 0.5])
    x[:, 0] += 0.4 * x[:, 0].abs() ** 1.5
    x[:, 1] += 0.3 * x[:, 1].abs() ** 1.5
    return x - x.mean(dim=0)


def test_pca_frames_are_proper_and_rotation_equivariant() -> None:
    cloud = _asymmetric_cloud()[None].expand(5, -1, -1)
    R = random_rotations(5, seed=7)
    frames = pca_frames(rotate_points(cloud, R))
    eye = torch.eye(3, dtype=torch.float64).expand(5, 3, 3)
    torch.testing.assert_close(frames.transpose(1, 2) @ frames, eye)
    torch.testing.assert_close(torch.linalg.det(frames), torch.ones(5, dtype=torch.float64))
    # The frame turns with the cloud: Q(X Rᵀ) = R Q(X), so (X Rᵀ) Q(X Rᵀ) = X Q(X).
    torch.testing.assert_close(frames, R @ pca_frames(cloud))
    # Variances along the frame axes decrease; third moments of a0, a1 are positive.
    aligned = rotate_points(cloud, R) @ frames
    variances = aligned.var(dim=1)
    assert bool(
        (variances[:, 0] > variances[:, 1]).all() and (variances[:, 1] > variances[:, 2]).all()
    )
    assert bool(((aligned[..., :2] ** 3).sum(dim=1) > 0).all())


def test_prealigned_tnet_keeps_the_rotation_contract() -> None:
    torch.manual_seed(4)
    net = TNet((8, 16), (8,), prealign="pca").eval()
    assert net.config()["prealign"] == "pca"
    cloud = _asymmetric_cloud().float()[None].expand(3, -1, -1)
    R_gt = random_rotations(3, seed=8).float()
    rotated = rotate_points(cloud, R_gt)
    with torch.no_grad():
        frames = pca_frames(rotated)
        expected = frames @ rotation_from_6d(net(rotated @ frames))
        R_pred = net.rotation(rotated)
        aligned, again = net.align(rotated)
    torch.testing.assert_close(R_pred, expected)
    torch.testing.assert_close(again, R_pred)
    torch.testing.assert_close(aligned, rotated @ R_pred)
    # The prediction only depends on the cloud's shape, not its orientation: rotating the
    # input rotates R_pred with it (R_pred(X Sᵀ) = S R_pred(X)), up to float32 round-off.
    S = random_rotations(1, seed=9).float()
    with torch.no_grad():
        turned = net.rotation(rotate_points(rotated, S))
    torch.testing.assert_close(turned, S @ R_pred, atol=1e-4, rtol=0)


def test_prealigned_tnet_learns_a_fixed_orientation_quickly() -> None:
    """With PCA pre-alignment one rigid shape under random rotations is solved in a few steps."""
    torch.manual_seed(5)
    net = TNet((16, 32), (16,), prealign="pca").train()
    optimizer = torch.optim.Adam(net.parameters(), lr=1e-2)
    cloud = _asymmetric_cloud(200).float()
    losses = []
    for step in range(40):
        R_gt = random_rotations(8, seed=100 + step).float()
        canonical = cloud[None].expand(8, -1, -1)
        rotated = rotate_points(canonical, R_gt)
        loss = tnet_loss(net.rotation(rotated), R_gt, canonical, rotated)
        optimizer.zero_grad()
        loss.total.backward()
        optimizer.step()
        losses.append(float(loss.angle.detach()))
    assert sum(losses[-5:]) / 5 < 0.3 < losses[0]


def test_cube_rotations_are_the_24_proper_signed_permutations() -> None:
    assert CUBE_ROTATIONS.shape == (24, 3, 3)
    eye = torch.eye(3, dtype=torch.float64)
    torch.testing.assert_close(
        CUBE_ROTATIONS.transpose(1, 2) @ CUBE_ROTATIONS, eye.expand(24, 3, 3)
    )
    torch.testing.assert_close(
        torch.linalg.det(CUBE_ROTATIONS), torch.ones(24, dtype=torch.float64)
    )
    assert len({tuple(m.flatten().tolist()) for m in CUBE_ROTATIONS}) == 24


def test_rotation_with_explicit_frames() -> None:
    torch.manual_seed(6)
    net = TNet((8, 16), (8,), prealign="pca").eval()
    cloud = _asymmetric_cloud().float()[None].expand(2, -1, -1)
    frames = pca_frames(cloud) @ CUBE_ROTATIONS[[3, 17]].float()
    with torch.no_grad():
        R = net.rotation(cloud, frames)
        expected = frames @ rotation_from_6d(net(cloud @ frames))
    torch.testing.assert_close(R, expected)
    with pytest.raises(ArrayShapeError):
        net.rotation(cloud, frames[:1])
    with pytest.raises(InputError):
        TNet((8,), ()).rotation(cloud, frames)
