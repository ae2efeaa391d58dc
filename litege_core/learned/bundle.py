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

The directory format itself (constants, manifests, hashes) is :mod:`litege_core.learned.manifest`,
torch-free and re-exported here. The format is shared with matching bundles
(:mod:`litege_core.matching.bundle`): both are a :class:`Bundle`, written by :func:`write_bundle`
(basis + weight files + manifest with file hashes and a content hash) and opened by
:func:`open_bundle` (hashes, kind, format version and basis verified). A manifest without a
``kind`` is a geodesic bundle (the key came with matching).
"""

from __future__ import annotations

import abc
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch

from litege_core.descriptor import UdfPcaBasis
from litege_core.errors import ArtifactError, InputError
from litege_core.learned.manifest import (
    BASIS_FILE,
    DEFAULT_MODEL,
    FORMAT_VERSION,
    GEODESIC,
    MANIFEST,
    NETWORK_FILE,
    SHIPPED_DIR,
    PipelineConfig,
    consistent_manifest,
    descriptor_summary,
    manifest_core,
    open_bundle,
    read_verified_manifest,
    replace_basis,
    shipped_bundles,
    shipped_directories,
    write_manifest,
)
from litege_core.nets import GeodesicNet, load_state, state_to_tensors

# --------------------------------------------------------------------------- the shared format


class Bundle(abc.ABC):
    """A loaded, verified bundle directory: a UDF-PCA basis, networks (eval mode, on one
    device) and the manifest whose ``content_hash`` covers every file and setting."""

    name: str
    basis: UdfPcaBasis
    manifest: dict[str, Any]
    path: Path | None

    @property
    @abc.abstractmethod
    def modules(self) -> tuple[torch.nn.Module, ...]:
        """The bundle's networks (all on :attr:`device`)."""

    @property
    def content_hash(self) -> str:
        return str(self.manifest["content_hash"])

    @property
    def category(self) -> str:
        return str(self.manifest.get("category", "unknown"))

    @property
    def kind(self) -> str:
        return str(self.manifest.get("kind", GEODESIC))

    @property
    def device(self) -> torch.device:
        return next(self.modules[0].parameters()).device


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


def check_descriptor_width(
    networks: Sequence[GeodesicNet], basis: UdfPcaBasis, error: type[Exception] = InputError
) -> None:
    """Every network reads ``basis.n_components``-d descriptors (else ``error``)."""
    if not networks:
        raise error("a bundle needs at least one network")
    for net in networks:
        if net.descriptor_dim != basis.n_components:
            raise error(
                f"network expects {net.descriptor_dim}-d descriptors, "
                f"basis has {basis.n_components} components"
            )


def write_bundle(
    directory: str | os.PathLike,
    core: dict[str, Any],
    basis: UdfPcaBasis,
    weights: Mapping[str, torch.nn.Module],
    *,
    weights_dtype: torch.dtype = torch.float32,
    training: dict[str, Any] | None = None,
    metrics: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """Write a bundle directory: ``basis.safetensors``, one safetensors file per entry of
    ``weights`` (parameters narrowed to ``weights_dtype``) and the manifest (``core`` plus the
    :func:`descriptor_summary`, file hashes and content hash); returns the manifest."""
    from safetensors.torch import save_file

    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    basis.save(directory / BASIS_FILE)
    for filename, module in weights.items():
        save_file(narrowed_state(module, weights_dtype), str(directory / filename))
    core = {**core, "descriptor": descriptor_summary(basis)}
    return write_manifest(directory, core, [BASIS_FILE, *weights], training, metrics)


def load_weights(module: torch.nn.Module, path: Path, device: str | torch.device) -> None:
    """Load a safetensors weight file into ``module``, move it to ``device``, eval mode."""
    from safetensors import SafetensorError
    from safetensors.torch import load_file

    try:
        tensors = load_file(str(path))
    except (SafetensorError, OSError) as exc:
        raise ArtifactError(f"cannot read {path.name}: {exc}") from exc
    load_state(module, tensors)
    module.to(device).eval()


# --------------------------------------------------------------------------- geodesic bundles


@dataclass(frozen=True, eq=False)
class ModelBundle(Bundle):
    """A loaded geodesic bundle: basis, network (eval mode, on ``device``) and manifest."""

    name: str
    basis: UdfPcaBasis
    network: GeodesicNet
    pipeline: PipelineConfig
    manifest: dict[str, Any] = field(repr=False)
    path: Path | None = None

    @property
    def modules(self) -> tuple[torch.nn.Module, ...]:
        return (self.network,)


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
    check_descriptor_width([network], basis)
    core = {
        "format_version": FORMAT_VERSION,
        "name": name,
        "version": version,
        "category": category,
        "pipeline": pipeline.__dict__,
        "network": network.config(),
    }
    return write_bundle(
        directory,
        core,
        basis,
        {NETWORK_FILE: network},
        weights_dtype=weights_dtype,
        training=training,
        metrics=metrics,
    )


def load_bundle(path: str | os.PathLike, device: str | torch.device = "cpu") -> ModelBundle:
    """Load and verify a bundle directory.

    Raises:
        ArtifactError: missing or damaged files, hash mismatch, or inconsistent pieces.
    """
    directory, manifest, basis = open_bundle(path, GEODESIC, "model bundle")
    with consistent_manifest("bundle"):
        network = GeodesicNet.from_config(manifest["network"])
        pipeline = PipelineConfig(**manifest["pipeline"])
    check_descriptor_width([network], basis, ArtifactError)
    load_weights(network, directory / NETWORK_FILE, device)
    return ModelBundle(manifest["name"], basis, network, pipeline, manifest, directory)


def load_shipped(name: str = DEFAULT_MODEL, device: str | torch.device = "cpu") -> ModelBundle:
    """Load a shipped bundle by name (``quadrupeds`` or ``humans``)."""
    if name not in shipped_bundles():
        raise InputError(f"unknown model {name!r}; shipped models: {shipped_bundles()}")
    return load_bundle(SHIPPED_DIR / name, device)


def load_model(name_or_dir: str | os.PathLike, device: str | torch.device = "cpu") -> ModelBundle:
    """A bundle directory (:func:`load_bundle`) if ``name_or_dir`` is one, else a shipped
    bundle by name (:func:`load_shipped`)."""
    if Path(name_or_dir).is_dir():
        return load_bundle(name_or_dir, device)
    return load_shipped(str(name_or_dir), device)


__all__ = [
    "BASIS_FILE",
    "DEFAULT_MODEL",
    "FORMAT_VERSION",
    "GEODESIC",
    "MANIFEST",
    "NETWORK_FILE",
    "SHIPPED_DIR",
    "Bundle",
    "ModelBundle",
    "PipelineConfig",
    "check_descriptor_width",
    "consistent_manifest",
    "descriptor_summary",
    "load_bundle",
    "load_model",
    "load_shipped",
    "load_weights",
    "manifest_core",
    "narrowed_state",
    "open_bundle",
    "read_verified_manifest",
    "replace_basis",
    "save_bundle",
    "shipped_bundles",
    "shipped_directories",
    "write_bundle",
    "write_manifest",
]
