"""Files written so that a reader never sees half of one: atomic JSON and safetensors writes,
content hashes, and JSON and safetensors reads that report damage as :class:`ArtifactError`;
output directories made with an :class:`InputError` when the path cannot be one.

Shared by datasets (shards, manifests) and model bundles (manifests, weights).
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from litege_core.errors import ArtifactError, InputError


def file_sha256(path: Path) -> str:
    """Hex SHA-256 of a file's bytes (read in 1 MiB blocks)."""
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def make_directory(path: str | os.PathLike, what: str = "output directory") -> Path:
    """Create directory ``path`` (and its parents) unless it exists; return it as a Path.

    Raises:
        InputError: it cannot be created (a file is in the way, no permission, ...).
    """
    directory = Path(path)
    try:
        directory.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"cannot create {what} {directory}: {exc.strerror or exc}") from exc
    return directory


def read_json_object(path: Path, what: str) -> dict:
    """The JSON object in ``path``; ``what`` names the file in errors.

    Raises:
        ArtifactError: the file cannot be read (missing, a directory, ...), is not valid
            UTF-8 JSON, or holds something other than an object.
    """
    try:
        data = json.loads(Path(path).read_text(encoding="utf-8"))
    except OSError as exc:
        raise ArtifactError(f"cannot read {what}: {exc.strerror or exc}") from exc
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ArtifactError(f"{what} is not valid JSON: {exc}") from exc
    if not isinstance(data, dict):
        raise ArtifactError(f"{what} is not a JSON object")
    return data


def write_json_atomic(path: Path, data: dict) -> None:
    """Write ``data`` as sorted, indented JSON via a temporary file and a rename."""
    temporary = path.with_suffix(path.suffix + ".tmp")
    temporary.write_text(json.dumps(data, indent=2, sort_keys=True) + "\n")
    os.replace(temporary, path)


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


__all__ = [
    "file_sha256",
    "make_directory",
    "read_json_object",
    "read_tensors",
    "write_json_atomic",
    "write_tensors_atomic",
]
