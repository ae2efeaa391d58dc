"""The learned-geodesic model: a bundle, the predictor that serves it, and paths.

::

    ModelBundle (bundle.py)  ──►  Predictor (predictor.py)  ──►  GeodesicPath (paths.py)
      manifest, basis, net         register → ShapeState          gradient walk on the
                                   (state.py: ShapeRecord,        predicted distance
                                   ShapeState, ResolvedPoints)
    describe.py: shape → canonical frame + UDF-PCA descriptor (+ OOD residual)

It builds on ``canonical``, ``descriptor``, ``nets`` (the folded network), ``projection`` and
``query`` below it, and is used by ``matching``, ``train``, ``evaluation``, the CLI and the
service above it.
"""

from litege_core.learned.bundle import (
    DEFAULT_MODEL,
    ModelBundle,
    PipelineConfig,
    load_bundle,
    load_shipped,
    save_bundle,
    shipped_bundles,
)
from litege_core.learned.describe import ShapeDescription, describe_shape, shape_samples
from litege_core.learned.paths import GeodesicPath, trace_path, trace_paths
from litege_core.learned.predictor import Predictor
from litege_core.learned.state import OOD_Z_THRESHOLD, ResolvedPoints, ShapeRecord, ShapeState

__all__ = [
    "DEFAULT_MODEL",
    "OOD_Z_THRESHOLD",
    "GeodesicPath",
    "ModelBundle",
    "PipelineConfig",
    "Predictor",
    "ResolvedPoints",
    "ShapeDescription",
    "ShapeRecord",
    "ShapeState",
    "describe_shape",
    "load_bundle",
    "load_shipped",
    "save_bundle",
    "shape_samples",
    "shipped_bundles",
    "trace_path",
    "trace_paths",
]
