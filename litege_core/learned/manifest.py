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

import numpy as np

from litege_core.canonical import BBOX_SQRT_AREA
from litege_core.descriptor.basis import UdfPcaBasis
from litege_core.errors import ArtifactError, InputError
from litege_core.files import file_sha256, read_json_object, write_json_atomic

FORMAT_VERSION = 1
MANIFEST = "manifest.json"
BASIS_FILE = "basis.safetensors"
NETWORK_FILE = "geodesic.safetensors"
SHIPPED_DIR = Path(__file__).resolve().parent.parent / "models"
DEFAULT_MODEL = "quadrupeds"
GEODESIC = "geodesic"
"""Kind of a bundle whose manifest has no ``kind`` key."""
HEADS = ("full", "small")
"""The distance heads a predictor runs: the trained head or the bundle's distilled one."""
AUTO_HEAD = "auto"
"""The predictors' default head: ``"small"`` for a bundle that ships one, else ``"full"``."""
HEAD_CHOICES = (AUTO_HEAD, *HEADS)
"""What a predictor's head argument accepts."""
SMALL_HEAD_WEIGHTS = "head-small.safetensors"
SMALL_HEAD_CONFIG = "head-small.json"
SMALL_HEAD_KIND = "small_head"
SMALL_HEAD_FORMAT = 1


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
    created: str | None = None,
) -> dict[str, Any]:
    """Hash ``filenames`` of ``directory`` and write ``manifest.json`` (``core`` + file hashes,
    training summary, metrics, creation time (now unless ``created``), content hash); returns
    the manifest."""
    files = {f: file_sha256(directory / f) for f in filenames}
    manifest = {
        **core,
        "files": files,
        "training": training or {},
        "metrics": metrics or {},
        "created": created or datetime.now(UTC).isoformat(timespec="seconds"),
        "content_hash": _content_hash(files, core),
    }
    write_json_atomic(directory / MANIFEST, manifest)
    return manifest


_NOT_CORE = ("files", "training", "metrics", "created", "content_hash")
"""Manifest keys outside a bundle's content hash (or the file hashes it covers)."""


def manifest_core(manifest: dict[str, Any]) -> dict[str, Any]:
    """The part of a manifest its content hash covers besides the file hashes."""
    return {k: v for k, v in manifest.items() if k not in _NOT_CORE}


def replace_basis(directory: Path, basis: UdfPcaBasis) -> dict[str, Any]:
    """Write ``basis`` over a bundle's basis file and re-hash its manifest (the descriptor's
    basis hash, the file hashes, the content hash; the creation time is kept); returns the new
    manifest.

    For a basis with the same voxels and components up to storage rounding (e.g.
    :meth:`~litege_core.descriptor.basis.UdfPcaBasis.with_component_storage`): the networks
    are kept as they are. Sidecars that name the bundle's content hash must follow it.

    Raises:
        ArtifactError: a damaged bundle, or a basis of another shape than the bundle's.
    """
    manifest = read_verified_manifest(directory)
    old = UdfPcaBasis.load(directory / BASIS_FILE)
    if (old.grid, old.n_voxels, old.n_components) != (
        basis.grid,
        basis.n_voxels,
        basis.n_components,
    ) or not np.array_equal(old.voxel_indices, basis.voxel_indices):
        raise ArtifactError(f"the new basis does not have the voxels and size of {directory}'s")
    basis.save(directory / BASIS_FILE)
    core = manifest_core(manifest)
    core["descriptor"] = {**core["descriptor"], **descriptor_summary(basis)}
    files, training, metrics = list(manifest["files"]), manifest["training"], manifest["metrics"]
    return write_manifest(directory, core, files, training, metrics, manifest.get("created"))


def read_verified_manifest(directory: Path, what: str = "model bundle") -> dict[str, Any]:
    """``manifest.json`` of a bundle directory, after checking every listed file's hash.

    Raises:
        ArtifactError: no or invalid manifest, a missing file or a hash mismatch.
    """
    if not (directory / MANIFEST).exists():  # also when ``directory`` is a file
        raise ArtifactError(f"no {what} at {directory} ({MANIFEST} missing)")
    manifest = read_json_object(directory / MANIFEST, str(directory / MANIFEST))
    files = manifest.get("files", {})
    if not isinstance(files, dict):
        raise ArtifactError(f"{directory / MANIFEST}: 'files' is not a JSON object")
    for filename, expected in files.items():
        if not (directory / filename).is_file():
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


def resolve_head(directory: Path | None, head: str) -> str:
    """``head`` itself, or for :data:`AUTO_HEAD` ``"small"`` when the bundle directory holds a
    small-head sidecar (checked when it is loaded) and ``"full"`` otherwise.

    Raises:
        InputError: not one of :data:`HEAD_CHOICES`.
    """
    if head not in HEAD_CHOICES:
        raise InputError(f"head must be one of {HEAD_CHOICES}, got {head!r}")
    if head != AUTO_HEAD:
        return head
    sidecar = directory is not None and (Path(directory) / SMALL_HEAD_CONFIG).is_file()
    return "small" if sidecar else "full"


def verified_small_head(
    directory: Path, name: str, content_hash: str
) -> tuple[dict[str, Any], Path]:
    """The small-head sidecar of a bundle directory (:mod:`litege_core.learned.small_head`):
    its config and its weights file, checked against the bundle's ``content_hash``.

    Raises:
        InputError: the bundle has no small head, or its head was distilled from another
            bundle (teacher content hash ≠ the bundle's).
        ArtifactError: a damaged sidecar (bad JSON, another format, a weights hash mismatch).
    """
    path = Path(directory) / SMALL_HEAD_CONFIG
    if not path.is_file():
        raise InputError(
            f"model {name!r} has no small head ({SMALL_HEAD_CONFIG}); distil one with "
            "scripts/distill_head.py or use head='full'"
        )
    config = read_json_object(path, f"{SMALL_HEAD_CONFIG} of {name}")
    if (config.get("kind"), config.get("format_version")) != (SMALL_HEAD_KIND, SMALL_HEAD_FORMAT):
        raise ArtifactError(
            f"{SMALL_HEAD_CONFIG} of {name} is not a small head of format {SMALL_HEAD_FORMAT}"
        )
    teacher = str(config.get("teacher_content_hash", ""))
    if teacher != content_hash:
        raise InputError(
            f"the small head of {name!r} was distilled from bundle {teacher[:12]}…, "
            f"not from this bundle ({content_hash[:12]}…); distil it again"
        )
    weights = Path(directory) / SMALL_HEAD_WEIGHTS
    if not weights.is_file():
        raise ArtifactError(f"bundle {name} lacks {SMALL_HEAD_WEIGHTS}")
    if file_sha256(weights) != config.get("weights_sha256"):
        raise ArtifactError(f"{SMALL_HEAD_WEIGHTS} of {name} does not match its hash")
    return config, weights


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
    "AUTO_HEAD",
    "BASIS_FILE",
    "DEFAULT_MODEL",
    "FORMAT_VERSION",
    "GEODESIC",
    "HEADS",
    "HEAD_CHOICES",
    "MANIFEST",
    "NETWORK_FILE",
    "SHIPPED_DIR",
    "SMALL_HEAD_CONFIG",
    "SMALL_HEAD_FORMAT",
    "SMALL_HEAD_KIND",
    "SMALL_HEAD_WEIGHTS",
    "PipelineConfig",
    "check_pipeline",
    "consistent_manifest",
    "descriptor_summary",
    "manifest_core",
    "open_bundle",
    "read_verified_manifest",
    "replace_basis",
    "residual_statistics",
    "resolve_head",
    "shipped_bundles",
    "shipped_directories",
    "verified_small_head",
    "write_manifest",
]
