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

Shards are written to a temporary name and renamed, and the manifest is rewritten after each
shard, so an interrupted build resumes from the last complete shard. No pickle anywhere.
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from litege_core.errors import ArtifactError

MANIFEST = "manifest.json"
TEMPLATE = "template.safetensors"
SHARD_KEYS = ("vertices", "sources", "distances", "area", "seed", "family")


def shard_name(split: str, index: int) -> str:
    return f"{split}-{index:05d}.safetensors"


def file_sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def write_tensors_atomic(path: Path, tensors: dict[str, NDArray]) -> str:
    """Write ``tensors`` to ``path`` via a temporary file; return the file's SHA-256."""
    from safetensors.numpy import save_file

    temporary = path.with_suffix(path.suffix + ".tmp")
    save_file({k: np.ascontiguousarray(v) for k, v in tensors.items()}, str(temporary))
    os.replace(temporary, path)
    return file_sha256(path)


def read_tensors(path: Path, keys: tuple[str, ...] | None = None) -> dict[str, NDArray]:
    """Read a safetensors file (optionally only ``keys``), raising ArtifactError on damage."""
    from safetensors import SafetensorError
    from safetensors.numpy import load_file

    try:
        tensors = load_file(str(path))
    except (SafetensorError, OSError, ValueError) as exc:
        raise ArtifactError(f"cannot read {path.name}: {exc}") from exc
    if keys is not None:
        missing = set(keys) - set(tensors)
        if missing:
            raise ArtifactError(f"{path.name} lacks tensors {sorted(missing)}")
        tensors = {k: tensors[k] for k in keys}
    return tensors


def write_json_atomic(path: Path, data: dict) -> None:
    temporary = path.with_suffix(path.suffix + ".tmp")
    temporary.write_text(json.dumps(data, indent=2, sort_keys=True) + "\n")
    os.replace(temporary, path)


def read_manifest(directory: Path) -> dict:
    path = Path(directory) / MANIFEST
    try:
        return json.loads(path.read_text())
    except FileNotFoundError as exc:
        raise ArtifactError(f"no {MANIFEST} in {directory}") from exc
    except json.JSONDecodeError as exc:
        raise ArtifactError(f"{path} is not valid JSON: {exc}") from exc
