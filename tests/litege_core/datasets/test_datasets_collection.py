"""Collection datasets: shapes with their own triangulations (padded shards, per-shape
farthest-point sources), resumable, verifiable, deterministic; folder datasets."""

import json

import numpy as np
import pytest
import trimesh

from litege_core.datasets import (
    DatasetSpec,
    GeodesicDataset,
    build_collection_dataset,
    build_dataset,
    collection_preset,
    folder_spec,
    preset,
    shape_mesh,
    verify_dataset,
)
from litege_core.datasets.build import shape_sources
from litege_core.datasets.storage import MANIFEST
from litege_core.engines import compute_distances
from litege_core.errors import ArtifactError, InputError
from litege_core.shape import Shape


class BlobFactory:
    """Toy collection: icospheres of 1 or 2 subdivisions (42 / 162 vertices) by family,
    scaled anisotropically by a seeded factor."""

    category = "blobs"
    version = "blobs-1"

    def generate_mesh(self, family, seed):
        sphere = trimesh.creation.icosphere(subdivisions={"small": 1, "large": 2}[family])
        rng = np.random.default_rng(seed)
        return np.asarray(sphere.vertices) * rng.uniform(0.7, 1.3, size=3), np.asarray(sphere.faces)


def edge_dijkstra(vertices, faces, sources):
    return compute_distances(
        Shape.from_arrays(vertices, faces), sources, method="edge_dijkstra"
    ).distances


def blob_spec(**overrides):
    options = dict(
        name="blobs",
        category="blobs",
        families=("small", "large"),
        n_shapes={"train": 5, "val": 2, "test": 1},
        n_shared_sources=5,
        n_extra_sources=3,
        shard_size=2,
        kind="collection",
    )
    options.update(overrides)
    return DatasetSpec(**options)


def _build(spec, directory, distance_fn=edge_dijkstra, **kwargs):
    return build_dataset(
        spec, directory, BlobFactory(), distance_fn=distance_fn, progress=False, **kwargs
    )


def test_collection_layout_padding_and_rows(tmp_path):
    manifest = _build(blob_spec(), tmp_path / "a")
    assert manifest["format_version"] == 2 and manifest["kind"] == "collection"
    assert manifest["counts"] == {"train": 5, "val": 2, "test": 1}
    assert not (tmp_path / "a" / "template.safetensors").exists()
    dataset = GeodesicDataset(tmp_path / "a")
    assert dataset.is_collection and dataset.faces is None and dataset.shared_sources is None
    train = dataset.load_split("train")
    np.testing.assert_array_equal(train["n_vertices"], [42, 162, 42, 162, 42])
    np.testing.assert_array_equal(train["n_faces"], [80, 320, 80, 320, 80])
    assert train["vertices"].shape == (5, 162, 3) and train["faces"].shape == (5, 320, 3)
    assert train["distances"].shape == (5, 8, 162) and train["distances"].dtype == np.float16
    assert (train["faces"][0, 80:] == -1).all() and (train["vertices"][0, 42:] == 0).all()
    assert (train["distances"][0][:, 42:] == 0).all()
    for index, family in enumerate(["small", "large", "small", "large", "small"]):
        vertices, faces = shape_mesh(train, index)
        expected_vertices, expected_faces = BlobFactory().generate_mesh(family, index)
        np.testing.assert_allclose(vertices, expected_vertices, rtol=1e-6)
        np.testing.assert_array_equal(faces, expected_faces)
        sources = shape_sources(expected_vertices, 5, 3, index)
        np.testing.assert_array_equal(train["sources"][index], sources)
        rows = edge_dijkstra(expected_vertices, expected_faces, sources)
        np.testing.assert_allclose(train["distances"][index][:, : len(vertices)], rows, rtol=1e-3)
    assert dataset.load_split("test")["distances"].dtype == np.float32
    assert verify_dataset(tmp_path / "a")["counts"] == {"train": 5, "val": 2, "test": 1}
    # deterministic: a second build gives byte-identical shards; parallel equals serial
    second = _build(blob_spec(), tmp_path / "b", workers=2)
    assert {k: v["sha256"] for k, v in second["shards"].items()} == {
        k: v["sha256"] for k, v in manifest["shards"].items()
    }


def test_collection_resume_verify_and_spec_guard(tmp_path):
    calls = []

    def counting(vertices, faces, sources):
        calls.append(len(vertices))
        return edge_dijkstra(vertices, faces, sources)

    _build(blob_spec(), tmp_path, counting)
    assert len(calls) == 8
    (tmp_path / "train-00002.safetensors").unlink()
    damaged = tmp_path / "val-00000.safetensors"
    damaged.write_bytes(damaged.read_bytes()[:-8] + b"01234567")
    with pytest.raises(ArtifactError):
        verify_dataset(tmp_path)
    calls.clear()
    _build(blob_spec(), tmp_path, counting)
    assert len(calls) == 3  # one shape of the last train shard, two of the val shard
    verify_dataset(tmp_path)
    with pytest.raises(ArtifactError, match="spec"):
        _build(blob_spec(n_extra_sources=4), tmp_path)


def test_verify_catches_a_wrong_source_row(tmp_path):
    def shifted(vertices, faces, sources):
        return edge_dijkstra(vertices, faces, sources) + 1.0

    _build(blob_spec(n_shapes={"train": 0, "val": 1, "test": 0}), tmp_path, shifted)
    with pytest.raises(ArtifactError, match="source"):
        verify_dataset(tmp_path)


def test_exact_rows_on_a_collection_shape(tmp_path):
    spec = blob_spec(
        n_shapes={"train": 0, "val": 0, "test": 1}, n_shared_sources=3, n_extra_sources=0
    )
    build_dataset(spec, tmp_path, BlobFactory(), progress=False)
    test = GeodesicDataset(tmp_path).load_split("test")
    vertices, faces = shape_mesh(test, 0)
    rows = test["distances"][0][:, : len(vertices)]
    euclid = np.linalg.norm(vertices[test["sources"][0]][:, None] - vertices[None], axis=2)
    upper = edge_dijkstra(vertices, faces, test["sources"][0])
    assert (rows >= euclid - 1e-5).all() and (rows <= upper + 1e-5).all()
    verify_dataset(tmp_path)


def test_template_specs_serialize_as_before_and_collection_specs_round_trip():
    spec = preset("large", "quadruped")
    data = json.loads(spec.to_json())
    assert "kind" not in data and "split_families" not in data
    assert DatasetSpec.from_dict(data) == spec
    folder = blob_spec(split_families={"train": ("small",), "val": ("large",), "test": ("large",)})
    assert DatasetSpec.from_dict(json.loads(folder.to_json())) == folder
    assert folder.shape_key("train", 3) == ("small", 3)
    assert folder.shape_key("val", 1) == ("large", 1_000_001)
    with pytest.raises(InputError):
        blob_spec(kind="mosaic")
    with pytest.raises(InputError):
        blob_spec(split_families={"train": ("medium",)})


def test_collection_presets():
    rigged = collection_preset("small", "rigged")
    assert rigged.is_collection and len(rigged.families) == 12
    assert preset("large", "rigged").n_shapes["train"] >= 2000
    humans = preset("small", "makehuman")
    assert humans.families == ("makehuman",) and sum(humans.n_shapes.values()) >= 500
    with pytest.raises(InputError):
        collection_preset("huge", "rigged")


def test_folder_dataset_build_resume_and_split(tmp_path):
    meshes = tmp_path / "meshes"
    meshes.mkdir()
    for i, subdivisions in enumerate((1, 2, 1)):
        sphere = trimesh.creation.icosphere(subdivisions=subdivisions)
        sphere.vertices *= [1.0 + 0.3 * i, 1.0, 0.8]
        sphere.export(meshes / f"shape{i}.ply")
    spec = folder_spec(
        meshes, shapes_per_mesh=2, eval_shapes_per_mesh=1, n_sources=4, n_extra_sources=2
    )
    assert spec.n_shapes == {"train": 2, "val": 1, "test": 1}
    assert len({spec.split_families[s][0] for s in ("train", "val", "test")}) == 3
    from litege_core.synth.folder import FolderSettings

    settings = FolderSettings(vertex_range=(150, 200))
    kwargs = dict(
        shapes_per_mesh=2,
        eval_shapes_per_mesh=1,
        n_sources=4,
        n_extra_sources=2,
        settings=settings,
        progress=False,
    )
    manifest = build_collection_dataset(meshes, tmp_path / "data", **kwargs)
    assert manifest["counts"] == {"train": 2, "val": 1, "test": 1}
    assert manifest["generator"]["version"].startswith("folder-2:")
    again = build_collection_dataset(meshes, tmp_path / "data", **kwargs)  # resume: nothing to do
    assert again["shards"] == manifest["shards"]
    train = GeodesicDataset(tmp_path / "data").load_split("train")
    assert (train["n_vertices"] >= 140).all() and (train["n_vertices"] <= 220).all()
    verify_dataset(tmp_path / "data")
    # changed files never resume into the old dataset
    (meshes / "shape0.ply").write_bytes((meshes / "shape1.ply").read_bytes())
    with pytest.raises(ArtifactError, match="generator"):
        build_collection_dataset(meshes, tmp_path / "data", **kwargs)
    (tmp_path / "json").mkdir()
    with pytest.raises(InputError):
        folder_spec(tmp_path / "json")
    assert json.loads((tmp_path / "data" / MANIFEST).read_text())["kind"] == "collection"


def test_a_dataset_started_before_the_engines_rename_resumes(tmp_path):
    spec = blob_spec(n_shapes={"train": 0, "val": 2, "test": 0})
    build_dataset(spec, tmp_path, BlobFactory(), progress=False)
    path = tmp_path / MANIFEST
    manifest = json.loads(path.read_text())
    manifest["solver"] = "exact MMP (litege_core.geodesics, method='exact')"
    path.write_text(json.dumps(manifest))
    build_dataset(spec, tmp_path, BlobFactory(), progress=False)  # no ArtifactError
    manifest["solver"] = (
        "heat method (litege_core.geodesics, method='heat'; ~2 % mean relative error vs exact)"
    )
    path.write_text(json.dumps(manifest))
    with pytest.raises(ArtifactError, match="solver"):
        build_dataset(spec, tmp_path, BlobFactory(), progress=False)
