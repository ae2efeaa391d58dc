"""Geodesic paths (gradient descent of the learned distance + projection) and the exact
surface projection they rely on, checked against trimesh's closest point (slow reference).
Measured on the fitted sphere net below (16 pairs, geodesic angle < 1.8 rad, 800 fit steps,
Intel Xeon, 2026-11-22): polyline length / predicted distance within 0.96–1.11, polyline
length / true great-circle distance within 1.00–1.02. The tests allow 0.12 and 0.05. With 400
fit steps the net was marginal on some CPUs (their float32 kernels differ, and training
amplifies the difference), hence 800.
"""

import importlib.util

import numpy as np
import pytest
import torch
import trimesh
from scipy.spatial import cKDTree

from litege_core.canonical import canonicalize_bbox
from litege_core.descriptor import VoxelGrid, fit_basis
from litege_core.errors import ArrayShapeError, IndexOutOfRangeError, InputError
from litege_core.learned import (
    GeodesicPath,
    Predictor,
    load_bundle,
    save_bundle,
    shape_samples,
    trace_path,
    trace_paths,
)
from litege_core.nets import GeodesicNet, residual_target
from litege_core.projection import (
    CloudProjector,
    MeshProjector,
    closest_point_on_triangles,
)
from litege_core.shape import Shape
from litege_core.variants import random_rotation

RADIUS = 2.0
K = 3
STEPS = 800  # fit steps of the sphere net (see the module docstring)


def _sphere(subdivisions: int = 3) -> Shape:
    mesh = trimesh.creation.icosphere(subdivisions=subdivisions)
    return Shape.from_arrays(np.asarray(mesh.vertices) * RADIUS, mesh.faces)


def _great_circle(shape: Shape, a, b) -> np.ndarray:
    unit = shape.vertices / RADIUS
    return RADIUS * np.arccos(np.clip(np.sum(unit[a] * unit[b], axis=-1), -1.0, 1.0))


@pytest.fixture(scope="module")
def basis():
    mesh = trimesh.creation.icosphere(subdivisions=3)
    shapes = []
    for seed in range(5):
        stretch = np.random.default_rng(seed).uniform(0.8, 1.2, 3)
        shapes.append((np.asarray(mesh.vertices) * stretch * 0.5, np.asarray(mesh.faces)))
    return fit_basis(
        shapes,
        grid=VoxelGrid(resolution=17, pitch=0.12),
        std_threshold=0.05,
        n_components=K,
        n_udf_samples=300,
        seed=0,
    )


def _fit_sphere_net(basis) -> GeodesicNet:
    """A tiny net fitted (~6 s) to great-circle distances of pairs closer than 2 rad."""
    sphere = _sphere()
    samples = shape_samples(sphere, 2000, 0)
    transform = canonicalize_bbox(samples)
    descriptor = torch.as_tensor(basis.describe(transform.apply(samples)))
    canonical = torch.tensor(transform.apply(sphere.vertices), dtype=torch.float32)
    unit = torch.tensor(sphere.vertices / RADIUS, dtype=torch.float32)
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # tiny matrices: threads only add synchronisation
    try:
        torch.manual_seed(0)
        net = GeodesicNet(width=32, descriptor_dim=K)
        net.fit_coord_normalization(canonical.numpy())
        optimizer = torch.optim.Adam(net.parameters(), lr=1e-2)
        schedule = torch.optim.lr_scheduler.CosineAnnealingLR(optimizer, STEPS, 1e-4)
        generator = torch.Generator().manual_seed(0)
        desc = descriptor[None].expand(1024, -1)
        n = canonical.shape[0]
        for _ in range(STEPS):
            i = torch.randint(n, (4096,), generator=generator)
            j = torch.randint(n, (4096,), generator=generator)
            angle = torch.arccos((unit[i] * unit[j]).sum(1).clamp(-1.0, 1.0))
            keep = torch.nonzero(angle < 2.0)[:1024, 0]
            i, j = i[keep], j[keep]
            geodesic = angle[keep] * RADIUS * transform.scale
            euclidean = torch.linalg.vector_norm(canonical[i] - canonical[j], dim=1)
            loss = (
                (net(canonical[i], canonical[j], desc, desc) - residual_target(geodesic, euclidean))
                .abs()
                .mean()
            )
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
            schedule.step()
    finally:
        torch.set_num_threads(threads)
    return net.eval()


@pytest.fixture(scope="module")
def sphere_predictor(tmp_path_factory, basis):
    directory = tmp_path_factory.mktemp("sphere") / "bundle"
    save_bundle(directory, name="s", category="s", basis=basis, network=_fit_sphere_net(basis))
    return Predictor(load_bundle(directory), descriptor_lattice="full")  # as it was fitted


@pytest.fixture(scope="module")
def euclidean_predictor(tmp_path_factory, basis):
    """A net whose head outputs 0: the residual model then predicts the Euclidean distance,
    which is the geodesic distance on a plane."""
    torch.manual_seed(1)
    net = GeodesicNet(width=32, descriptor_dim=K)
    with torch.no_grad():
        net.final_linear.weight.zero_()
        net.final_linear.bias.zero_()
    directory = tmp_path_factory.mktemp("euclid") / "bundle"
    save_bundle(directory, name="e", category="e", basis=basis, network=net.eval())
    return Predictor(load_bundle(directory))


@pytest.fixture(scope="module")
def sphere(sphere_predictor):
    shape = _sphere()
    return shape, sphere_predictor.register(shape)


def _pairs(shape: Shape, count: int, seed: int, max_angle: float = 1.8):
    rng = np.random.default_rng(seed)
    a, b = rng.integers(0, shape.n_points, (2, 8 * count))
    keep = (_great_circle(shape, a, b) < max_angle * RADIUS) & (a != b)
    return a[keep][:count], b[keep][:count]


def _distance_to_mesh(shape: Shape, points: np.ndarray) -> np.ndarray:
    mesh = trimesh.Trimesh(shape.vertices, shape.faces, process=False)
    return trimesh.proximity.closest_point(mesh, points)[1]


# ------------------------------------------------------------------------ projection


def test_closest_point_on_triangles_matches_trimesh():
    rng = np.random.default_rng(0)
    triangles = rng.normal(size=(500, 3, 3))
    points = rng.normal(size=(500, 3)) * 2.0
    closest, bary = closest_point_on_triangles(
        points, triangles[:, 0], triangles[:, 1], triangles[:, 2]
    )
    expected = trimesh.triangles.closest_point(triangles, points)
    np.testing.assert_allclose(closest, expected, atol=1e-9)
    assert (bary >= -1e-12).all()
    np.testing.assert_allclose(bary.sum(axis=1), 1.0)
    np.testing.assert_allclose(np.einsum("nk,nkd->nd", bary, triangles), closest, atol=1e-12)


def test_closest_point_handles_degenerate_triangles():
    a = np.array([[0.0, 0.0, 0.0], [1.0, 1.0, 1.0]])
    b = np.array([[1.0, 0.0, 0.0], [1.0, 1.0, 1.0]])
    c = np.array([[2.0, 0.0, 0.0], [1.0, 1.0, 1.0]])  # a segment and a point
    points = np.array([[0.5, 1.0, 0.0], [0.0, 0.0, 0.0]])
    closest, _ = closest_point_on_triangles(points, a, b, c)
    np.testing.assert_allclose(closest, [[0.5, 0.0, 0.0], [1.0, 1.0, 1.0]], atol=1e-12)
    # a triangle with two equal corners
    sliver, _ = closest_point_on_triangles(np.array([0.5, -1.0, 0.0]), a[0], b[0], b[0])
    np.testing.assert_allclose(sliver, [0.5, 0.0, 0.0], atol=1e-12)


def test_mesh_projector_is_exact_even_with_long_triangles():
    # a cylinder's side triangles span its whole height: the certificate must widen the search
    mesh = trimesh.creation.cylinder(radius=0.3, height=4.0, sections=24)
    rng = np.random.default_rng(1)
    points = rng.uniform(-2.5, 2.5, (400, 3)) * [0.3, 0.3, 1.0]
    projector = MeshProjector(mesh.vertices, mesh.faces, candidates=4)
    result = projector.project(points)
    _, expected, _ = trimesh.proximity.closest_point(mesh, points)
    np.testing.assert_allclose(result.distance, expected, atol=1e-9)
    np.testing.assert_allclose(
        np.linalg.norm(result.points - points, axis=1), result.distance, atol=1e-12
    )
    on_faces = np.einsum(
        "nk,nkd->nd", result.barycentric, mesh.vertices[mesh.faces][result.face_index]
    )
    np.testing.assert_allclose(on_faces, result.points, atol=1e-12)
    # vertices project onto themselves exactly
    np.testing.assert_array_equal(projector.project(mesh.vertices[:10]).points, mesh.vertices[:10])


def test_cloud_projector_snaps_to_the_nearest_point():
    rng = np.random.default_rng(2)
    cloud = np.column_stack([rng.uniform(0, 1, (300, 2)), np.zeros(300)])
    projector = CloudProjector(cloud)
    queries = rng.uniform(0, 1, (50, 3))
    result = projector.project(queries)
    brute = np.argmin(np.linalg.norm(queries[:, None] - cloud[None], axis=2), axis=1)
    np.testing.assert_array_equal(result.point_index, brute)
    np.testing.assert_array_equal(result.points, cloud[brute])
    np.testing.assert_allclose(np.abs(result.normals[:, 2]), 1.0, atol=1e-9)
    _, neighbours = projector.neighbours(queries, 4)
    brute4 = np.argsort(np.linalg.norm(queries[:, None] - cloud[None], axis=2), axis=1)[:, :4]
    np.testing.assert_array_equal(neighbours, brute4)
    assert projector.mean_spacing > 0
    # repeated points count once: a cloud sent twice keeps its spacing
    twice = CloudProjector(np.vstack([cloud, cloud]))
    assert twice.mean_spacing == pytest.approx(projector.mean_spacing, rel=1e-12)
    assert CloudProjector(np.zeros((5, 3))).mean_spacing == 0.0


# ------------------------------------------------------------------------ paths


def _grid(nx: int, ny: int, width: float, height: float) -> tuple[np.ndarray, np.ndarray]:
    """A flat triangulated rectangle in the z = 0 plane, diagonals alternating."""
    u, v = np.meshgrid(np.linspace(0, width, nx), np.linspace(0, height, ny), indexing="ij")
    vertices = np.column_stack([u.ravel(), v.ravel(), np.zeros(u.size)])
    index = np.arange(nx * ny).reshape(nx, ny)
    a, b = index[:-1, :-1].ravel(), index[1:, :-1].ravel()
    c, d = index[1:, 1:].ravel(), index[:-1, 1:].ravel()
    flip = ((np.arange(nx - 1)[:, None] + np.arange(ny - 1)[None]) % 2).ravel() == 1
    first = np.where(flip[:, None], np.column_stack([a, b, d]), np.column_stack([a, b, c]))
    second = np.where(flip[:, None], np.column_stack([b, c, d]), np.column_stack([a, c, d]))
    return vertices, np.concatenate([first, second])


def test_path_on_a_plane_is_the_straight_segment(euclidean_predictor):
    vertices, faces = _grid(31, 23, 2.0, 1.4)
    rotation = random_rotation(4)
    shape = Shape.from_arrays(3.0 * vertices @ rotation.T + [1.0, 2.0, -1.0], faces)
    state = euclidean_predictor.register(shape)
    corners = np.array([[0.1, 0.1, 0], [1.9, 1.3, 0], [0.2, 1.2, 0], [1.8, 0.3, 0]])
    ends = np.argmin(np.linalg.norm(vertices[:, None] - corners[None], axis=2), axis=0)
    sources, targets = ends[[0, 2]], ends[[1, 3]]
    paths = euclidean_predictor.paths(state, sources, targets)
    for path, s, t in zip(paths, sources, targets, strict=True):
        start, end = shape.vertices[s], shape.vertices[t]
        np.testing.assert_array_equal(path.points[0], start)  # source → target
        np.testing.assert_array_equal(path.points[-1], end)
        chord = np.linalg.norm(end - start)
        assert path.converged and path.n_steps > 10 and path.segments == ((0, "learned"),)
        assert path.predicted_distance == pytest.approx(chord, rel=1e-5)
        assert path.length == pytest.approx(chord, rel=1e-4)
        direction = (end - start) / chord
        offsets = path.points - start
        off_line = offsets - np.outer(offsets @ direction, direction)
        assert np.linalg.norm(off_line, axis=1).max() < 1e-4 * chord


def test_sphere_paths_follow_geodesics(sphere_predictor, sphere):
    shape, state = sphere
    sources, targets = _pairs(shape, 12, 0)
    paths = trace_paths(sphere_predictor, state, sources, targets)
    true = _great_circle(shape, sources, targets)
    ratios = []
    for path, s, t, g in zip(paths, sources, targets, true, strict=True):
        assert isinstance(path, GeodesicPath) and not path.points.flags.writeable
        np.testing.assert_array_equal(path.points[0], shape.vertices[s])
        np.testing.assert_array_equal(path.points[-1], shape.vertices[t])
        assert _distance_to_mesh(shape, path.points).max() < 1e-6 * RADIUS
        assert path.converged
        assert abs(path.length / g - 1) < 0.05
        length = np.linalg.norm(np.diff(path.points, axis=0), axis=1).sum()
        assert path.length == pytest.approx(length)
        ratios.append(path.length / path.predicted_distance)
    assert np.abs(np.array(ratios) - 1).max() < 0.12


def test_batched_paths_equal_single_paths(sphere_predictor, sphere):
    shape, state = sphere
    sources, targets = _pairs(shape, 4, 1)
    batch = sphere_predictor.paths(state, sources, targets)
    for path, s, t in zip(batch, sources, targets, strict=True):
        single = sphere_predictor.path(state, int(s), int(t))
        # float32 products over different batch sizes: equal to rounding
        np.testing.assert_allclose(single.points, path.points, atol=1e-6)
        assert single.n_steps == path.n_steps
    # one source broadcast against several targets
    fan = trace_paths(sphere_predictor, state, sources[0], targets)
    for path, t in zip(fan, targets, strict=True):
        np.testing.assert_array_equal(path.points[0], shape.vertices[sources[0]])
        np.testing.assert_array_equal(path.points[-1], shape.vertices[t])


def test_paths_are_in_the_users_frame(sphere_predictor, sphere):
    shape, state = sphere
    rotation = random_rotation(3)
    moved = shape.with_vertices(10.0 * shape.vertices @ rotation.T + [5.0, 0.0, -2.0])
    moved_state = sphere_predictor.register(moved)
    sources, targets = _pairs(shape, 3, 2)
    for a, b in zip(
        sphere_predictor.paths(state, sources, targets),
        sphere_predictor.paths(moved_state, sources, targets),
        strict=True,
    ):
        assert b.n_steps == a.n_steps
        np.testing.assert_allclose(
            b.points, 10.0 * a.points @ rotation.T + [5.0, 0.0, -2.0], atol=1e-4
        )
        assert b.length == pytest.approx(10.0 * a.length, rel=1e-5)
        assert b.predicted_distance == pytest.approx(10.0 * a.predicted_distance, rel=1e-4)


def test_xyz_endpoints_are_projected(sphere_predictor, sphere):
    shape, state = sphere
    source = shape.vertices[5] * 1.05  # off the surface
    path = trace_path(sphere_predictor, state, source, 300)
    np.testing.assert_allclose(path.points[0], shape.vertices[5], atol=1e-9)
    assert path.converged and path.n_steps > 0


def test_point_cloud_paths_hop_between_cloud_points(sphere_predictor):
    points = shape_samples(_sphere(4), 3000, seed=1)
    cloud = Shape.from_arrays(points)
    state = sphere_predictor.register(cloud)
    paths = sphere_predictor.paths(state, [0, 10], [1500, 2500])
    tree = cKDTree(points)
    for path, s, t in zip(paths, [0, 10], [1500, 2500], strict=True):
        assert tree.query(path.points)[0].max() == 0.0  # every vertex is a cloud point
        np.testing.assert_array_equal(path.points[[0, -1]], points[[s, t]])
        assert path.converged and path.n_steps > 3
        assert 0.85 < path.length / path.predicted_distance < 1.35


def test_a_cloud_of_repeated_points_walks_as_the_cloud_itself(sphere_predictor):
    """Every point sent twice: the nearest other point is at distance 0, the step is not."""
    points = shape_samples(_sphere(4), 1500, seed=1)
    once = sphere_predictor.register(Shape.from_arrays(points))
    twice = sphere_predictor.register(Shape.from_arrays(np.vstack([points, points])))
    assert twice.spacing == pytest.approx(once.spacing, rel=1e-9) and twice.spacing > 0
    path = sphere_predictor.path(twice, 0, 1000)
    assert path.converged and path.n_steps > 3
    np.testing.assert_array_equal(path.points[[0, -1]], points[[0, 1000]])


def test_degenerate_and_capped_walks(sphere_predictor, sphere):
    _, state = sphere
    same = sphere_predictor.path(state, 7, 7)
    assert same.points.shape == (2, 3) and same.length == 0.0
    assert same.predicted_distance == 0.0 and same.converged and same.n_steps == 0
    assert same.segments == ((0, "learned"),)
    # no step at all: the whole path is the on-surface route, not a chord through the sphere
    capped = sphere_predictor.path(state, 0, 400, max_steps=0)
    assert capped.n_steps == 0 and not capped.converged
    route = "edge-flip" if importlib.util.find_spec("potpourri3d") else "mesh-edges"
    assert capped.segments == ((0, route),) and capped.points.shape[0] > 2
    short = sphere_predictor.path(state, 0, 400, max_steps=3)
    assert short.n_steps <= 3 and not short.converged
    (_, first), (start, second) = short.segments
    assert (first, second) == (route, "learned")
    assert short.points.shape[0] - start == short.n_steps + 1  # the walk: target + its steps


def test_bad_path_queries_are_refused(sphere_predictor, sphere):
    _, state = sphere
    with pytest.raises(IndexOutOfRangeError):
        sphere_predictor.path(state, 0, state.n_points)
    with pytest.raises(IndexOutOfRangeError):
        sphere_predictor.paths(state, [-1], [3])
    with pytest.raises(ArrayShapeError):
        sphere_predictor.paths(state, [0, 1, 2], [3, 4])
    with pytest.raises(ArrayShapeError):
        trace_path(sphere_predictor, state, [0, 1], 3)
    with pytest.raises(InputError):
        sphere_predictor.path(state, 0, 3, step=0.0)
    with pytest.raises(InputError):
        sphere_predictor.path(state, 0, 3, tolerance=float("nan"))
    with pytest.raises(InputError):
        sphere_predictor.path(state, 0, 3, max_steps=-1)
    with pytest.raises(InputError):
        sphere_predictor.path(state, [np.nan, 0.0, 0.0], 3)


def test_paths_need_the_torch_predictor(sphere_predictor, sphere):
    """The torch-free runtime has no gradients to walk: a clear InputError, no AttributeError."""
    from litege_core.learned.numpy_predictor import NumpyPredictor

    runtime = NumpyPredictor(sphere_predictor.bundle.path)
    shape, _ = sphere
    with pytest.raises(InputError, match="paths need the torch Predictor"):
        trace_path(runtime, runtime.register(shape), 0, 3)
