"""MatchingModel: preparation, search against the exhaustive reference, serialization, errors."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from litege_core.errors import (
    ArrayShapeError,
    ArtifactError,
    CoordinateRangeError,
    IndexOutOfRangeError,
    InputError,
    NonFiniteError,
)
from litege_core.matching import (
    MatchingModel,
    MatchingShape,
    load_matching_bundle,
    save_matching_bundle,
)
from litege_core.matching.frame import choose_scaling
from litege_core.seams import boundary_edge_fraction
from litege_core.shape import Shape
from litege_core.synth import families, generate_shape


@pytest.fixture(scope="module")
def model() -> MatchingModel:
    return MatchingModel.tiny_random(0)


@pytest.fixture(scope="module")
def shapes() -> tuple[Shape, Shape]:
    names = families("quadruped")
    a = generate_shape("quadruped", names[0], 2_000_000)
    b = generate_shape("quadruped", names[1], 2_000_001)
    return Shape.from_arrays(a.vertices, a.faces), Shape.from_arrays(b.vertices, b.faces)


@pytest.fixture(scope="module")
def prepared(model, shapes):
    return model.prepare_many(list(shapes))


def test_prepare_puts_vertices_in_the_aligned_unit_area_frame(model, shapes, prepared):
    x, _ = prepared
    assert x.scaling == "unit_area" and x.kind == "mesh" and x.n_points == shapes[0].n_points
    np.testing.assert_allclose(x.aligned, x.transform.apply(shapes[0].vertices), atol=1e-5)
    rotation = x.transform.rotation
    np.testing.assert_allclose(rotation @ rotation.T, np.eye(3), atol=1e-9)
    assert np.linalg.det(rotation) == pytest.approx(1.0)
    aligned_area = Shape.from_arrays(x.aligned.astype(np.float64), shapes[0].faces)
    assert aligned_area.area == pytest.approx(1.0, rel=1e-4)


def test_prepare_is_deterministic_and_matches_the_batched_call(model, shapes, prepared):
    again = model.prepare(shapes[0])
    np.testing.assert_allclose(again.aligned, prepared[0].aligned, atol=1e-6)
    np.testing.assert_allclose(again.descriptor, prepared[0].descriptor, atol=1e-5)


def test_exhaustive_match_is_the_argmin_of_the_cross_distances(model, prepared):
    x, y = prepared
    queries = np.arange(0, x.n_points, 97)
    result = model.match(x, y, queries, exhaustive=True)
    table = model.cross_distances(x, y, queries, np.arange(y.n_points))
    np.testing.assert_array_equal(result.indices, table.argmin(axis=1))
    np.testing.assert_allclose(result.distance, table.min(axis=1), rtol=1e-5, atol=1e-7)
    assert result.evaluations == queries.size * y.n_points


def test_coarse_to_fine_scores_only_cache_candidates_and_returns_their_distance(model, prepared):
    x, y = prepared
    queries = np.arange(50)
    result = model.match(x, y, queries)
    assert result.indices.dtype == np.int64 and result.indices.shape == (50,)
    assert ((result.indices >= 0) & (result.indices < y.n_points)).all()
    assert result.evaluations < queries.size * y.n_points / 10
    direct = model.cross_distances(x, y, queries, result.indices).diagonal()
    np.testing.assert_allclose(result.distance, direct, rtol=1e-5, atol=1e-7)
    exhaustive = model.match(x, y, queries, exhaustive=True)
    assert (exhaustive.distance <= result.distance + 1e-7).all()


def test_query_points_equal_query_indices_on_the_same_vertices(model, shapes, prepared):
    x, y = prepared
    by_index = model.match(x, y, [3, 500, 1200])
    by_point = model.match(x, y, query_points=shapes[0].vertices[[3, 500, 1200]])
    np.testing.assert_array_equal(by_index.indices, by_point.indices)
    everything = model.match(x, y)
    assert everything.indices.shape == (x.n_points,)
    np.testing.assert_array_equal(everything.indices[[3, 500, 1200]], by_index.indices)


def test_arrays_round_trip_gives_identical_matches(model, prepared):
    x, y = prepared
    arrays = x.to_arrays()
    assert all(isinstance(v, np.ndarray) for v in arrays.values())
    restored = MatchingShape.from_arrays(arrays)
    a = model.match(restored, y, np.arange(64))
    b = model.match(x, y, np.arange(64))
    np.testing.assert_array_equal(a.indices, b.indices)


def test_malformed_arrays_are_an_artifact_error(prepared):
    arrays = prepared[0].to_arrays()
    broken = {k: v for k, v in arrays.items() if k != "descriptor"}
    with pytest.raises(ArtifactError):
        MatchingShape.from_arrays(broken)
    nan = dict(arrays, aligned=np.full_like(arrays["aligned"], np.nan))
    with pytest.raises(ArtifactError):
        MatchingShape.from_arrays(nan)


def test_bad_queries_raise_precise_errors(model, prepared):
    x, y = prepared
    with pytest.raises(IndexOutOfRangeError):
        model.match(x, y, [0, x.n_points])
    with pytest.raises(IndexOutOfRangeError):
        model.match(x, y, [-1])
    with pytest.raises(ArrayShapeError):
        model.match(x, y, [])
    with pytest.raises(NonFiniteError):
        model.match(x, y, query_points=[[0.0, np.nan, 0.0]])
    with pytest.raises(ArrayShapeError):
        model.match(x, y, query_points=[[0.0, 1.0]])
    with pytest.raises(InputError):
        model.match(x, y, [0], query_points=[[0.0, 0.0, 0.0]])
    with pytest.raises(InputError):
        model.match(x, y, [0.5])
    with pytest.raises(ArrayShapeError, match="integers"):  # the one rule: 1.0 is no index
        model.match(x, y, [1.0, 2.0])
    with pytest.raises(CoordinateRangeError):
        model.match(x, y, [[1e40, 0.0, 0.0]])


def test_xyz_queries_are_snapped_onto_the_mesh_surface(model, shapes, prepared):
    """The rule of the geodesic predictor: a point off a mesh is moved to its closest surface
    point before it is embedded, so lifting a query along the normal changes nothing."""
    import trimesh

    x, y = prepared
    mesh = trimesh.Trimesh(shapes[0].vertices, shapes[0].faces, process=False)
    rows = [3, 500, 1200]
    lifted = shapes[0].vertices[rows] + 0.01 * mesh.vertex_normals[rows]
    np.testing.assert_array_equal(
        model.match(x, y, lifted).indices, model.match(x, y, rows).indices
    )
    assert x.faces is not None and MatchingShape.from_arrays(x.to_arrays()).faces is not None


def test_shapes_prepared_by_another_model_are_refused(prepared):
    other = MatchingModel.tiny_random(1)
    with pytest.raises(InputError, match="another matching model"):
        other.match(prepared[0], prepared[1], [0])


def _save_copy(model, directory, category="test", **extra) -> None:
    """Write ``model``'s bundle again under ``directory`` (``extra``: more bundle parts)."""
    bundle = model.bundle
    save_matching_bundle(
        directory,
        name="tiny",
        category=category,
        basis=bundle.basis,
        tnet=bundle.tnet,
        networks=list(bundle.networks),
        pipeline=bundle.pipeline,
        search=bundle.search,
        **extra,
    )


def test_bundle_round_trip_keeps_matches_and_detects_tampering(model, prepared, tmp_path):
    _save_copy(model, tmp_path / "b")
    loaded = MatchingModel.load(tmp_path / "b")
    x, y = loaded.prepare_many(
        [Shape.from_arrays(p.aligned.astype(np.float64), None) for p in prepared]
    )
    reference = model.prepare_many(
        [Shape.from_arrays(p.aligned.astype(np.float64), None) for p in prepared]
    )
    a = loaded.match(x, y, np.arange(40))
    b = model.match(reference[0], reference[1], np.arange(40))
    np.testing.assert_array_equal(a.indices, b.indices)
    weights = tmp_path / "b" / "matching-0.safetensors"
    weights.write_bytes(weights.read_bytes()[:-8] + b"\0" * 8)
    with pytest.raises(ArtifactError, match="hash"):
        load_matching_bundle(tmp_path / "b")


def test_a_bundle_may_carry_its_own_frame_judge(model, tmp_path):
    from litege_core.nets import GeodesicNet, state_to_tensors

    judge = GeodesicNet.from_config(model.bundle.networks[0].config())  # other weights
    with torch.no_grad():
        for p in judge.parameters():
            p.add_(0.5)
    _save_copy(model, tmp_path / "plain", "quadruped")
    _save_copy(model, tmp_path / "judged", "quadruped", judge_networks=[judge])
    plain, judged = (MatchingModel.load(tmp_path / d) for d in ("plain", "judged"))
    assert plain.bundle.judge_networks == () and "judge_networks" not in plain.bundle.manifest
    assert plain.frame_judge.networks == list(plain.bundle.networks)
    (loaded,) = judged.bundle.judge_networks
    got, want = state_to_tensors(loaded), state_to_tensors(judge)
    assert all(torch.equal(got[k], want[k]) for k in want)
    assert judged.frame_judge.networks == [loaded]  # scores frames with its own network
    assert judged.content_hash != plain.content_hash
    weights = tmp_path / "judged" / "judge-0.safetensors"
    weights.write_bytes(weights.read_bytes()[:-8] + b"\0" * 8)
    with pytest.raises(ArtifactError, match="hash"):
        load_matching_bundle(tmp_path / "judged")


def test_scaling_is_chosen_from_the_input(model, shapes):
    mesh = shapes[0]
    assert choose_scaling(mesh, model.pipeline) == "unit_area"
    rng = np.random.default_rng(0)
    keep = rng.random(mesh.faces.shape[0]) > 0.4
    broken = Shape.from_arrays(mesh.vertices, mesh.faces[keep])
    assert boundary_edge_fraction(broken.faces) > 0.1
    assert choose_scaling(broken, model.pipeline) == "broken_mesh"
    corner = np.asarray(mesh.faces).reshape(-1)  # a soup of the mesh: whole once welded
    soup = Shape.from_arrays(mesh.vertices[corner], np.arange(corner.size).reshape(-1, 3))
    assert choose_scaling(soup, model.pipeline) == "unit_area"
    small = Shape.from_arrays(mesh.vertices[:500], None)
    large = Shape.from_arrays(mesh.vertices, None)
    assert choose_scaling(small, model.pipeline) == "cloud_500"
    assert choose_scaling(large, model.pipeline) == "cloud_8k"
    with pytest.raises(InputError):
        choose_scaling(small, model.pipeline, "unit_area")
    with pytest.raises(InputError):
        choose_scaling(mesh, model.pipeline, "sideways")


def test_point_clouds_and_broken_meshes_match_end_to_end(model, shapes, prepared):
    rng = np.random.default_rng(1)
    cloud = Shape.from_arrays(shapes[0].vertices[rng.choice(shapes[0].n_points, 500, False)], None)
    keep = rng.random(shapes[1].faces.shape[0]) > 0.4
    broken = Shape.from_arrays(shapes[1].vertices, shapes[1].faces[keep])
    pc, pb = model.prepare_many([cloud, broken])
    assert (pc.scaling, pb.scaling) == ("cloud_500", "broken_mesh")
    result = model.match(pc, pb)
    assert result.indices.shape == (500,) and result.indices.max() < broken.n_points


def test_stray_points_of_a_target_cloud_are_never_matched(model, shapes, prepared):
    """A cloud with stray points far from its surface: its frame is the clean cloud's, and no
    query lands on a stray (the search never scores them)."""
    rng = np.random.default_rng(2)
    clean = shapes[1].vertices[rng.choice(shapes[1].n_points, 2000, False)]
    low, high = clean.min(0), clean.max(0)
    strays = rng.uniform(low - (high - low), high + (high - low), size=(300, 3))
    strays = strays[np.abs(strays - clean.mean(0)).max(axis=1) > (high - low).max()][:40]
    with_strays = Shape.from_arrays(np.concatenate([clean, strays]))
    target, plain = model.prepare_many([with_strays, Shape.from_arrays(clean)])
    assert target.transform.allclose(plain.transform)
    result = model.match(prepared[0], target)
    assert result.indices.max() < 2000
    assert not np.isin(np.arange(2000, 2000 + len(strays)), target.cache.tiers[0]).any()


def test_features_are_memoized_per_shape(model, prepared):
    x = prepared[0]
    first = model.features(x)
    assert model.features(x)[0].data_ptr() == first[0].data_ptr()
    assert isinstance(first[0], torch.Tensor) and first[0].shape[0] == x.n_points


def test_an_ensemble_averages_the_distances_of_its_networks(model, shapes):
    import dataclasses

    from litege_core.nets import GeodesicNet

    torch.manual_seed(7)
    first = model.bundle.networks[0]
    second = GeodesicNet(first.width, first.descriptor_dim).eval()
    second.set_coord_normalization([0.0, 0.0, 0.0], [0.2, 0.2, 0.2])
    alone = [
        MatchingModel(dataclasses.replace(model.bundle, networks=(net,))) for net in (first, second)
    ]
    both = MatchingModel(dataclasses.replace(model.bundle, networks=(first, second)))
    queries, candidates = np.arange(0, 300, 7), np.arange(0, 3000, 11)
    tables = []
    for m in [*alone, both]:
        x, y = m.prepare_many(list(shapes))
        tables.append(m.cross_distances(x, y, queries, candidates))
    np.testing.assert_allclose(tables[2], (tables[0] + tables[1]) / 2, rtol=1e-5, atol=1e-7)


def test_a_bfloat16_search_head_scores_like_float32_and_keeps_float32_frames(
    model, prepared, tmp_path
):
    x, y = prepared
    fast = MatchingModel(model.bundle, precision="bfloat16")
    assert fast.precision == "bfloat16"
    assert [f.precision for f in fast._folded] == ["bfloat16"] * len(model.bundle.networks)
    _save_copy(model, tmp_path / "q", "quadruped")  # a category with a frame judge
    judged = MatchingModel.load(tmp_path / "q", precision="bfloat16")
    assert [f.precision for f in judged.frame_judge.folded] == ["float32"]
    queries = np.arange(0, x.n_points, 97)
    candidates = np.arange(y.n_points)
    reference = model.cross_distances(x, y, queries, candidates)
    table = fast.cross_distances(x, y, queries, candidates)
    scale = float(np.abs(reference).max())
    assert np.abs(table - reference).max() <= 0.02 * scale  # bfloat16: 8 mantissa bits
    assert not np.array_equal(table, reference)  # the product really ran in bfloat16
    result = fast.match(x, y, queries, exhaustive=True)
    np.testing.assert_array_equal(result.indices, table.argmin(axis=1))


def test_precision_auto_resolves_and_an_unknown_precision_is_refused(model):
    from litege_core.nets.folded import fast_bfloat16

    auto = MatchingModel(model.bundle, precision="auto")
    assert auto.precision == ("bfloat16" if fast_bfloat16("cpu") else "float32")
    with pytest.raises(InputError, match="precision"):
        MatchingModel(model.bundle, precision="float16")
