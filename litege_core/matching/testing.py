"""A miniature, untrained matching bundle for fast tests of the plumbing around matching
(service, CLI, evaluation). Deterministic for a seed; its matches mean nothing."""

from __future__ import annotations

import functools
import hashlib
from pathlib import Path

import numpy as np
import torch
import trimesh

from litege_core.descriptor import VoxelGrid, fit_basis
from litege_core.matching.bundle import (
    KIND,
    MatchingBundle,
    SearchSettings,
    save_matching_bundle,
)
from litege_core.matching.frame import MatchingPipeline
from litege_core.nets import GeodesicNet, TNet

TINY_COMPONENTS = 6
TINY_WIDTH = 16


@functools.lru_cache(maxsize=4)
def _tiny_basis(seed: int):
    rng = np.random.default_rng(seed)
    shapes = []
    for _ in range(8):
        mesh = trimesh.creation.icosphere(subdivisions=2)
        vertices = np.asarray(mesh.vertices) * rng.uniform(0.2, 0.6, 3)
        vertices /= np.sqrt(mesh.area)  # roughly unit-area scale
        shapes.append((vertices, np.asarray(mesh.faces)))
    return fit_basis(
        shapes,
        grid=VoxelGrid(resolution=21, pitch=0.12),
        std_threshold=0.05,
        n_components=TINY_COMPONENTS,
        n_udf_samples=300,
        seed=seed,
    )


def tiny_matching_bundle(seed: int = 0) -> MatchingBundle:
    """Random weights (``torch.manual_seed(seed)``), a 6-component basis, small tiers."""
    basis = _tiny_basis(seed)
    torch.manual_seed(seed)
    tnet = TNet(conv_widths=(8, 16, 32), fc_widths=(16, 8)).eval()
    net = GeodesicNet(width=TINY_WIDTH, descriptor_dim=basis.n_components).eval()
    net.set_coord_normalization([0.0, 0.0, 0.0], [0.3, 0.15, 0.2])
    pipeline = MatchingPipeline(n_center_samples=1000, n_tnet_points=500)
    search = SearchSettings(tier_sizes=(16, 64), neighbours=(12, 16), beams=1)
    digest = hashlib.sha256(f"tiny-matching-{seed}-{basis.content_hash}".encode()).hexdigest()
    manifest = {"kind": KIND, "name": "tiny", "category": "test", "content_hash": digest}
    return MatchingBundle("tiny", basis, tnet, (net,), pipeline, search, manifest)


def save_tiny_matching_bundle(directory: str | Path, seed: int = 0, name: str = "tiny") -> dict:
    """Write :func:`tiny_matching_bundle` as a bundle directory; returns its manifest."""
    bundle = tiny_matching_bundle(seed)
    return save_matching_bundle(
        directory,
        name=name,
        category="test",
        basis=bundle.basis,
        tnet=bundle.tnet,
        networks=list(bundle.networks),
        pipeline=bundle.pipeline,
        search=bundle.search,
    )


__all__ = [
    "TINY_COMPONENTS",
    "TINY_WIDTH",
    "save_tiny_matching_bundle",
    "tiny_matching_bundle",
]
