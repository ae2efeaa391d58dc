"""Matching bundles: T-Net, UDF-PCA basis and matching network(s) as one versioned artifact.

::

    BUNDLE/manifest.json         kind "matching", name, category, pipeline constants, network
                                 and T-Net configs, search settings, training summary, metrics,
                                 file hashes, content hash
    BUNDLE/basis.safetensors     UDF-PCA basis of the aligned unit-area frame
    BUNDLE/tnet.safetensors      T-Net weights
    BUNDLE/matching-K.safetensors   matching network K (several = an ensemble, outputs averaged)
    BUNDLE/judge-K.safetensors      optional: the frame judge's network K (without them the
                                    judge scores frames with the matching networks)
    BUNDLE/orientation.safetensors  optional: an OrientationNet; where present it, not the
                                    judge, weighs the candidate frames of ``judged`` frames

Loading verifies every file hash and that the networks fit the basis, as for geodesic bundles:
both formats are a :class:`~litege_core.learned.bundle.Bundle`, written and opened by the same
functions of :mod:`litege_core.learned.bundle`. Shipped matching bundles live in
``litege_core/models/NAME-matching/``.
"""

from __future__ import annotations

import os
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import torch

from litege_core.descriptor import UdfPcaBasis
from litege_core.errors import ArtifactError, InputError
from litege_core.learned.bundle import (
    BASIS_FILE,
    FORMAT_VERSION,
    MANIFEST,
    SHIPPED_DIR,
    Bundle,
    check_descriptor_width,
    consistent_manifest,
    load_weights,
    open_bundle,
    shipped_directories,
    write_bundle,
)
from litege_core.matching.cache import DEFAULT_NEIGHBOURS, DEFAULT_TIER_SIZES
from litege_core.matching.frame import MatchingPipeline
from litege_core.nets import GeodesicNet, TNet
from litege_core.nets.orientation import OrientationNet

KIND = "matching"
TNET_FILE = "tnet.safetensors"
ORIENTATION_FILE = "orientation.safetensors"
SUFFIX = "-matching"


def network_file(index: int) -> str:
    return f"matching-{index}.safetensors"


def judge_file(index: int) -> str:
    return f"judge-{index}.safetensors"


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
class MatchingBundle(Bundle):
    """A loaded matching bundle (networks in eval mode on one device)."""

    name: str
    basis: UdfPcaBasis
    tnet: TNet
    networks: tuple[GeodesicNet, ...]
    pipeline: MatchingPipeline
    search: SearchSettings
    manifest: dict[str, Any] = field(repr=False)
    path: Path | None = None
    judge_networks: tuple[GeodesicNet, ...] = ()
    orientation: OrientationNet | None = None

    @property
    def modules(self) -> tuple[torch.nn.Module, ...]:
        extra = (self.orientation,) if self.orientation is not None else ()
        return (*self.networks, self.tnet, *self.judge_networks, *extra)

    @property
    def frame_judge_networks(self) -> tuple[GeodesicNet, ...]:
        """The networks the frame judge scores with: the bundle's own judge networks, else
        its matching networks."""
        return self.judge_networks or self.networks


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
    judge_networks: list[GeodesicNet] | tuple[GeodesicNet, ...] = (),
    orientation: OrientationNet | None = None,
) -> dict[str, Any]:
    """Write a matching bundle; returns its manifest. ``judge_networks`` (optional) are
    the frame judge's own networks, e.g. the network a continued bundle started from, whose
    frame choices were validated; ``orientation`` (optional) the network that weighs candidate
    frames instead of the judge (:mod:`litege_core.nets.orientation`)."""
    pipeline = pipeline or MatchingPipeline()
    search = search or SearchSettings()
    check_descriptor_width((*networks, *judge_networks), basis)
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
    }
    weights = {TNET_FILE: tnet, **{network_file(k): net for k, net in enumerate(networks)}}
    if judge_networks:
        core["judge_networks"] = [net.config() for net in judge_networks]
        weights.update({judge_file(k): net for k, net in enumerate(judge_networks)})
    if orientation is not None:
        core["orientation"] = orientation.config()
        weights[ORIENTATION_FILE] = orientation
    return write_bundle(
        directory,
        core,
        basis,
        weights,
        weights_dtype=weights_dtype,
        training=training,
        metrics=metrics,
    )


def load_matching_bundle(
    path: str | os.PathLike, device: str | torch.device = "cpu"
) -> MatchingBundle:
    """Load and verify a matching bundle directory.

    Raises:
        ArtifactError: missing or damaged files, hash mismatch, or inconsistent pieces.
    """
    directory, manifest, basis = open_bundle(path, KIND, "matching bundle")
    with consistent_manifest("matching bundle"):
        tnet = TNet.from_config(manifest["tnet"])
        networks = tuple(GeodesicNet.from_config(c) for c in manifest["networks"])
        judges = tuple(GeodesicNet.from_config(c) for c in manifest.get("judge_networks", []))
        orientation = (
            OrientationNet.from_config(manifest["orientation"])
            if "orientation" in manifest
            else None
        )
        pipeline = MatchingPipeline.from_dict(manifest["pipeline"])
        search = SearchSettings.from_dict(manifest["search"])
    check_descriptor_width((*networks, *judges), basis, ArtifactError)
    load_weights(tnet, directory / TNET_FILE, device)
    for k, net in enumerate(networks):
        load_weights(net, directory / network_file(k), device)
    for k, net in enumerate(judges):
        load_weights(net, directory / judge_file(k), device)
    if orientation is not None:
        load_weights(orientation, directory / ORIENTATION_FILE, device)
    return MatchingBundle(
        manifest["name"],
        basis,
        tnet,
        networks,
        pipeline,
        search,
        manifest,
        directory,
        judges,
        orientation,
    )


def shipped_matching_bundles() -> list[str]:
    """Names (without the ``-matching`` suffix) of the shipped matching bundles."""
    return [
        directory.name.removesuffix(SUFFIX)
        for directory in shipped_directories(KIND)
        if directory.name.endswith(SUFFIX)
    ]


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


__all__ = [
    "BASIS_FILE",
    "FORMAT_VERSION",
    "KIND",
    "MANIFEST",
    "SUFFIX",
    "TNET_FILE",
    "MatchingBundle",
    "SearchSettings",
    "load_matching_bundle",
    "network_file",
    "resolve_matching_bundle",
    "save_matching_bundle",
    "shipped_matching_bundles",
]
