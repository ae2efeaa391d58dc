import json

import numpy as np
import pytest
import torch
import trimesh

from litege_core.descriptor import VoxelGrid, fit_basis
from litege_core.errors import ArtifactError, InputError
from litege_core.learned import load_bundle, save_bundle
from litege_core.learned.bundle import Bundle
from litege_core.learned.manifest import (
    BASIS_FILE,
    GEODESIC,
    MANIFEST,
    NETWORK_FILE,
    _content_hash,
    manifest_core,
    replace_basis,
    shipped_directories,
)
from litege_core.matching.bundle import KIND, load_matching_bundle
from litege_core.matching.testing import save_tiny_matching_bundle
from litege_core.nets import GeodesicNet


@pytest.fixture(scope="module")
def basis():
    shapes = []
    for seed in range(6):
        mesh = trimesh.creation.icosphere(subdivisions=2)
        scale = np.random.default_rng(seed).uniform(0.3, 0.6, 3)
        shapes.append((np.asarray(mesh.vertices) * scale, np.asarray(mesh.faces)))
    return fit_basis(
        shapes,
        grid=VoxelGrid(resolution=25, pitch=0.06),
        std_threshold=0.1,
        n_components=4,
        n_udf_samples=300,
        seed=0,
    )


@pytest.fixture()
def network():
    torch.manual_seed(0)
    net = GeodesicNet(width=16, descriptor_dim=4)
    net.set_coord_normalization([0.1, 0.0, -0.1], [0.3, 0.2, 0.1])
    return net.eval()


def _outputs(net):
    generator = torch.Generator().manual_seed(1)
    src, dst = torch.randn(5, 3, generator=generator), torch.randn(5, 3, generator=generator)
    desc = torch.randn(5, 4, generator=generator)
    with torch.no_grad():
        return net(src, dst, desc, desc)


def test_round_trip(tmp_path, basis, network):
    manifest = save_bundle(
        tmp_path / "b",
        name="toy",
        category="toy",
        basis=basis,
        network=network,
        metrics={"mean_error": 1.0},
    )
    bundle = load_bundle(tmp_path / "b")
    assert bundle.content_hash == manifest["content_hash"] and bundle.category == "toy"
    assert bundle.basis == basis and not bundle.network.training
    torch.testing.assert_close(_outputs(bundle.network), _outputs(network))
    assert bundle.manifest["metrics"] == {"mean_error": 1.0}


def test_float16_weights_are_close_and_smaller(tmp_path, basis):
    torch.manual_seed(0)
    network = GeodesicNet(width=64, descriptor_dim=4).eval()  # wide enough that weights dominate
    save_bundle(tmp_path / "a", name="t", category="t", basis=basis, network=network)
    save_bundle(
        tmp_path / "h",
        name="t",
        category="t",
        basis=basis,
        network=network,
        weights_dtype=torch.float16,
    )
    assert (tmp_path / "h" / NETWORK_FILE).stat().st_size < (
        tmp_path / "a" / NETWORK_FILE
    ).stat().st_size * 0.6
    half = load_bundle(tmp_path / "h").network
    torch.testing.assert_close(half.coord_std, network.coord_std)
    torch.testing.assert_close(_outputs(half), _outputs(network), atol=2e-2, rtol=2e-2)


def test_tampered_files_are_refused(tmp_path, basis, network):
    save_bundle(tmp_path / "b", name="t", category="t", basis=basis, network=network)
    weights = tmp_path / "b" / NETWORK_FILE
    data = bytearray(weights.read_bytes())
    data[-1] ^= 0xFF
    weights.write_bytes(bytes(data))
    with pytest.raises(ArtifactError, match="hash"):
        load_bundle(tmp_path / "b")


def test_missing_and_inconsistent_bundles(tmp_path, basis, network):
    with pytest.raises(ArtifactError):
        load_bundle(tmp_path / "nothing")
    with pytest.raises(InputError):
        save_bundle(
            tmp_path / "x",
            name="t",
            category="t",
            basis=basis,
            network=GeodesicNet(width=16, descriptor_dim=5),
        )
    save_bundle(tmp_path / "b", name="t", category="t", basis=basis, network=network)
    manifest = json.loads((tmp_path / "b" / MANIFEST).read_text())
    manifest["network"]["descriptor_dim"] = 7
    (tmp_path / "b" / MANIFEST).write_text(json.dumps(manifest))
    with pytest.raises(ArtifactError):
        load_bundle(tmp_path / "b")
    (tmp_path / "b" / BASIS_FILE).unlink()
    with pytest.raises(ArtifactError):
        load_bundle(tmp_path / "b")


def test_unreadable_bundle_paths_and_manifests_are_artifact_errors(tmp_path, basis, network):
    """A file as bundle, a manifest that is a directory, not UTF-8 or has a list of files."""
    (tmp_path / "file").write_text("not a bundle")
    with pytest.raises(ArtifactError, match="no model bundle"):
        load_bundle(tmp_path / "file")
    save_bundle(tmp_path / "b", name="t", category="t", basis=basis, network=network)
    manifest = tmp_path / "b" / MANIFEST
    manifest.write_text(json.dumps({"files": [BASIS_FILE]}))
    with pytest.raises(ArtifactError, match="'files'"):
        load_bundle(tmp_path / "b")
    manifest.write_bytes(b"\xff\xfe\x00")
    with pytest.raises(ArtifactError, match="not valid JSON"):
        load_bundle(tmp_path / "b")
    manifest.unlink()
    manifest.mkdir()
    with pytest.raises(ArtifactError, match="cannot read"):
        load_bundle(tmp_path / "b")


def test_float16_export_keeps_large_buffers_finite(tmp_path, basis):
    torch.manual_seed(0)
    network = GeodesicNet(width=16, descriptor_dim=4).eval()
    network.final_layers[1].running_var.fill_(1e6)  # beyond float16's range (65504)
    save_bundle(
        tmp_path / "b",
        name="t",
        category="t",
        basis=basis,
        network=network,
        weights_dtype=torch.float16,
    )
    loaded = load_bundle(tmp_path / "b").network
    assert loaded.final_layers[1].running_var.max().item() == 1e6
    network.final_layers[0].weight.data[0, 0] = 1e9  # a parameter that float16 cannot hold
    with pytest.raises(InputError, match="not finite"):
        save_bundle(
            tmp_path / "c",
            name="t",
            category="t",
            basis=basis,
            network=network,
            weights_dtype=torch.float16,
        )


# --------------------------------------------------------------------------- the shared format


def test_shipped_bundles_keep_their_content_hashes():
    """The format did not move: every shipped manifest's content hash is still what the shared
    writer computes from its file hashes and settings, and the loaders accept them."""
    directories = shipped_directories(GEODESIC) + shipped_directories(KIND)
    assert {d.name for d in directories} >= {"quadrupeds", "humans", "quadrupeds-matching"}
    not_core = {"files", "training", "metrics", "created", "content_hash"}
    for directory in directories:
        manifest = json.loads((directory / MANIFEST).read_text())
        core = {k: v for k, v in manifest.items() if k not in not_core}
        assert core == manifest_core(manifest)
        assert _content_hash(manifest["files"], core) == manifest["content_hash"], directory
        load = load_matching_bundle if manifest.get("kind") == KIND else load_bundle
        bundle = load(directory)
        assert isinstance(bundle, Bundle) and bundle.content_hash == manifest["content_hash"]
        assert bundle.kind == manifest.get("kind", GEODESIC)


def test_geodesic_and_matching_bundles_share_the_format(tmp_path, basis, network):
    geodesic = save_bundle(tmp_path / "g", name="t", category="toy", basis=basis, network=network)
    assert "kind" not in geodesic  # the geodesic format predates the key
    assert list(geodesic) == [
        "format_version",
        "name",
        "version",
        "category",
        "pipeline",
        "network",
        "descriptor",
        "files",
        "training",
        "metrics",
        "created",
        "content_hash",
    ]
    matching = save_tiny_matching_bundle(tmp_path / "m")
    assert matching["kind"] == KIND and matching["descriptor"]["n_components"] > 0
    assert list(matching["files"]) == [BASIS_FILE, "tnet.safetensors", "matching-0.safetensors"]
    bundle = load_bundle(tmp_path / "g")
    assert (bundle.kind, bundle.category, bundle.device) == (GEODESIC, "toy", torch.device("cpu"))
    with pytest.raises(ArtifactError, match="not a model bundle"):
        load_bundle(tmp_path / "m")
    with pytest.raises(ArtifactError, match="not a matching bundle"):
        load_matching_bundle(tmp_path / "g")


def test_a_bundle_of_another_format_version_is_refused(tmp_path, basis, network):
    save_bundle(tmp_path / "b", name="t", category="t", basis=basis, network=network)
    manifest = json.loads((tmp_path / "b" / MANIFEST).read_text())
    manifest["format_version"] = 2
    (tmp_path / "b" / MANIFEST).write_text(json.dumps(manifest))
    with pytest.raises(ArtifactError, match="format 1"):
        load_bundle(tmp_path / "b")


def test_replace_basis_stores_int8_components_and_rehashes(tmp_path, basis, network):
    before = save_bundle(
        tmp_path / "b", name="t", category="t", basis=basis, network=network, metrics={"m": 1}
    )
    small = basis.with_component_storage("int8")
    after = replace_basis(tmp_path / "b", small)
    assert after["content_hash"] != before["content_hash"]
    assert after["descriptor"]["basis_hash"] == small.content_hash
    assert after["metrics"] == {"m": 1} and after["training"] == before["training"]
    assert after["files"][NETWORK_FILE] == before["files"][NETWORK_FILE]
    bundle = load_bundle(tmp_path / "b")
    assert bundle.content_hash == after["content_hash"] and bundle.basis == small
    assert bundle.basis.component_storage == "int8"
    torch.testing.assert_close(_outputs(bundle.network), _outputs(network))
    with pytest.raises(ArtifactError, match="voxels and size"):
        replace_basis(tmp_path / "b", basis.truncate(2))
    assert load_bundle(tmp_path / "b").content_hash == after["content_hash"]  # nothing written
