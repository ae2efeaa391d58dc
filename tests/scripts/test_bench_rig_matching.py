"""scripts/bench_rig_matching.py: the held-out pose pairs it scores."""

import numpy as np

from litege_core.datasets import DatasetSpec, build_dataset
from litege_core.train.matching_from_meshes import FolderTemplateFactory


def test_held_out_pairs_are_turned_poses_whose_truth_is_the_same_vertex(
    bench_rig_matching, tmp_path, rigged_gltf
):
    folder = bench_rig_matching.link_rig(rigged_gltf(tmp_path / "capsule.gltf"), tmp_path / "rig")
    assert bench_rig_matching.link_rig(tmp_path / "capsule.gltf", folder) == folder  # once
    factory = FolderTemplateFactory(str(folder), ("capsule.gltf",), "x", poses=True)
    spec = DatasetSpec(
        name="rig",
        category="folder-template",
        families=("capsule.gltf",),
        n_shapes={"train": 1, "val": 0, "test": 4},
        n_shared_sources=4,
        n_extra_sources=0,
        shard_size=4,
    )
    build_dataset(spec, tmp_path / "data", factory, solver="heat", progress=False)
    pairs = bench_rig_matching.held_out_pairs(tmp_path / "data", 3, 20, seed=0)
    assert [p.name for p in pairs] == ["pose0→pose1", "pose1→pose2", "pose2→pose3"]
    first = pairs[0]
    np.testing.assert_array_equal(first.queries, first.truth)
    assert len(np.unique(first.queries)) == 20
    perfect = first.errors(first.truth)[0]
    assert np.allclose(perfect, 0.0)  # matching each query to itself costs nothing
    wrong = first.errors(np.roll(first.truth, 1))[0]
    assert wrong.mean() > 0.05  # … and to another vertex a geodesic
    x = first.x.shape.vertices
    assert not np.allclose(x, pairs[0].y.shape.vertices)  # other poses, other turns
