"""Ground-truth geodesic datasets (build, store, read): procedural families sharing one
triangulation (template kind) and collections of shapes with their own triangulations."""

from litege_core.datasets.build import (
    CollectionFactory,
    ShapeFactory,
    build_dataset,
    exact_distance_rows,
    verify_dataset,
)
from litege_core.datasets.collection import build_collection_dataset, folder_spec
from litege_core.datasets.reader import GeodesicDataset, shape_mesh
from litege_core.datasets.spec import DatasetSpec, collection_preset, preset

__all__ = [
    "CollectionFactory",
    "DatasetSpec",
    "GeodesicDataset",
    "ShapeFactory",
    "build_collection_dataset",
    "build_dataset",
    "collection_preset",
    "exact_distance_rows",
    "folder_spec",
    "preset",
    "shape_mesh",
    "verify_dataset",
]
