"""The learned-geodesic model: a bundle, the predictor that serves it, and paths.

::

    ModelBundle (bundle.py)  ──►  Predictor (predictor.py)  ──►  GeodesicPath (paths.py)
      manifest, basis, net         register → ShapeState          gradient walk on the
                                   (state.py: ShapeRecord,        predicted distance
                                   ShapeState, ResolvedPoints)
    describe.py: shape → canonical frame + UDF-PCA descriptor (+ OOD residual)
    manifest.py: the bundle directory format (torch-free)
    numpy_predictor.py: NumpyPredictor, a torch-free CPU runtime of the same model (CLI)

It builds on ``canonical``, ``descriptor``, ``nets`` (the folded network), ``projection`` and
``query`` below it, and is used by ``matching``, ``train``, ``evaluation``, the CLI and the
service above it.
"""

from importlib import import_module
from typing import TYPE_CHECKING

_EXPORTS: dict[str, str] = {
    "DEFAULT_MODEL": "manifest",
    "PipelineConfig": "manifest",
    "shipped_bundles": "manifest",
    "ModelBundle": "bundle",
    "load_bundle": "bundle",
    "load_model": "bundle",
    "load_shipped": "bundle",
    "save_bundle": "bundle",
    "ShapeDescription": "describe",
    "describe_shape": "describe",
    "shape_samples": "describe",
    "GeodesicPath": "paths",
    "trace_path": "paths",
    "trace_paths": "paths",
    "Predictor": "predictor",
    "NumpyPredictor": "numpy_predictor",
    "OOD_Z_THRESHOLD": "state",
    "ResolvedPoints": "state",
    "ShapeRecord": "state",
    "ShapeState": "state",
}
"""Public name → submodule. Imported on first access (PEP 562), so that importing one
torch-free submodule (``manifest``, ``numpy_predictor``) does not import torch through this
package."""


def __getattr__(name: str) -> object:
    if name in _EXPORTS:
        return getattr(import_module(f"{__name__}.{_EXPORTS[name]}"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


if TYPE_CHECKING:
    from litege_core.learned.bundle import (
        ModelBundle,
        load_bundle,
        load_model,
        load_shipped,
        save_bundle,
    )
    from litege_core.learned.describe import ShapeDescription, describe_shape, shape_samples
    from litege_core.learned.manifest import DEFAULT_MODEL, PipelineConfig, shipped_bundles
    from litege_core.learned.numpy_predictor import NumpyPredictor
    from litege_core.learned.paths import GeodesicPath, trace_path, trace_paths
    from litege_core.learned.predictor import Predictor
    from litege_core.learned.state import (
        OOD_Z_THRESHOLD,
        ResolvedPoints,
        ShapeRecord,
        ShapeState,
    )

__all__ = [
    "DEFAULT_MODEL",
    "OOD_Z_THRESHOLD",
    "GeodesicPath",
    "ModelBundle",
    "NumpyPredictor",
    "PipelineConfig",
    "Predictor",
    "ResolvedPoints",
    "ShapeDescription",
    "ShapeRecord",
    "ShapeState",
    "describe_shape",
    "load_bundle",
    "load_model",
    "load_shipped",
    "save_bundle",
    "shape_samples",
    "shipped_bundles",
    "trace_path",
    "trace_paths",
]
