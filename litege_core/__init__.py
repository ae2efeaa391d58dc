"""LiteGE core library: shapes, canonicalization, UDF-PCA descriptors, geodesic engines.

Pure library (numpy / scipy / trimesh / torch): no web, RPC or cache dependencies.
"""

from litege_core.errors import LiteGEError
from litege_core.io import load_shape, save_shape
from litege_core.shape import Shape, ShapeKind
from litege_core.validate import ShapeLimits

__version__ = "0.1.0"

__all__ = [
    "LiteGEError",
    "Shape",
    "ShapeKind",
    "ShapeLimits",
    "__version__",
    "load_shape",
    "save_shape",
]
