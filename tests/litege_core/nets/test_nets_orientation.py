"""OrientationNet and its density grids (litege_core.nets.orientation)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from litege_core.errors import ArrayShapeError, InputError
from litege_core.nets.orientation import N_TURNS, OrientationNet, density_grids
from litege_core.nets.tnet import CUBE_ROTATIONS


def _cloud(seed: int = 0, n: int = 300) -> torch.Tensor:
    rng = np.random.default_rng(seed)
    return torch.from_numpy(rng.normal(size=(2, n, 3)) * [0.3, 0.5, 1.0] + [0.2, -0.1, 0.4])


def test_grids_sum_to_one_and_ignore_scale_and_centre() -> None:
    points = _cloud()
    grids = density_grids(points, grid=8)
    assert grids.shape == (2, 1, 8, 8, 8)
    assert torch.allclose(grids.sum(dim=(1, 2, 3, 4)), torch.ones(2), atol=1e-5)
    moved = density_grids(points * 3.7 + torch.tensor([5.0, -2.0, 1.0]), grid=8)
    assert torch.allclose(grids, moved, atol=1e-5)


@pytest.mark.parametrize("turn", [1, 5, 13, 23])
def test_a_cube_turn_of_the_cloud_permutes_the_grid(turn: int) -> None:
    """The cells are symmetric about the centre, so ``points @ K`` has the grid of ``points``
    with its axes permuted and flipped as ``K`` says."""
    points = _cloud(1)
    K = CUBE_ROTATIONS[turn]
    turned = density_grids(points @ K, grid=10)[:, 0]
    plain = density_grids(points, grid=10)[:, 0]
    # new coordinate j = Σ_i p_i K_ij: axis j of the turned grid is axis i of the plain one
    order = [int(torch.nonzero(K[:, j]).item()) for j in range(3)]
    expected = plain.permute(0, *(1 + a for a in order))
    flips = [1 + j for j in range(3) if K[order[j], j] < 0]
    expected = expected.flip(flips) if flips else expected
    assert torch.allclose(turned, expected, atol=1e-5)


def test_network_outputs_and_config_round_trip() -> None:
    torch.manual_seed(0)
    net = OrientationNet(grid=8, conv_widths=(4, 8), fc_width=16).eval()
    logits = net(_cloud().float())
    assert logits.shape == (2, N_TURNS)
    log_p = net.canonical_log_probability(_cloud().float())
    assert log_p.shape == (2,) and bool((log_p <= 0).all())
    copy = OrientationNet.from_config(net.config())
    assert copy.config() == net.config()


@pytest.mark.parametrize(
    "config",
    [{"grid": 6, "conv_widths": [4, 8]}, {"extent": 0.0}, {"conv_widths": []}, {"width": 3}],
)
def test_bad_configs_are_input_errors(config: dict) -> None:
    with pytest.raises(InputError):
        OrientationNet.from_config(config)


def test_bad_points_are_shape_errors() -> None:
    with pytest.raises(ArrayShapeError):
        density_grids(torch.zeros(5, 3))
