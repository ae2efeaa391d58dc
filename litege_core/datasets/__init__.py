"""Ground-truth geodesic datasets of procedural shape families (build, store, read)."""

from litege_core.datasets.build import (
    ShapeFactory,
    build_dataset,
    exact_distance_rows,
    verify_dataset,
)
from litege_core.datasets.reader import GeodesicDataset
from litege_core.datasets.spec import DatasetSpec, preset

__all__ = [
    "DatasetSpec",
    "GeodesicDataset",
    "ShapeFactory",
    "build_dataset",
    "exact_distance_rows",
    "preset",
    "verify_dataset",
]
