import json

import numpy as np
import pytest
import trimesh

from litege_core.datasets import DatasetSpec, GeodesicDataset, build_dataset, preset, verify_dataset
from litege_core.datasets.build import extra_sources
from litege_core.datasets.storage import MANIFEST
from litege_core.engines import compute_distances
from litege_core.errors import ArtifactError, InputError
from litege_core.shape import Shape

SPHERE = trimesh.creation.icosphere(subdivisions=2)


class EllipsoidFactory:
    """Toy family: the icosphere scaled anisotropically by a seeded factor per family."""

    category = "toy"
    version = "toy-1"

    def template(self):
        return np.asarray(SPHERE.vertices), np.asarray(SPHERE.faces)

    def generate(self, family, seed):
        rng = np.random.default_rng(seed)
        base = {"round": 1.0, "long": 2.0}[family]
        return np.asarray(SPHERE.vertices) * [base * rng.uniform(0.9, 1.1), 1.0, 0.8]


def edge_dijkstra(vertices, faces, sources):
    """Cheap stand-in for the exact solver: the library's edge-graph Dijkstra rows."""
    shape = Shape.from_arrays(vertices, faces)
    return compute_distances(shape, sources, method="edge_dijkstra").distances


def toy_spec(**overrides):
    options = dict(
        name="toy",
        category="toy",
        families=("round", "long"),
        n_shapes={"train": 5, "val": 2, "test": 3},
        n_shared_sources=6,
        n_extra_sources=3,
        shard_size=2,
    )
    options.update(overrides)
    return DatasetSpec(**options)


def test_build_layout_contents_and_determinism(tmp_path):
    spec = toy_spec()
    manifest = build_dataset(
        spec, tmp_path / "a", EllipsoidFactory(), distance_fn=edge_dijkstra, progress=False
    )
    assert manifest["counts"] == {"train": 5, "val": 2, "test": 3}
    assert len(manifest["shards"]) == 3 + 1 + 2
    assert manifest["distance_dtype"] == {"train": "float16", "val": "float32", "test": "float32"}
    dataset = GeodesicDataset(tmp_path / "a")
    train = dataset.load_split("train")
    assert train["vertices"].shape == (5, 162, 3) and train["vertices"].dtype == np.float32
    assert train["distances"].shape == (5, 9, 162) and train["distances"].dtype == np.float16
    assert dataset.load_split("test")["distances"].dtype == np.float32
    np.testing.assert_array_equal(train["seed"], np.arange(5))
    np.testing.assert_array_equal(train["family"], [0, 1, 0, 1, 0])
    np.testing.assert_array_equal(dataset.load_split("val")["seed"], [1_000_000, 1_000_001])
    # Shared sources come first on every shape; rows are correct distances.
    assert (train["sources"][:, :6] == dataset.shared_sources).all()
    factory = EllipsoidFactory()
    expected = edge_dijkstra(factory.generate("long", 1), dataset.faces, train["sources"][1])
    np.testing.assert_allclose(train["distances"][1], expected, rtol=1e-3)
    assert all(e["max_relative_storage_error"] <= 2**-11 for e in manifest["shards"].values())
    # A second build with the same spec gives byte-identical shards.
    build_dataset(spec, tmp_path / "b", factory, distance_fn=edge_dijkstra, progress=False)
    second = json.loads((tmp_path / "b" / MANIFEST).read_text())
    assert {k: v["sha256"] for k, v in second["shards"].items()} == {
        k: v["sha256"] for k, v in manifest["shards"].items()
    }


def test_parallel_build_equals_serial(tmp_path):
    spec = toy_spec(n_shapes={"train": 4, "val": 0, "test": 0})
    serial = build_dataset(
        spec, tmp_path / "s", EllipsoidFactory(), distance_fn=edge_dijkstra, progress=False
    )
    parallel = build_dataset(
        spec,
        tmp_path / "p",
        EllipsoidFactory(),
        workers=2,
        distance_fn=edge_dijkstra,
        progress=False,
    )
    assert [e["sha256"] for e in serial["shards"].values()] == [
        e["sha256"] for e in parallel["shards"].values()
    ]


def test_first_index_continues_the_seed_sequence_without_repeating_a_shape(tmp_path):
    factory = EllipsoidFactory()
    whole = build_dataset(
        toy_spec(n_shapes={"train": 5, "val": 0, "test": 0}),
        tmp_path / "whole",
        factory,
        distance_fn=edge_dijkstra,
        progress=False,
    )
    first = build_dataset(
        toy_spec(name="first", n_shapes={"train": 2, "val": 0, "test": 0}),
        tmp_path / "first",
        factory,
        distance_fn=edge_dijkstra,
        progress=False,
    )
    rest = build_dataset(
        toy_spec(name="rest", n_shapes={"train": 3, "val": 1, "test": 0}, first_index=2),
        tmp_path / "rest",
        factory,
        distance_fn=edge_dijkstra,
        progress=False,
    )
    assert whole["counts"]["train"] == first["counts"]["train"] + rest["counts"]["train"]
    full = GeodesicDataset(tmp_path / "whole").load_split("train")
    head = GeodesicDataset(tmp_path / "first").load_split("train")
    tail = GeodesicDataset(tmp_path / "rest").load_split("train")
    np.testing.assert_array_equal(tail["seed"], [2, 3, 4])
    np.testing.assert_array_equal(tail["family"], full["family"][2:])
    for key in ("vertices", "sources", "distances"):
        np.testing.assert_array_equal(np.concatenate([head[key], tail[key]]), full[key])
    val = GeodesicDataset(tmp_path / "rest").load_split("val")
    np.testing.assert_array_equal(val["seed"], [1_000_002])
    assert rest["spec"]["first_index"] == 2 and "first_index" not in whole["spec"]


@pytest.mark.parametrize("first_index", [-1, 999_998, True])
def test_first_index_must_keep_seeds_inside_their_split(first_index):
    with pytest.raises(InputError, match="first_index"):
        toy_spec(first_index=first_index)


def test_resume_recomputes_only_missing_or_damaged_shards(tmp_path):
    spec = toy_spec()
    calls = []

    def counting(vertices, faces, sources):
        calls.append(1)
        return edge_dijkstra(vertices, faces, sources)

    build_dataset(spec, tmp_path, EllipsoidFactory(), distance_fn=counting, progress=False)
    assert len(calls) == 10
    (tmp_path / "train-00001.safetensors").unlink()
    damaged = tmp_path / "test-00000.safetensors"
    damaged.write_bytes(damaged.read_bytes()[:-10] + b"0123456789")
    with pytest.raises(ArtifactError):
        verify_dataset(tmp_path)
    calls.clear()
    build_dataset(spec, tmp_path, EllipsoidFactory(), distance_fn=counting, progress=False)
    assert len(calls) == 4  # two shards of two shapes each
    assert verify_dataset(tmp_path)["counts"] == {"train": 5, "val": 2, "test": 3}


def test_refuses_to_mix_specs(tmp_path):
    build_dataset(
        toy_spec(), tmp_path, EllipsoidFactory(), distance_fn=edge_dijkstra, progress=False
    )
    with pytest.raises(ArtifactError):
        build_dataset(
            toy_spec(n_extra_sources=4),
            tmp_path,
            EllipsoidFactory(),
            distance_fn=edge_dijkstra,
            progress=False,
        )


def test_an_output_directory_that_cannot_be_made_is_an_input_error(tmp_path):
    """``--out`` under a file, or a file itself: a clear InputError, not an OSError."""
    (tmp_path / "file").write_text("x")
    for out in (tmp_path / "file" / "x", tmp_path / "file"):
        with pytest.raises(InputError, match="cannot create output directory"):
            build_dataset(toy_spec(), out, EllipsoidFactory(), distance_fn=edge_dijkstra)


def test_a_spec_without_shapes_is_refused_and_a_complete_build_keeps_its_manifest(tmp_path):
    """Zero shapes in all is "nothing to build"; re-running a finished build changes nothing."""
    with pytest.raises(InputError, match="nothing to build"):
        toy_spec(n_shapes={"train": 0, "val": 0, "test": 0})
    spec = toy_spec(n_shapes={"train": 1, "val": 0, "test": 0})
    first = build_dataset(spec, tmp_path, EllipsoidFactory(), distance_fn=edge_dijkstra)
    again = build_dataset(spec, tmp_path, EllipsoidFactory(), distance_fn=edge_dijkstra)
    assert again["shards"] == first["shards"] and (tmp_path / MANIFEST).is_file()
    assert verify_dataset(tmp_path)["counts"] == {"train": 1, "val": 0, "test": 0}


def test_exact_engine_rows(tmp_path):
    spec = toy_spec(n_shapes={"train": 0, "val": 0, "test": 1})
    build_dataset(spec, tmp_path, EllipsoidFactory(), progress=False)
    test = GeodesicDataset(tmp_path).load_split("test")
    rows, vertices = test["distances"][0], test["vertices"][0].astype(np.float64)
    euclid = np.linalg.norm(vertices[test["sources"][0]][:, None] - vertices[None], axis=2)
    upper = edge_dijkstra(vertices, GeodesicDataset(tmp_path).faces, test["sources"][0])
    assert (rows >= euclid - 1e-5).all() and (rows <= upper + 1e-5).all()


def test_extra_sources_are_seeded_and_disjoint():
    shared = np.arange(10)
    first = extra_sources(100, shared, 5, seed=3)
    np.testing.assert_array_equal(first, extra_sources(100, shared, 5, seed=3))
    assert not np.intersect1d(first, shared).size


def test_spec_validation_and_presets():
    with pytest.raises(InputError):
        toy_spec(families=())
    with pytest.raises(InputError):
        toy_spec(n_shapes={"holdout": 3})
    with pytest.raises(InputError):
        preset("huge", "quadruped")
    small = preset("small", "quadruped")
    assert sum(small.n_shapes.values()) >= 500 and len(small.families) == 5
    assert sum(preset("full", "quadruped").n_shapes.values()) >= 10_000
    assert DatasetSpec.from_dict(json.loads(small.to_json())) == small


def test_heat_solver_is_recorded_close_to_exact_and_not_mixed_on_resume(tmp_path):
    spec = toy_spec(n_shapes={"train": 2, "val": 0, "test": 0}, n_extra_sources=0)
    manifest = build_dataset(
        spec, tmp_path / "h", EllipsoidFactory(), solver="heat", progress=False
    )
    assert manifest["solver"].startswith("heat method")
    arrays = GeodesicDataset(tmp_path / "h").load_split("train")
    shape = Shape.from_arrays(arrays["vertices"][0].astype(np.float64), SPHERE.faces)
    exact = compute_distances(shape, arrays["sources"][0], method="exact").distances
    positive = exact > 0
    relative = np.abs(arrays["distances"][0][positive] - exact[positive]) / exact[positive]
    assert relative.mean() < 0.05
    with pytest.raises(ArtifactError, match="solver"):
        build_dataset(spec, tmp_path / "h", EllipsoidFactory(), solver="exact", progress=False)
    with pytest.raises(InputError, match="unknown solver"):
        build_dataset(spec, tmp_path / "x", EllipsoidFactory(), solver="guess", progress=False)


def test_matching_preset_keeps_only_shared_sources():
    spec = preset("matching", "quadruped")
    assert spec.n_extra_sources == 0 and spec.n_shapes["test"] == 0
    assert spec.n_shapes["train"] >= 100 and spec.n_shapes["val"] >= 16


def test_the_procedural_factory_poses_its_steep_share_and_names_it():
    from litege_core.datasets.factories import SynthFactory, factory_for
    from litege_core.synth import GENERATOR_VERSION, generate_shape
    from litege_core.synth.poses import steep_pose

    plain, steep = factory_for("quadruped"), factory_for("quadruped", steep_share=0.5)
    assert isinstance(steep, SynthFactory)
    assert plain.version == GENERATOR_VERSION
    # a build never resumes the other, nor one of the two-mode revision 1 (rearing, leaping)
    assert steep.version == f"{GENERATOR_VERSION}+steep0.5r3"
    seed = next(s for s in range(100) if steep_pose("quadruped", s, 0.5))
    mode = steep_pose("quadruped", seed, 0.5)
    np.testing.assert_array_equal(
        steep.generate("cat", seed), generate_shape("quadruped", "cat", seed, mode).vertices
    )
    drawn = next(s for s in range(100) if steep_pose("quadruped", s, 0.5) is None)
    np.testing.assert_array_equal(steep.generate("cat", drawn), plain.generate("cat", drawn))
    for category, share in (("quadruped", 1.5), ("quadruped", -0.1), ("biped", 0.3)):
        with pytest.raises(InputError):
            factory_for(category, steep_share=share)


def test_the_procedural_factory_widens_proportions_by_its_spread_and_names_it():
    from litege_core.datasets.factories import factory_for
    from litege_core.synth import GENERATOR_VERSION, generate_shape

    wide = factory_for("quadruped", steep_share=0.5, spread=3.0)
    assert wide.version == f"{GENERATOR_VERSION}+steep0.5r3+spread3"
    assert factory_for("quadruped", spread=1.0).version == GENERATOR_VERSION
    np.testing.assert_array_equal(
        factory_for("quadruped", spread=2.0).generate("horse", 3),
        generate_shape("quadruped", "horse", 3, spread=2.0).vertices,
    )
    lean = factory_for("quadruped", spread=3.0, girth_std=0.3)
    assert lean.version == f"{GENERATOR_VERSION}+spread3+girth0.3"
    np.testing.assert_array_equal(
        lean.generate("dog", 4),
        generate_shape("quadruped", "dog", 4, spread=3.0, girth_std=0.3).vertices,
    )
    for category, spread, girth in (("quadruped", 0.0, 0.0), ("rigged", 2.0, 0.0)):
        with pytest.raises(InputError):
            factory_for(category, "../shared/train-data", spread=spread, girth_std=girth)
    for category, girth in (("quadruped", -0.1), ("makehuman", 0.3)):
        with pytest.raises(InputError):
            factory_for(category, "../shared/train-data", girth_std=girth)
