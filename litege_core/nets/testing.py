"""An untrained :class:`~litege_core.nets.GeodesicNet` with non-trivial BatchNorm statistics,
for tests of everything that folds or re-implements the network (the folded network, the
predictors, the torch-free runtime): with the default statistics (mean 0, variance 1, scale 1,
shift 0) folding BatchNorm would be an identity and its mistakes would go unseen."""

from __future__ import annotations

import torch

from litege_core.nets.geodesic import GeodesicNet, OutputKind


def random_geodesic_net(
    width: int, descriptor_dim: int, *, output: OutputKind = "abs", seed: int = 0
) -> GeodesicNet:
    """A ``width``-wide net for ``descriptor_dim``-d descriptors in eval mode, deterministic
    for ``seed``: random weights, random BatchNorm running statistics and affine parameters,
    and a coordinate z-score other than the identity."""
    torch.manual_seed(seed)
    net = GeodesicNet(width=width, descriptor_dim=descriptor_dim, output=output)
    net.set_coord_normalization([0.1, -0.05, 0.02], [0.45, 0.25, 0.12])
    with torch.no_grad():
        for module in net.modules():
            if isinstance(module, torch.nn.BatchNorm1d):
                assert module.running_mean is not None and module.running_var is not None
                module.running_mean.normal_(0.0, 0.3)
                module.running_var.uniform_(0.5, 2.0)
                module.weight.normal_(1.0, 0.2)
                module.bias.normal_(0.0, 0.2)
    return net.eval()


__all__ = ["random_geodesic_net"]
