"""Reading a built geodesic dataset."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from litege_core.datasets.spec import DatasetSpec
from litege_core.datasets.storage import SHARD_KEYS, TEMPLATE, read_manifest, read_tensors
from litege_core.errors import InputError


class GeodesicDataset:
    """A dataset directory written by :func:`~litege_core.datasets.build.build_dataset`.

    Attributes:
        spec: the :class:`DatasetSpec` it was built from.
        faces: ``(F, 3)`` int64 triangulation shared by every shape.
        shared_sources: ``(R0,)`` vertex indices that are sources on every shape.
    """

    def __init__(self, directory: str | Path) -> None:
        self.directory = Path(directory)
        self.manifest = read_manifest(self.directory)
        self.spec = DatasetSpec.from_dict(self.manifest["spec"])
        template = read_tensors(self.directory / TEMPLATE, ("faces", "shared_sources"))
        self.faces: NDArray = template["faces"]
        self.shared_sources: NDArray = template["shared_sources"]

    def shard_names(self, split: str) -> list[str]:
        if split not in self.manifest["counts"]:
            raise InputError(f"unknown split {split!r}")
        return sorted(n for n, e in self.manifest["shards"].items() if e["split"] == split)

    def iter_shards(self, split: str) -> Iterator[dict[str, NDArray]]:
        """Yield each shard of ``split`` as a dict of arrays (see storage layout)."""
        for name in self.shard_names(split):
            yield read_tensors(self.directory / name, SHARD_KEYS)

    def load_split(self, split: str) -> dict[str, NDArray]:
        """All shards of ``split`` concatenated along the shape axis."""
        shards = list(self.iter_shards(split))
        if not shards:
            raise InputError(f"split {split!r} of {self.directory} is empty")
        return {key: np.concatenate([s[key] for s in shards]) for key in SHARD_KEYS}
