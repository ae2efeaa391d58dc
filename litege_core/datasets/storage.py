"""On-disk layout of a geodesic dataset: safetensors shards plus a JSON manifest.

::

    DIR/manifest.json             spec, generator version, counts, seeds, shard hashes, timings
    DIR/template.safetensors      faces (F, 3) int64 shared by every shape; shared sources (R0,)
    DIR/{split}-{i:05d}.safetensors
        vertices   (S, V, 3) float32
        sources    (S, R)    int32      first R0 columns are the shared sources
        distances  (S, R, V) float16 (train) / float32 (val, test), raw shape units
        area       (S,)      float64    surface area (rescale distances by 1/sqrt(area))
        seed       (S,)      int64
        family     (S,)      int64      index into spec.families

**Collection datasets** (manifest ``"kind": "collection"``, ``format_version`` 2) hold shapes
with their own vertex counts and triangulations. There is no template file; each shard pads
its shapes to the shard's largest vertex / face count ``Vs`` / ``Fs``::

    DIR/{split}-{i:05d}.safetensors
        vertices    (S, Vs, 3) float32    rows ≥ n_vertices[s] are 0
        faces       (S, Fs, 3) int32      rows ≥ n_faces[s] are -1
        n_vertices  (S,)       int64
        n_faces     (S,)       int64
        sources     (S, R)     int32      first R0 columns: farthest-point samples of the shape
        distances   (S, R, Vs) float16 (train) / float32 (val, test); columns ≥ n_vertices are 0
        area, seed, family     as above

Readers concatenate shards along the shape axis, re-padding to the split's largest counts.
Padding keeps every array rectangular, so training gathers by index exactly as for template
datasets and only has to draw targets below ``n_vertices[s]``.

Shards are written to a temporary name and renamed, and the manifest is rewritten after each
shard, so an interrupted build resumes from the last complete shard. No pickle anywhere.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from litege_core.errors import ArtifactError
from litege_core.files import read_json_object

MANIFEST = "manifest.json"
TEMPLATE = "template.safetensors"
SHARD_KEYS = ("vertices", "sources", "distances", "area", "seed", "family")
COLLECTION_KEYS = (*SHARD_KEYS, "faces", "n_vertices", "n_faces")
FACE_PAD = -1
"""Value of the padding rows of a collection shard's ``faces``."""


def pad_axis(array: NDArray, size: int, axis: int, value: float = 0) -> NDArray:
    """``array`` padded with ``value`` at the end of ``axis`` to length ``size``."""
    missing = size - array.shape[axis]
    if missing < 0:
        raise ValueError("cannot pad to a smaller size")
    if missing == 0:
        return array
    widths = [(0, 0)] * array.ndim
    widths[axis] = (0, missing)
    return np.pad(array, widths, constant_values=value)


def concatenate_collection(shards: list[dict[str, NDArray]]) -> dict[str, NDArray]:
    """Concatenate collection shards (or splits) along the shape axis, re-padding vertices,
    faces and distances to the largest counts."""
    n_v = max(s["vertices"].shape[1] for s in shards)
    n_f = max(s["faces"].shape[1] for s in shards)
    padded = {
        "vertices": [pad_axis(s["vertices"], n_v, 1) for s in shards],
        "distances": [pad_axis(s["distances"], n_v, 2) for s in shards],
        "faces": [pad_axis(s["faces"], n_f, 1, FACE_PAD) for s in shards],
    }
    return {
        key: np.concatenate(padded[key] if key in padded else [s[key] for s in shards])
        for key in COLLECTION_KEYS
    }


def shard_name(split: str, index: int) -> str:
    return f"{split}-{index:05d}.safetensors"


def read_manifest(directory: Path) -> dict:
    """The ``manifest.json`` object of a dataset directory.

    Raises:
        ArtifactError: no manifest (or ``directory`` is not a directory), or one that is not
            a readable JSON object.
    """
    path = Path(directory) / MANIFEST
    if not path.exists():  # also when ``directory`` is a file
        raise ArtifactError(f"no {MANIFEST} in {directory}")
    return read_json_object(path, str(path))


__all__ = [
    "COLLECTION_KEYS",
    "FACE_PAD",
    "MANIFEST",
    "SHARD_KEYS",
    "TEMPLATE",
    "concatenate_collection",
    "pad_axis",
    "read_manifest",
    "shard_name",
]
