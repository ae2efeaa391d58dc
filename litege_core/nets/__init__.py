"""Networks of LiteGE: the geodesic / matching network and the T-Net (reference-spec §1.6, §3).

* :class:`GeodesicNet` — the distance network; :func:`matching_net` builds the matching
  variant. Coordinates go in raw (canonical units); the z-score is a buffer of the network.
* :data:`TARGET_SCALE` and the helpers :func:`residual_target`, :func:`geodesic_from_residual`,
  :func:`matching_target`, :func:`geodesic_from_output`, :func:`predict_geodesic` — the one
  place where the legacy factor 1.42 is applied.
* :class:`TNet`, :func:`tnet_loss`, :func:`rotation_from_6d`, :func:`rotation_angle`,
  :func:`rotate_points`, :func:`align_points` — orientation for the matching pipeline.
* :class:`FoldedGeodesicNet`, :class:`FoldedShapeMlp` — the trained network folded into affine
  maps for inference.
* :func:`state_to_tensors` / :func:`load_state` — weights as flat tensor dicts (for bundles).
"""

from litege_core.nets.folded import FoldedGeodesicNet, FoldedShapeMlp
from litege_core.nets.geodesic import (
    MATCHING_DESCRIPTOR_DIM,
    MATCHING_WIDTH,
    REGRESSION_DESCRIPTOR_DIM,
    REGRESSION_WIDTH,
    TARGET_SCALE,
    GeodesicNet,
    OutputKind,
    geodesic_from_output,
    geodesic_from_residual,
    matching_net,
    matching_target,
    predict_geodesic,
    residual_target,
)
from litege_core.nets.rotation import (
    align_points,
    rotate_points,
    rotation_angle,
    rotation_from_6d,
)
from litege_core.nets.state import load_state, state_to_tensors
from litege_core.nets.tnet import POINT_LOSS_WEIGHT, TNet, TNetLoss, tnet_loss

__all__ = [
    "MATCHING_DESCRIPTOR_DIM",
    "MATCHING_WIDTH",
    "POINT_LOSS_WEIGHT",
    "REGRESSION_DESCRIPTOR_DIM",
    "REGRESSION_WIDTH",
    "TARGET_SCALE",
    "FoldedGeodesicNet",
    "FoldedShapeMlp",
    "GeodesicNet",
    "OutputKind",
    "TNet",
    "TNetLoss",
    "align_points",
    "geodesic_from_output",
    "geodesic_from_residual",
    "load_state",
    "matching_net",
    "matching_target",
    "predict_geodesic",
    "residual_target",
    "rotate_points",
    "rotation_angle",
    "rotation_from_6d",
    "state_to_tensors",
    "tnet_loss",
]
