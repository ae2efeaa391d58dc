"""Model bundles: everything a trained LiteGE geodesic model needs, as one versioned artifact.

::

    BUNDLE/manifest.json            name, version, category, pipeline constants, network config,
                                    training summary, metrics, file hashes, content hash
    BUNDLE/basis.safetensors        the UDF-PCA basis (voxels, mean, components in float16)
    BUNDLE/geodesic.safetensors     GeodesicNet weights and coordinate normalization buffers

Loading checks every file hash and the consistency of the pieces (descriptor width of the
network = number of basis components, canonicalization the bundle was trained with), so a
network is never paired with the wrong basis or constants (reference-spec §10.6). No pickle.
Shipped bundles live in ``litege_core/models/NAME/`` (package data).
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import torch

from litege_core.datasets.storage import file_sha256, write_json_atomic
from litege_core.descriptor import UdfPcaBasis
from litege_core.errors import ArtifactError, InputError
from litege_core.nets import GeodesicNet, load_state, state_to_tensors

FORMAT_VERSION = 1
MANIFEST = "manifest.json"
BASIS_FILE = "basis.safetensors"
NETWORK_FILE = "geodesic.safetensors"
SHIPPED_DIR = Path(__file__).resolve().parent / "models"
DEFAULT_MODEL = "quadrupeds"


@dataclass(frozen=True)
class PipelineConfig:
    """Constants of the regression pipeline that a bundle was trained with."""

    canonicalization: str = "bbox"
    bbox_sqrt_area: float = 1.7
    n_mesh_samples: int = 2000
    residual: bool = True
    target_scale: float = 1.42


@dataclass(frozen=True, eq=False)
class ModelBundle:
    """A loaded bundle: basis, network (eval mode, on ``device``) and manifest."""

    name: str
    basis: UdfPcaBasis
    network: GeodesicNet
    pipeline: PipelineConfig
    manifest: dict[str, Any] = field(repr=False)
    path: Path | None = None

    @property
    def content_hash(self) -> str:
        return str(self.manifest["content_hash"])

    @property
    def category(self) -> str:
        return str(self.manifest.get("category", "unknown"))

    @property
    def device(self) -> torch.device:
        return next(self.network.parameters()).device


def _content_hash(file_hashes: dict[str, str], manifest_core: dict[str, Any]) -> str:
    digest = hashlib.sha256(json.dumps(file_hashes, sort_keys=True).encode())
    digest.update(json.dumps(manifest_core, sort_keys=True, default=str).encode())
    return digest.hexdigest()


def save_bundle(
    directory: str | os.PathLike,
    *,
    name: str,
    category: str,
    basis: UdfPcaBasis,
    network: GeodesicNet,
    pipeline: PipelineConfig = PipelineConfig(),
    version: str = "0.1.0",
    training: dict[str, Any] | None = None,
    metrics: dict[str, Any] | None = None,
    weights_dtype: torch.dtype = torch.float32,
) -> dict[str, Any]:
    """Write a bundle; returns its manifest. ``weights_dtype=torch.float16`` halves the size of
    the network parameters (buffers stay float32); non-finite weights are refused."""
    from safetensors.torch import save_file

    if network.descriptor_dim != basis.n_components:
        raise InputError(
            f"network expects {network.descriptor_dim}-d descriptors, "
            f"basis has {basis.n_components} components"
        )
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    basis.save(directory / BASIS_FILE)
    save_file(narrowed_state(network, weights_dtype), str(directory / NETWORK_FILE))
    core = {
        "format_version": FORMAT_VERSION,
        "name": name,
        "version": version,
        "category": category,
        "pipeline": pipeline.__dict__,
        "network": network.config(),
        "descriptor": descriptor_summary(basis),
    }
    return write_manifest(directory, core, [BASIS_FILE, NETWORK_FILE], training, metrics)


def narrowed_state(module: torch.nn.Module, dtype: torch.dtype) -> dict[str, torch.Tensor]:
    """State tensors with floating *parameters* cast to ``dtype``. Buffers (BatchNorm running
    statistics, coordinate normalization) keep float32: a running variance can exceed
    float16's range. Non-finite values after the cast are an :class:`InputError`."""
    parameters = {name for name, _ in module.named_parameters()}
    tensors = {
        key: value.to(dtype) if key in parameters and value.is_floating_point() else value
        for key, value in state_to_tensors(module).items()
    }
    for key, value in tensors.items():
        if value.is_floating_point() and not torch.isfinite(value).all():
            raise InputError(f"weights are not finite in {dtype} (e.g. {key})")
    return tensors


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
    for filename, expected in manifest.get("files", {}).items():
        if not (directory / filename).exists():
            raise ArtifactError(f"bundle {directory.name} lacks {filename}")
        if file_sha256(directory / filename) != expected:
            raise ArtifactError(f"{filename} of bundle {directory.name} does not match its hash")
    return manifest


def load_bundle(path: str | os.PathLike, device: str | torch.device = "cpu") -> ModelBundle:
    """Load and verify a bundle directory.

    Raises:
        ArtifactError: missing or damaged files, hash mismatch, or inconsistent pieces.
    """
    directory = Path(path)
    manifest = read_verified_manifest(directory)
    if manifest.get("format_version") != FORMAT_VERSION:
        raise ArtifactError(f"bundle format {manifest.get('format_version')} is not supported")
    basis = UdfPcaBasis.load(directory / BASIS_FILE)
    if basis.content_hash != manifest["descriptor"]["basis_hash"]:
        raise ArtifactError("bundle basis differs from the one it was trained with")
    try:
        network = GeodesicNet.from_config(manifest["network"])
        pipeline = PipelineConfig(**manifest["pipeline"])
    except (KeyError, TypeError, ValueError, InputError) as exc:
        raise ArtifactError(f"bundle manifest is inconsistent: {exc}") from exc
    if network.descriptor_dim != basis.n_components:
        raise ArtifactError("bundle network and basis disagree on the descriptor size")
    from safetensors import SafetensorError
    from safetensors.torch import load_file

    try:
        tensors = load_file(str(directory / NETWORK_FILE))
    except (SafetensorError, OSError) as exc:
        raise ArtifactError(f"cannot read {NETWORK_FILE}: {exc}") from exc
    load_state(network, tensors)
    network.to(device).eval()
    return ModelBundle(manifest["name"], basis, network, pipeline, manifest, directory)


def shipped_bundles() -> list[str]:
    """Names of the geodesic bundles shipped inside the package (matching bundles, kind
    ``"matching"``, are listed by :func:`litege_core.matching.shipped_matching_bundles`)."""
    if not SHIPPED_DIR.is_dir():
        return []
    return sorted(
        p.name
        for p in SHIPPED_DIR.iterdir()
        if (p / MANIFEST).exists()
        and json.loads((p / MANIFEST).read_text()).get("kind", "geodesic") == "geodesic"
    )


def load_shipped(name: str = DEFAULT_MODEL, device: str | torch.device = "cpu") -> ModelBundle:
    """Load a shipped bundle by name (``quadrupeds`` or ``humans``)."""
    if name not in shipped_bundles():
        raise InputError(f"unknown model {name!r}; shipped models: {shipped_bundles()}")
    return load_bundle(SHIPPED_DIR / name, device)
