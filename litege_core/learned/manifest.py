"""The bundle directory format without torch: constants, manifests, hashes, pipeline checks.

A bundle directory is ``manifest.json`` plus the files it lists by SHA-256 (a basis and weight
files); :func:`read_verified_manifest` and :func:`open_bundle` check them, :func:`write_manifest`
writes them. The network side (torch modules, :class:`~litege_core.learned.bundle.ModelBundle`)
is in :mod:`litege_core.learned.bundle`, which re-exports everything here; the torch-free
runtime (:mod:`litege_core.learned.numpy_predictor`) reads bundles through this module only.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from litege_core.canonical import BBOX_SQRT_AREA
from litege_core.descriptor.basis import UdfPcaBasis
from litege_core.errors import ArtifactError, InputError
from litege_core.files import file_sha256, write_json_atomic

FORMAT_VERSION = 1
MANIFEST = "manifest.json"
BASIS_FILE = "basis.safetensors"
NETWORK_FILE = "geodesic.safetensors"
SHIPPED_DIR = Path(__file__).resolve().parent.parent / "models"
DEFAULT_MODEL = "quadrupeds"
GEODESIC = "geodesic"
"""Kind of a bundle whose manifest has no ``kind`` key."""


def _content_hash(file_hashes: dict[str, str], manifest_core: dict[str, Any]) -> str:
    digest = hashlib.sha256(json.dumps(file_hashes, sort_keys=True).encode())
    digest.update(json.dumps(manifest_core, sort_keys=True, default=str).encode())
    return digest.hexdigest()


def descriptor_summary(basis: UdfPcaBasis) -> dict[str, Any]:
    """The manifest's ``descriptor`` entry: what a network must be paired with."""
    return {
        "n_components": basis.n_components,
        "n_voxels": basis.n_voxels,
        "basis_hash": basis.content_hash,
    }


def write_manifest(
    directory: Path,
    core: dict[str, Any],
    filenames: list[str],
    training: dict[str, Any] | None,
    metrics: dict[str, Any] | None,
) -> dict[str, Any]:
    """Hash ``filenames`` of ``directory`` and write ``manifest.json`` (``core`` + file hashes,
    training summary, metrics, creation time, content hash); returns the manifest."""
    files = {f: file_sha256(directory / f) for f in filenames}
    manifest = {
        **core,
        "files": files,
        "training": training or {},
        "metrics": metrics or {},
        "created": datetime.now(UTC).isoformat(timespec="seconds"),
        "content_hash": _content_hash(files, core),
    }
    write_json_atomic(directory / MANIFEST, manifest)
    return manifest


def read_verified_manifest(directory: Path, what: str = "model bundle") -> dict[str, Any]:
    """``manifest.json`` of a bundle directory, after checking every listed file's hash.

    Raises:
        ArtifactError: no or invalid manifest, a missing file or a hash mismatch.
    """
    try:
        manifest = json.loads((directory / MANIFEST).read_text())
    except FileNotFoundError as exc:
        raise ArtifactError(f"no {what} at {directory} ({MANIFEST} missing)") from exc
    except json.JSONDecodeError as exc:
        raise ArtifactError(f"{directory / MANIFEST} is not valid JSON: {exc}") from exc
    if not isinstance(manifest, dict):
        raise ArtifactError(f"{directory / MANIFEST} is not a JSON object")
    for filename, expected in manifest.get("files", {}).items():
        if not (directory / filename).exists():
            raise ArtifactError(f"bundle {directory.name} lacks {filename}")
        if file_sha256(directory / filename) != expected:
            raise ArtifactError(f"{filename} of bundle {directory.name} does not match its hash")
    return manifest


def open_bundle(
    path: str | os.PathLike, kind: str, what: str
) -> tuple[Path, dict[str, Any], UdfPcaBasis]:
    """The verified manifest and basis of a bundle directory of ``kind``.

    Raises:
        ArtifactError: damaged files, another kind or format version, or a basis other than
            the one the networks were trained with.
    """
    directory = Path(path)
    manifest = read_verified_manifest(directory, what)
    found = (manifest.get("kind", GEODESIC), manifest.get("format_version"))
    if found != (kind, FORMAT_VERSION):
        raise ArtifactError(
            f"{directory} is not a {what} of format {FORMAT_VERSION} "
            f"(kind {found[0]!r}, format {found[1]!r})"
        )
    basis = UdfPcaBasis.load(directory / BASIS_FILE)
    if basis.content_hash != manifest.get("descriptor", {}).get("basis_hash"):
        raise ArtifactError("bundle basis differs from the one it was trained with")
    return directory, manifest, basis


@contextmanager
def consistent_manifest(what: str) -> Iterator[None]:
    """Turn a missing key or a bad value while building from a manifest into an
    :class:`ArtifactError`."""
    try:
        yield
    except (KeyError, TypeError, ValueError, InputError) as exc:
        raise ArtifactError(f"{what} manifest is inconsistent: {exc}") from exc


def shipped_directories(kind: str) -> list[Path]:
    """The bundle directories of ``kind`` shipped inside the package, by name."""
    if not SHIPPED_DIR.is_dir():
        return []
    found = []
    for directory in sorted(SHIPPED_DIR.iterdir()):
        manifest = directory / MANIFEST
        if manifest.is_file() and json.loads(manifest.read_text()).get("kind", GEODESIC) == kind:
            found.append(directory)
    return found


@dataclass(frozen=True)
class PipelineConfig:
    """Constants of the regression pipeline that a bundle was trained with."""

    canonicalization: str = "bbox"
    bbox_sqrt_area: float = 1.7
    n_mesh_samples: int = 2000
    residual: bool = True
    target_scale: float = 1.42


def shipped_bundles() -> list[str]:
    """Names of the geodesic bundles shipped inside the package (matching bundles, kind
    ``"matching"``, are listed by :func:`litege_core.matching.shipped_matching_bundles`)."""
    return [directory.name for directory in shipped_directories(GEODESIC)]


def check_pipeline(name: str, pipeline: PipelineConfig) -> None:
    """Raise :class:`ArtifactError` unless the geodesic predictors implement ``pipeline``."""
    if pipeline.canonicalization != "bbox":
        raise ArtifactError(
            f"bundle {name!r} uses canonicalization {pipeline.canonicalization!r}; "
            "the geodesic predictor implements 'bbox'"
        )
    if not math.isclose(pipeline.bbox_sqrt_area, BBOX_SQRT_AREA, rel_tol=1e-12):
        raise ArtifactError(
            f"bundle {name!r} was trained with bbox_sqrt_area "
            f"{pipeline.bbox_sqrt_area}, this library canonicalizes to {BBOX_SQRT_AREA}"
        )
    if not (pipeline.target_scale > 0 and pipeline.n_mesh_samples >= 4):
        raise ArtifactError(f"bundle {name!r} has an invalid pipeline: {pipeline}")


def residual_statistics(name: str, manifest: dict[str, Any]) -> tuple[float, float] | None:
    """``(mean, std)`` of the training shapes' UDF-PCA residuals (the OOD z-score's
    calibration) from the manifest's ``training`` section, or ``None`` where it has none.

    Raises:
        ArtifactError: statistics that are not finite or a standard deviation ≤ 0.
    """
    training = manifest.get("training") or {}
    mean, std = training.get("residual_mean"), training.get("residual_std")
    if mean is None or std is None:
        return None
    if not (math.isfinite(float(mean)) and math.isfinite(float(std)) and std > 0):
        raise ArtifactError(f"bundle {name!r} has invalid residual statistics {mean}, {std}")
    return float(mean), float(std)


__all__ = [
    "BASIS_FILE",
    "DEFAULT_MODEL",
    "FORMAT_VERSION",
    "GEODESIC",
    "MANIFEST",
    "NETWORK_FILE",
    "SHIPPED_DIR",
    "PipelineConfig",
    "check_pipeline",
    "consistent_manifest",
    "descriptor_summary",
    "open_bundle",
    "read_verified_manifest",
    "residual_statistics",
    "shipped_bundles",
    "shipped_directories",
    "write_manifest",
]
