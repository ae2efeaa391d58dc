"""T-Net training shapes: canonical frames, procedural, steep and collection sets, caches."""

import numpy as np
import pytest
import trimesh

from litege_core.train.tnet import (
    TNetTrainConfig,
    generate_shape_set,
    sample_batch,
)
from litege_core.train.tnet.shapes import collection_shape_set, training_shape_sets
from litege_core.validate import triangle_areas


def test_canonical_shapes_are_centred_unit_area(toy_shapes) -> None:
    train, _ = toy_shapes
    for v, f in zip(train.vertices, train.faces, strict=True):
        assert triangle_areas(v, f).sum() == pytest.approx(1.0)
        assert np.abs(v.mean(axis=0)).max() < 0.2  # centred on surface samples, not vertices


def test_generated_shapes_follow_the_dataset_convention_and_cache(tmp_path) -> None:
    first = generate_shape_set("quadruped", "val", 1, cache_dir=tmp_path)
    shapes = generate_shape_set("quadruped", "val", 2, cache_dir=tmp_path)  # extends the cache
    assert shapes.keys == [("cat", 1_000_000), ("dog", 1_000_001)]
    assert triangle_areas(shapes.vertices[1], shapes.faces[1]).sum() == pytest.approx(1.0)
    np.testing.assert_array_equal(shapes.vertices[0], first.vertices[0])
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        f"tnet-shapes-quadruped-val-{n}-synth-template-v1.npz" for n in (1, 2)
    ]
    again = generate_shape_set("quadruped", "val", 2, cache_dir=tmp_path)  # read back
    sliced = generate_shape_set("quadruped", "val", 1, cache_dir=tmp_path)
    for cached in (again, sliced):
        assert cached.keys == shapes.keys[: len(cached)]
        for a, b in zip(cached.vertices, shapes.vertices, strict=False):
            np.testing.assert_array_equal(a, b)
        np.testing.assert_array_equal(cached.faces[0], shapes.faces[0])


def test_steep_shapes_are_posed_and_cached_apart(tmp_path) -> None:
    from litege_core.synth import generate_shape
    from litege_core.synth.poses import steep_pose

    seed = next(s for s in range(1_000_000, 1_000_100) if steep_pose("quadruped", s, 0.5))
    n_shapes = seed - 1_000_000 + 1
    drawn = generate_shape_set("quadruped", "val", n_shapes, cache_dir=tmp_path)
    steep = generate_shape_set("quadruped", "val", n_shapes, cache_dir=tmp_path, steep_share=0.5)
    family = steep.keys[-1][0]
    posed = generate_shape("quadruped", family, seed, steep_pose("quadruped", seed, 0.5))
    centred = steep.vertices[-1] - steep.vertices[-1].mean(axis=0)
    expected = posed.vertices - posed.vertices.mean(axis=0)
    scale = np.linalg.norm(centred) / np.linalg.norm(expected)
    np.testing.assert_allclose(centred, expected * scale, atol=1e-9)  # same shape, same frame
    assert not np.allclose(steep.vertices[-1], drawn.vertices[-1])
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        f"tnet-shapes-quadruped-val-{n_shapes}-synth-template-v1+steep0.5r3.npz",
        f"tnet-shapes-quadruped-val-{n_shapes}-synth-template-v1.npz",
    ]


class _ToyCollection:
    """A stand-in collection factory: toy meshes of a size that depends on the seed."""

    category = "makehuman"

    def __init__(self, root: str, steep_share: float = 0.0) -> None:
        self.root = root
        self.version = "toy-1" + (f"+steep{steep_share:g}" if steep_share else "")

    def generate_mesh(self, family: str, seed: int) -> tuple[np.ndarray, np.ndarray]:
        assert family == "makehuman"
        sphere = trimesh.creation.icosphere(subdivisions=1 + seed % 2)
        return np.asarray(sphere.vertices) * [2.0, 1.0, 0.5] + seed, np.asarray(sphere.faces)


@pytest.fixture
def toy_collection(monkeypatch):
    import litege_core.datasets.factories as factories

    monkeypatch.setattr(
        factories,
        "factory_for",
        lambda source, root=None, pose=None, steep_share=0.0: _ToyCollection(root, steep_share),
    )


def test_collection_shapes_are_canonical_and_cached_ragged(toy_collection, tmp_path) -> None:
    first = collection_shape_set("makehuman", "train", 1, "assets", tmp_path)
    shapes = collection_shape_set("makehuman", "train", 3, "assets", tmp_path)  # extends the cache
    assert shapes.keys == [("makehuman", 0), ("makehuman", 1), ("makehuman", 2)]
    assert [len(v) for v in shapes.vertices] == [42, 162, 42]  # ragged: sizes differ per shape
    for v, f in zip(shapes.vertices, shapes.faces, strict=True):
        assert triangle_areas(v, f).sum() == pytest.approx(1.0)
        assert np.abs(v.mean(axis=0)).max() < 0.2  # the seed's offset is gone
    np.testing.assert_array_equal(first.vertices[0], shapes.vertices[0])
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        f"tnet-shapes-makehuman-train-{n}-toy-1.npz" for n in (1, 3)
    ]
    steep = collection_shape_set("makehuman", "train", 2, "assets", tmp_path, steep_share=0.4)
    assert (tmp_path / "tnet-shapes-makehuman-train-2-toy-1+steep0.4.npz").is_file()  # its own
    assert len(steep.vertices) == 2
    (tmp_path / "tnet-shapes-makehuman-train-2-toy-1+steep0.4.npz").unlink()
    again = collection_shape_set("makehuman", "train", 2, "assets", tmp_path)  # sliced from 3
    assert again.keys == shapes.keys[:2]
    for a, b, fa, fb in zip(
        again.vertices, shapes.vertices, again.faces, shapes.faces, strict=False
    ):
        np.testing.assert_array_equal(a, b)
        np.testing.assert_array_equal(fa, fb)
    assert len(list(tmp_path.iterdir())) == 2  # nothing generated, nothing written


def test_training_sets_append_the_extra_collection(toy_collection, tmp_path) -> None:
    config = TNetTrainConfig.from_dict(
        {
            "data": {
                "category": "quadruped",
                "n_train": 2,
                "n_val": 1,
                "extra_category": "makehuman",
                "n_extra_train": 2,
                "n_extra_val": 1,
                "cache_dir": str(tmp_path),
            }
        }
    )
    train, val = training_shape_sets(config.data)
    assert train.keys == [("cat", 0), ("dog", 1), ("makehuman", 0), ("makehuman", 1)]
    assert val.keys == [("cat", 1_000_000), ("makehuman", 1_000_000)]
    assert len(train.faces[0]) != len(train.faces[2])  # procedural and collection meshes mixed
    batch = sample_batch(train, config, step=0, batch_size=8)  # ragged sets sample as before
    assert batch.canonical.shape[0] == 8


def test_parallel_shape_generation_gives_the_serial_shapes() -> None:
    serial = generate_shape_set("quadruped", "val", 3)
    parallel = generate_shape_set("quadruped", "val", 3, workers=2)
    assert parallel.keys == serial.keys
    for a, b in zip(parallel.vertices, serial.vertices, strict=True):
        np.testing.assert_array_equal(a, b)
