"""Reading a built geodesic dataset (template or collection kind)."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from litege_core.datasets.spec import DatasetSpec
from litege_core.datasets.storage import (
    COLLECTION_KEYS,
    SHARD_KEYS,
    TEMPLATE,
    concatenate_collection,
    read_manifest,
)
from litege_core.errors import InputError
from litege_core.files import read_tensors


class GeodesicDataset:
    """A dataset directory written by :func:`~litege_core.datasets.build.build_dataset`.

    Attributes:
        spec: the :class:`DatasetSpec` it was built from.
        kind: ``"template"`` or ``"collection"``.
        faces: ``(F, 3)`` int64 triangulation shared by every shape (``None`` for a
            collection: each shape carries its own ``faces`` / ``n_faces``).
        shared_sources: ``(R0,)`` vertex indices that are sources on every shape (``None``
            for a collection: its first ``R0`` sources are each shape's farthest points).
    """

    def __init__(self, directory: str | Path) -> None:
        self.directory = Path(directory)
        self.manifest = read_manifest(self.directory)
        self.spec = DatasetSpec.from_dict(self.manifest["spec"])
        self.kind: str = self.manifest.get("kind", "template")
        self.faces: NDArray | None = None
        self.shared_sources: NDArray | None = None
        if self.kind == "template":
            template = read_tensors(self.directory / TEMPLATE, ("faces", "shared_sources"))
            self.faces = template["faces"]
            self.shared_sources = template["shared_sources"]

    @property
    def is_collection(self) -> bool:
        return self.kind == "collection"

    @property
    def shard_keys(self) -> tuple[str, ...]:
        return COLLECTION_KEYS if self.is_collection else SHARD_KEYS

    def shard_names(self, split: str) -> list[str]:
        if split not in self.manifest["counts"]:
            raise InputError(f"unknown split {split!r}")
        return sorted(n for n, e in self.manifest["shards"].items() if e["split"] == split)

    def iter_shards(self, split: str) -> Iterator[dict[str, NDArray]]:
        """Yield each shard of ``split`` as a dict of arrays (see storage layout)."""
        for name in self.shard_names(split):
            yield read_tensors(self.directory / name, self.shard_keys)

    def load_split(self, split: str) -> dict[str, NDArray]:
        """All shards of ``split`` concatenated along the shape axis (collection shards
        re-padded to the split's largest vertex and face counts)."""
        shards = list(self.iter_shards(split))
        if not shards:
            raise InputError(f"split {split!r} of {self.directory} is empty")
        if self.is_collection:
            return concatenate_collection(shards)
        return {key: np.concatenate([s[key] for s in shards]) for key in SHARD_KEYS}


def shape_mesh(
    arrays: dict[str, NDArray], index: int, faces: NDArray | None = None
) -> tuple[NDArray, NDArray]:
    """``(vertices (V_s, 3) float64, faces (F_s, 3) int64)`` of shape ``index`` of a loaded
    split: unpadded for a collection split (``arrays`` has ``n_vertices``), else the shape's
    vertices on the shared ``faces``."""
    vertices = np.asarray(arrays["vertices"][index], dtype=np.float64)
    if "n_vertices" in arrays:
        n_v, n_f = int(arrays["n_vertices"][index]), int(arrays["n_faces"][index])
        return vertices[:n_v], np.asarray(arrays["faces"][index][:n_f], dtype=np.int64)
    if faces is None:
        raise InputError("a template split needs the dataset's shared faces")
    return vertices, np.asarray(faces, dtype=np.int64)


__all__ = [
    "GeodesicDataset",
    "shape_mesh",
]
