"""Predictor: register once, then distances in the user's units, checked against the network's
own ``forward`` (slow reference), batched against per-shape calls, and at the boundary."""

import numpy as np
import pytest
import torch
import trimesh

from litege_core.canonical import canonicalize_bbox
from litege_core.descriptor import VoxelGrid, fit_basis
from litege_core.errors import (
    ArrayShapeError,
    ArtifactError,
    IndexOutOfRangeError,
    InputError,
    NonFiniteError,
)
from litege_core.learned import (
    OOD_Z_THRESHOLD,
    PipelineConfig,
    Predictor,
    ShapeState,
    describe_shape,
    load_bundle,
    save_bundle,
    shape_samples,
)
from litege_core.nets import TARGET_SCALE
from litege_core.nets.folded import BF16_MIN_ROWS, INT8_MIN_ROWS, fast_bfloat16, int8_engine
from litege_core.nets.testing import random_geodesic_net
from litege_core.shape import Shape
from litege_core.variants import random_rotation

K = 4


def _blob(seed: int, subdivisions: int = 3) -> Shape:
    """An asymmetric bent ellipsoid (well-defined PCA frame)."""
    rng = np.random.default_rng(seed)
    sphere = trimesh.creation.icosphere(subdivisions=subdivisions)
    vertices = np.asarray(sphere.vertices) * [1.6 + rng.uniform(-0.3, 0.3), 1.0, 0.6]
    vertices[:, 1] += 0.3 * vertices[:, 0] ** 2 * rng.uniform(0.5, 1.5)
    return Shape.from_arrays(vertices, sphere.faces)


@pytest.fixture(scope="module")
def basis():
    canonical = []
    for seed in range(6):
        shape = _blob(seed, subdivisions=2)
        transform = canonicalize_bbox(shape_samples(shape, 500, seed))
        canonical.append((transform.apply(shape.vertices), np.asarray(shape.faces)))
    return fit_basis(
        canonical,
        grid=VoxelGrid(resolution=21, pitch=0.1),
        std_threshold=0.05,
        n_components=K,
        n_udf_samples=300,
        seed=0,
    )


TRAINING = {"residual_mean": 0.5, "residual_std": 0.25}


@pytest.fixture(scope="module")
def bundle(tmp_path_factory, basis):
    directory = tmp_path_factory.mktemp("bundle") / "toy"
    save_bundle(
        directory,
        name="toy",
        category="toy",
        basis=basis,
        network=random_geodesic_net(32, K),
        pipeline=PipelineConfig(n_mesh_samples=800),
        training=TRAINING,
    )
    return load_bundle(directory)


@pytest.fixture(scope="module")
def predictor(bundle):
    return Predictor(bundle)


@pytest.fixture(scope="module")
def mesh():
    return _blob(100)


@pytest.fixture(scope="module")
def cloud():
    return Shape.from_arrays(shape_samples(_blob(101), 700, seed=5))


@pytest.fixture(scope="module")
def mesh_state(predictor, mesh):
    return predictor.register(mesh, seed=3)


def _reference(bundle, state: ShapeState, sources, targets) -> np.ndarray:
    """Slow reference: the network's training ``forward`` on every pair, in eval mode."""
    net = bundle.network
    points = torch.tensor(state.canonical_points, dtype=torch.float32)
    src = points[sources].repeat_interleave(len(targets), 0)
    dst = points[targets].repeat(len(sources), 1)
    desc = torch.as_tensor(np.array(state.descriptor))[None].expand(src.shape[0], -1)
    with torch.no_grad():
        out = net(src, dst, desc, desc)
    euclidean = torch.linalg.vector_norm(src - dst, dim=1)
    canonical = (out / TARGET_SCALE + euclidean).numpy().astype(np.float64)
    canonical[euclidean.numpy() == 0] = 0.0
    return canonical.reshape(len(sources), len(targets)) / state.transform.scale


# ------------------------------------------------------------------------ equivalences


def test_distances_equal_the_network_forward(bundle, predictor, mesh_state):
    rng = np.random.default_rng(0)
    sources = rng.integers(0, mesh_state.n_points, 7)
    targets = rng.integers(0, mesh_state.n_points, 50)
    targets[:3] = sources[:3]
    got = predictor.distances(mesh_state, sources, targets)
    assert got.dtype == np.float32 and got.shape == (7, 50)
    expected = _reference(bundle, mesh_state, sources, targets)
    np.testing.assert_allclose(got, expected, rtol=1e-5, atol=1e-6 * np.abs(expected).max())
    assert (got[[0, 1, 2], [0, 1, 2]] == 0).all()


@pytest.mark.skipif(int8_engine() is None, reason="this torch build has no quantized engine")
def test_int8_point_mlp_predictor_stays_close_and_keeps_its_own_tables(bundle, mesh):
    """``embed_precision="int8"``: a distance field within a few per cent of float32's; a
    state shared with a float32 predictor keeps one feature table per arithmetic, so neither
    predictor answers from the other's table."""
    exact, int8 = Predictor(bundle), Predictor(bundle, embed_precision="int8")
    assert "embed_precision='int8'" in repr(int8) and "int8" not in repr(exact)
    state = exact.register(mesh, seed=3)
    assert state.n_points >= INT8_MIN_ROWS
    want = exact.distances(state, [0, 5])  # builds the float32 table
    got = int8.distances(state, [0, 5])
    assert not np.array_equal(got, want)  # its own table, in int8
    assert np.abs(got - want).mean() < 0.03 * np.abs(want).mean()
    # not from the int8 table (row counts may move float32 rounding: 1e-7)
    np.testing.assert_allclose(exact.distances(state, [0, 5]), want, rtol=1e-5, atol=1e-6)
    with pytest.raises(InputError):
        Predictor(bundle, embed_precision="float16")


def test_bfloat16_point_mlp_predictor_stays_close_and_keeps_its_own_tables(bundle, mesh):
    """``embed_precision="bfloat16"``: a distance field within a per cent of float32's from
    its own feature table; ``"auto"`` is bfloat16 exactly where the CPU multiplies it
    natively."""
    exact, bf16 = Predictor(bundle), Predictor(bundle, embed_precision="bfloat16")
    assert "embed_precision='bfloat16'" in repr(bf16)
    auto = Predictor(bundle, embed_precision="auto").embed_precision
    assert auto == ("bfloat16" if fast_bfloat16("cpu") else "float32")
    state = exact.register(mesh, seed=3)
    assert state.n_points >= BF16_MIN_ROWS
    want = exact.distances(state, [0, 5])
    got = bf16.distances(state, [0, 5])
    assert not np.array_equal(got, want)  # its own table, in bfloat16
    assert np.abs(got - want).mean() < 0.01 * np.abs(want).mean()
    np.testing.assert_allclose(exact.distances(state, [0, 5]), want, rtol=1e-5, atol=1e-6)


def test_register_turned_describes_each_turned_frame(predictor, cloud):
    from litege_core.train.augment import axis_turn

    turns = np.stack([np.eye(3), axis_turn(1), random_rotation(np.random.default_rng(2))])
    plain = predictor.register(cloud)
    states = predictor.register_turned(cloud, turns)
    assert states[0].transform.allclose(plain.transform, atol=1e-9)
    np.testing.assert_allclose(states[0].descriptor, plain.descriptor, atol=1e-5)
    for turn, state in zip(turns, states, strict=True):  # frame i = turns[i] @ R_pca
        np.testing.assert_allclose(
            state.transform.rotation, turn @ plain.transform.rotation, atol=1e-12
        )
        np.testing.assert_allclose(state.transform.scale, plain.transform.scale)
        expected = predictor.bundle.basis.describe(state.transform.apply(cloud.vertices))
        np.testing.assert_allclose(state.descriptor, expected, atol=1e-4)
    assert not np.allclose(states[1].descriptor, plain.descriptor)  # the UDF sees the turn
    fields = [predictor.distances(s, [0]) for s in states]
    assert not np.allclose(fields[0], fields[1])  # and so does the network


def test_cached_state_equals_fresh_computation(bundle, predictor, mesh, mesh_state):
    net = bundle.network
    description = describe_shape(mesh, bundle.basis, n_samples=800, seed=3)
    assert mesh_state.transform.allclose(description.transform)
    np.testing.assert_array_equal(mesh_state.descriptor, description.descriptor)
    assert mesh_state.residual == pytest.approx(description.residual)
    np.testing.assert_allclose(
        mesh_state.canonical_points, description.transform.apply(mesh.vertices)
    )
    with torch.no_grad():
        shape_emb = net.shape_embedding(torch.as_tensor(description.descriptor)[None])[0]
        points = torch.tensor(mesh_state.canonical_points, dtype=torch.float32)
        fresh = net.point_embedding(points, shape_emb)
        first_head_layer = net.final_layers[0].weight  # (2n, n), no bias: W e_p
        bn = net.final_layers[1]
        bn_scale = bn.weight / torch.sqrt(bn.running_var + bn.eps)
        fresh_features = (fresh @ first_head_layer.T) * bn_scale
    torch.testing.assert_close(mesh_state.shape_embedding, shape_emb, rtol=1e-5, atol=1e-5)
    torch.testing.assert_close(
        predictor.point_table(mesh_state), fresh_features, rtol=1e-4, atol=1e-4
    )
    torch.testing.assert_close(mesh_state.canonical_vertices, points)


def test_state_fields_are_read_only_and_keyed_by_content(predictor, mesh, mesh_state):
    assert mesh_state.shape_id == mesh.content_hash
    assert mesh_state.kind is mesh.kind and mesh_state.n_points == mesh.n_points
    assert mesh_state.bundle_hash == predictor.bundle.content_hash
    for array in (mesh_state.descriptor, mesh_state.canonical_points, mesh_state.vertices):
        assert not array.flags.writeable
    fresh = predictor.register(mesh, seed=3)
    assert fresh.feature_table is None  # built only when a query needs it
    before = fresh.nbytes
    assert predictor.point_table(fresh).shape == (mesh.n_points, 64)
    assert fresh.feature_table is not None
    assert fresh.nbytes >= before + mesh.n_points * 64 * 4
    again = predictor.register(mesh, seed=3)  # deterministic
    np.testing.assert_array_equal(again.descriptor, mesh_state.descriptor)
    np.testing.assert_array_equal(again.canonical_points, mesh_state.canonical_points)
    # equal up to float32 rounding: the matrix kernels round differently with the number of
    # rows, and the fixture's state may already hold its point table (built by another test)
    np.testing.assert_allclose(
        predictor.distances(again, [1, 2]), predictor.distances(mesh_state, [1, 2]), rtol=1e-6
    )


def test_few_point_queries_embed_only_their_points(predictor, mesh):
    state = predictor.register(mesh, seed=3)
    few = predictor.distances(state, [3, 7], [1, 2, 400])
    assert state.feature_table is None  # a small query never builds the whole table
    # ... nor maps or uploads every vertex; its rows are exactly those of the whole
    assert "canonical_points" not in state._lazy and "canonical_vertices" not in state._lazy
    rows = state.canonical_rows(np.array([400, 3]))
    np.testing.assert_array_equal(rows, state.canonical_points[[400, 3]])
    np.testing.assert_array_equal(state.canonical_rows(np.array([400, 3])), rows)
    predictor.point_table(state)
    np.testing.assert_allclose(predictor.distances(state, [3, 7], [1, 2, 400]), few, rtol=1e-5)
    alone = predictor.register(mesh, seed=3)
    first = predictor.distances(alone, [5], "all")  # the source is embedded on its own
    # from the table: the same embedding, up to the rounding of a matrix product of more rows
    np.testing.assert_allclose(predictor.distances(alone, [5], "all"), first, rtol=1e-6)
    large = predictor.register(mesh, seed=3)
    predictor.distances(large, np.arange(mesh.n_points // 2), [1])
    assert large.feature_table is not None  # a query of most points builds it once


def test_distance_field_and_all_targets(predictor, mesh_state):
    matrix = predictor.distances(mesh_state, [3, 7])
    assert matrix.shape == (2, mesh_state.n_points)
    assert matrix[0, 3] == 0 and matrix[1, 7] == 0
    assert (np.delete(matrix[0], 3) > 0).all()
    # (equal up to float32 rounding: the matrix products differ in their row counts)
    np.testing.assert_allclose(predictor.distance_field(mesh_state, 7), matrix[1], rtol=1e-6)
    np.testing.assert_allclose(predictor.distances(mesh_state, [3], "all"), matrix[:1], rtol=1e-6)


def test_results_are_in_the_users_frame_and_units(predictor, mesh, mesh_state):
    rotation = random_rotation(11)
    moved = mesh.with_vertices(10.0 * mesh.vertices @ rotation.T + [3.0, -2.0, 5.0])
    state = predictor.register(moved, seed=3)
    sources, targets = [0, 50, 300], [1, 2, 400, 600]
    np.testing.assert_allclose(
        predictor.distances(state, sources, targets),
        10.0 * predictor.distances(mesh_state, sources, targets),
        rtol=1e-4,
    )
    # xyz queries in the moved frame land on the same vertices
    xyz = moved.vertices[[50, 300]]
    by_xyz = predictor.distances(state, xyz, targets)
    np.testing.assert_allclose(by_xyz, predictor.distances(state, [50, 300], targets), rtol=1e-4)


def test_xyz_queries_are_projected_onto_the_surface(predictor, mesh, mesh_state):
    normals = trimesh.Trimesh(mesh.vertices, mesh.faces, process=False).vertex_normals
    on_surface = predictor.distances(mesh_state, [10, 20], [5, 6, 7])
    lifted = mesh.vertices[[10, 20]] + 0.05 * normals[[10, 20]]  # off the surface
    np.testing.assert_allclose(
        predictor.distances(mesh_state, lifted, [5, 6, 7]), on_surface, rtol=2e-2
    )
    # a point inside a face: the projection is the point itself
    face = mesh.faces[40]
    inside = mesh.vertices[face].mean(axis=0)[None]
    resolved = predictor.resolve(mesh_state, inside)
    np.testing.assert_allclose(resolved.user, inside, atol=1e-12)
    assert resolved.indices is None


def test_point_cloud_queries(predictor, cloud):
    state = predictor.register(cloud)
    assert state.kind.value == "point_cloud" and not state.is_mesh
    by_index = predictor.distances(state, [4, 9], [4, 9, 100])
    assert by_index[0, 0] == 0 and by_index[1, 1] == 0
    jitter = cloud.vertices[[4, 9]] + 1e-4
    np.testing.assert_array_equal(predictor.distances(state, jitter, [4, 9, 100]), by_index)


def test_distances_many_equals_per_shape_calls(predictor, mesh, cloud, mesh_state):
    cloud_state = predictor.register(cloud)
    queries = [
        (mesh_state, [1, 2, 3], [4, 5]),
        (cloud_state, [7], None),
        (mesh_state, mesh.vertices[[9, 11]] + 0.01, [0, 9, 11, 12]),
        (cloud_state, [0, 1], [2, 3, 4]),
    ]
    states, sources, targets = zip(*queries, strict=True)
    batched = predictor.distances_many(states, sources, targets)
    for (state, src, dst), got in zip(queries, batched, strict=True):
        np.testing.assert_allclose(got, predictor.distances(state, src, dst), rtol=1e-6)
    # tiny chunks: same numbers through the chunked dense and grouped flat paths
    small = Predictor(predictor.bundle, chunk_pairs=7)
    for got, expected in zip(small.distances_many(states, sources, targets), batched, strict=True):
        np.testing.assert_allclose(got, expected, rtol=1e-6)
    full = predictor.distances(mesh_state, np.arange(40))
    np.testing.assert_allclose(small.distances(mesh_state, np.arange(40)), full, rtol=1e-6)


def test_one_pair_per_shape_batches_equal_per_shape_calls(predictor, mesh, cloud, mesh_state):
    """The paper's Table 1 workload (B shapes × one pair, one query per shape): no row index
    on the batch path, the same distances as one shape at a time; mixed with a 2-point query
    the grouped path indexes rows again."""
    cloud_state = predictor.register(cloud)
    states = [mesh_state, cloud_state, mesh_state, cloud_state]
    sources, targets = [[0], [3], [7], [3]], [[5], [8], [7], [0]]
    batched = predictor.distances_many(states, sources, targets)
    for state, src, dst, got in zip(states, sources, targets, batched, strict=True):
        assert got.shape == (1, 1)
        np.testing.assert_allclose(got, predictor.distances(state, src, dst), rtol=1e-6)
    assert batched[2][0, 0] == 0.0  # a point to itself
    mixed = predictor.distances_many([*states, cloud_state], [*sources, [1, 2]], [*targets, [4]])
    for got, want in zip(mixed[:-1], batched, strict=True):
        np.testing.assert_allclose(got, want, rtol=1e-6)
    np.testing.assert_allclose(mixed[-1], predictor.distances(cloud_state, [1, 2], [4]), rtol=1e-6)


def test_register_many_equals_register(predictor, mesh, cloud):
    shapes = [mesh, cloud, _blob(102)]
    many = predictor.register_many(shapes, seed=2)
    for shape, state in zip(shapes, many, strict=True):
        single = predictor.register(shape, seed=2)
        assert state.shape_id == single.shape_id
        np.testing.assert_array_equal(state.descriptor, single.descriptor)
        torch.testing.assert_close(predictor.point_table(state), predictor.point_table(single))
        table = state.feature_table
        assert table is not None and table.untyped_storage().size() == table.nbytes
        vertices = state.canonical_vertices
        assert vertices.untyped_storage().size() == vertices.nbytes  # not a view of the batch
        # embedding and bias are views of the batch's (3, 2n) rows, and charged for them
        rows = state.shape_embedding.untyped_storage()
        assert state.shape_bias.untyped_storage().data_ptr() == rows.data_ptr()
        assert rows.nbytes() == len(shapes) * (
            state.shape_embedding.nbytes + state.shape_bias.nbytes
        )
        assert state.nbytes >= rows.nbytes() + vertices.nbytes + table.nbytes
    assert predictor.register_many([]) == []


# ------------------------------------------------------------------------ OOD and pipeline


def test_ood_score_is_a_z_score_against_training_residuals(predictor, basis, tmp_path, mesh):
    state = predictor.register(mesh)
    expected = (state.residual - TRAINING["residual_mean"]) / TRAINING["residual_std"]
    assert predictor.ood_score(state) == pytest.approx(expected)
    assert state.ood_calibrated
    assert state.is_out_of_distribution == (expected > OOD_Z_THRESHOLD)
    box = trimesh.creation.box(extents=[1.0, 1.0, 1.0]).subdivide().subdivide()
    box_state = predictor.register(Shape.from_arrays(box.vertices, box.faces))
    assert box_state.ood_score > state.ood_score
    save_bundle(
        tmp_path / "raw", name="r", category="r", basis=basis, network=random_geodesic_net(32, K)
    )
    raw = Predictor(load_bundle(tmp_path / "raw")).register(mesh)
    assert raw.ood_score == raw.residual and raw.is_out_of_distribution is None


def test_pipeline_config_is_honoured(basis, tmp_path, mesh):
    save_bundle(
        tmp_path / "p",
        name="p",
        category="p",
        basis=basis,
        network=random_geodesic_net(32, K),
        pipeline=PipelineConfig(n_mesh_samples=300),
    )
    state = Predictor(load_bundle(tmp_path / "p")).register(mesh, seed=1)
    expected = describe_shape(mesh, basis, n_samples=300, seed=1).descriptor
    np.testing.assert_array_equal(state.descriptor, expected)
    save_bundle(
        tmp_path / "u",
        name="u",
        category="u",
        basis=basis,
        network=random_geodesic_net(32, K),
        pipeline=PipelineConfig(canonicalization="unit_area"),
    )
    with pytest.raises(ArtifactError, match="canonicalization"):
        Predictor(load_bundle(tmp_path / "u"))


# ------------------------------------------------------------------------ negative tests


def test_bad_indices_are_refused(predictor, mesh_state):
    n = mesh_state.n_points
    with pytest.raises(IndexOutOfRangeError):
        predictor.distances(mesh_state, [0, n])
    with pytest.raises(IndexOutOfRangeError):
        predictor.distances(mesh_state, [0], [-1])
    with pytest.raises(IndexOutOfRangeError):
        predictor.distance_field(mesh_state, n + 5)
    with pytest.raises(ArrayShapeError):
        predictor.distances(mesh_state, [0.5, 1.0])  # 1-D floats are not indices
    with pytest.raises(InputError):
        predictor.distances(mesh_state, [])
    with pytest.raises(ArrayShapeError):
        predictor.distances(mesh_state, [0], "some")
    with pytest.raises(ArrayShapeError):
        predictor.distance_field(mesh_state, [1, 2])


def test_bad_points_are_refused(predictor, mesh_state):
    with pytest.raises(NonFiniteError):
        predictor.distances(mesh_state, [[0.0, np.nan, 0.0]])
    with pytest.raises(NonFiniteError):
        predictor.distances(mesh_state, [0], [[np.inf, 0.0, 0.0]])
    with pytest.raises(ArrayShapeError):
        predictor.distances(mesh_state, np.zeros((2, 2)))
    with pytest.raises(ArrayShapeError):
        predictor.distances(mesh_state, np.zeros((0, 3)))
    with pytest.raises(ArrayShapeError):
        predictor.distances(mesh_state, [[0, 1], [2]])


def test_foreign_states_and_mismatched_batches(predictor, basis, tmp_path, mesh, mesh_state):
    save_bundle(
        tmp_path / "o",
        name="o",
        category="o",
        basis=basis,
        network=random_geodesic_net(32, K, seed=1),
    )
    other = Predictor(load_bundle(tmp_path / "o"))
    with pytest.raises(InputError, match="another model bundle"):
        other.distances(mesh_state, [0])
    with pytest.raises(InputError):
        predictor.distances_many([mesh_state, mesh_state], [[0]])
    with pytest.raises(InputError):
        predictor.distances(mesh, [0])  # a Shape is not a registered state
    with pytest.raises(InputError):
        predictor.register_many([mesh.vertices])
    with pytest.raises(InputError):
        Predictor(predictor.bundle, chunk_pairs=0)
    with pytest.raises(InputError, match="invalid torch device 'tpu'"):
        Predictor(predictor.bundle, "tpu")
