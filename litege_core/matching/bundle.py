"""Matching bundles: T-Net, UDF-PCA basis and matching network(s) as one versioned artifact.

::

    BUNDLE/manifest.json         kind "matching", name, category, pipeline constants, network
                                 and T-Net configs, search settings, training summary, metrics,
                                 file hashes, content hash
    BUNDLE/basis.safetensors     UDF-PCA basis of the aligned unit-area frame
    BUNDLE/tnet.safetensors      T-Net weights
    BUNDLE/matching-K.safetensors   matching network K (several = an ensemble, outputs averaged)

Loading verifies every file hash and that the networks fit the basis, as for geodesic bundles.
Shipped matching bundles live in ``litege_core/models/NAME-matching/``.
"""

from __future__ import annotations

import os
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import torch

from litege_core.bundle import (
    SHIPPED_DIR,
    descriptor_summary,
    narrowed_state,
    read_verified_manifest,
    write_manifest,
)
from litege_core.descriptor import UdfPcaBasis
from litege_core.errors import ArtifactError, InputError
from litege_core.matching.cache import DEFAULT_NEIGHBOURS, DEFAULT_TIER_SIZES
from litege_core.matching.frame import MatchingPipeline
from litege_core.nets import GeodesicNet, TNet, load_state

FORMAT_VERSION = 1
KIND = "matching"
MANIFEST = "manifest.json"
BASIS_FILE = "basis.safetensors"
TNET_FILE = "tnet.safetensors"
SUFFIX = "-matching"


def network_file(index: int) -> str:
    return f"matching-{index}.safetensors"


@dataclass(frozen=True)
class SearchSettings:
    """Coarse-to-fine search defaults of a bundle (spec §5.2–5.3, FPS tiers)."""

    tier_sizes: tuple[int, ...] = DEFAULT_TIER_SIZES
    neighbours: tuple[int, ...] = DEFAULT_NEIGHBOURS
    beams: int = 1
    strategy: str = "fps"

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> SearchSettings:
        return cls(
            tier_sizes=tuple(data["tier_sizes"]),
            neighbours=tuple(data["neighbours"]),
            beams=int(data["beams"]),
            strategy=str(data["strategy"]),
        )


@dataclass(frozen=True, eq=False)
class MatchingBundle:
    """A loaded matching bundle (networks in eval mode on one device)."""

    name: str
    basis: UdfPcaBasis
    tnet: TNet
    networks: tuple[GeodesicNet, ...]
    pipeline: MatchingPipeline
    search: SearchSettings
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
        return next(self.networks[0].parameters()).device


def save_matching_bundle(
    directory: str | os.PathLike,
    *,
    name: str,
    category: str,
    basis: UdfPcaBasis,
    tnet: TNet,
    networks: list[GeodesicNet] | tuple[GeodesicNet, ...],
    pipeline: MatchingPipeline | None = None,
    search: SearchSettings | None = None,
    version: str = "0.1.0",
    training: dict[str, Any] | None = None,
    metrics: dict[str, Any] | None = None,
    weights_dtype: torch.dtype = torch.float32,
) -> dict[str, Any]:
    """Write a matching bundle; returns its manifest."""
    from safetensors.torch import save_file

    pipeline = pipeline or MatchingPipeline()
    search = search or SearchSettings()
    if not networks:
        raise InputError("a matching bundle needs at least one network")
    for net in networks:
        if net.descriptor_dim != basis.n_components:
            raise InputError(
                f"network expects {net.descriptor_dim}-d descriptors, "
                f"basis has {basis.n_components} components"
            )
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    basis.save(directory / BASIS_FILE)
    save_file(narrowed_state(tnet, weights_dtype), str(directory / TNET_FILE))
    for k, net in enumerate(networks):
        save_file(narrowed_state(net, weights_dtype), str(directory / network_file(k)))
    names = [BASIS_FILE, TNET_FILE, *(network_file(k) for k in range(len(networks)))]
    core = {
        "format_version": FORMAT_VERSION,
        "kind": KIND,
        "name": name,
        "version": version,
        "category": category,
        "pipeline": pipeline.to_dict(),
        "search": asdict(search),
        "tnet": tnet.config(),
        "networks": [net.config() for net in networks],
        "descriptor": descriptor_summary(basis),
    }
    return write_manifest(directory, core, names, training, metrics)


def _load_state_file(module: torch.nn.Module, path: Path) -> None:
    from safetensors import SafetensorError
    from safetensors.torch import load_file

    try:
        tensors = load_file(str(path))
    except (SafetensorError, OSError) as exc:
        raise ArtifactError(f"cannot read {path.name}: {exc}") from exc
    load_state(module, tensors)


def load_matching_bundle(
    path: str | os.PathLike, device: str | torch.device = "cpu"
) -> MatchingBundle:
    """Load and verify a matching bundle directory.

    Raises:
        ArtifactError: missing or damaged files, hash mismatch, or inconsistent pieces.
    """
    directory = Path(path)
    manifest = read_verified_manifest(directory, "matching bundle")
    if manifest.get("kind") != KIND or manifest.get("format_version") != FORMAT_VERSION:
        raise ArtifactError(f"{directory} is not a matching bundle of format {FORMAT_VERSION}")
    basis = UdfPcaBasis.load(directory / BASIS_FILE)
    if basis.content_hash != manifest["descriptor"]["basis_hash"]:
        raise ArtifactError("bundle basis differs from the one it was trained with")
    try:
        tnet = TNet.from_config(manifest["tnet"])
        networks = tuple(GeodesicNet.from_config(c) for c in manifest["networks"])
        pipeline = MatchingPipeline.from_dict(manifest["pipeline"])
        search = SearchSettings.from_dict(manifest["search"])
    except (KeyError, TypeError, ValueError, InputError) as exc:
        raise ArtifactError(f"matching bundle manifest is inconsistent: {exc}") from exc
    if not networks or any(n.descriptor_dim != basis.n_components for n in networks):
        raise ArtifactError("bundle networks and basis disagree on the descriptor size")
    _load_state_file(tnet, directory / TNET_FILE)
    for k, net in enumerate(networks):
        _load_state_file(net, directory / network_file(k))
        net.to(device).eval()
    tnet.to(device).eval()
    return MatchingBundle(
        manifest["name"], basis, tnet, networks, pipeline, search, manifest, directory
    )


def shipped_matching_bundles() -> list[str]:
    """Names (without the ``-matching`` suffix) of the shipped matching bundles."""
    if not SHIPPED_DIR.is_dir():
        return []
    return sorted(
        p.name[: -len(SUFFIX)]
        for p in SHIPPED_DIR.iterdir()
        if p.name.endswith(SUFFIX) and (p / MANIFEST).exists()
    )


def resolve_matching_bundle(name_or_path: str | os.PathLike) -> Path:
    """A shipped name (``quadrupeds``) or a bundle directory → the bundle directory."""
    text = str(name_or_path)
    if text in shipped_matching_bundles():
        return SHIPPED_DIR / f"{text}{SUFFIX}"
    path = Path(text)
    if (path / MANIFEST).exists():
        return path
    raise InputError(
        f"unknown matching model {text!r}; shipped matching models: {shipped_matching_bundles()}"
    )
