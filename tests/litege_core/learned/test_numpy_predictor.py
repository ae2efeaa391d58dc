"""NumpyPredictor: the torch-free runtime equals the torch Predictor (the reference), on toy
bundles with non-trivial BatchNorm statistics and on the shipped models, and never imports
torch."""

import json
import shutil
import subprocess
import sys

import numpy as np
import pytest
import torch

from litege_core.descriptor import VoxelGrid, fit_basis
from litege_core.errors import ArrayShapeError, ArtifactError, IndexOutOfRangeError, InputError
from litege_core.learned import (
    NumpyPredictor,
    Predictor,
    load_bundle,
    load_shipped,
    save_bundle,
    shipped_bundles,
)
from litege_core.learned.manifest import MANIFEST, NETWORK_FILE, SMALL_HEAD_CONFIG
from litege_core.learned.small_head import save_small_head
from litege_core.nets.small_head import SmallHead
from litege_core.nets.testing import random_geodesic_net
from litege_core.shape import Shape

K = 4


@pytest.fixture(scope="module")
def scaled_blob(blob):
    """``scaled_blob(seed, subdivisions=3)``: the shared bent ellipsoid, in other units and
    away from the origin."""

    def make(seed: int, subdivisions: int = 3) -> Shape:
        shape = blob(seed, subdivisions)
        return Shape.from_arrays(shape.vertices * 7.0 + [3.0, -2.0, 1.0], shape.faces)

    return make


@pytest.fixture(scope="module", params=["abs", "softplus"])
def bundle_dir(request, tmp_path_factory, blob):
    shapes = [(blob(seed).vertices, blob(seed).faces) for seed in range(5)]
    basis = fit_basis(
        shapes,
        grid=VoxelGrid(resolution=21, pitch=0.12),
        std_threshold=0.05,
        n_components=K,
        n_udf_samples=400,
        seed=0,
    )
    net = random_geodesic_net(24, K, output=request.param)
    directory = tmp_path_factory.mktemp("numpy") / f"toy-{request.param}"
    save_bundle(
        directory,
        name="toy",
        category="toy",
        basis=basis,
        network=net,
        training={"residual_mean": 0.5, "residual_std": 0.25},
        weights_dtype=torch.float16,
    )
    return directory


@pytest.mark.parametrize("kind", ["mesh", "cloud"])
def test_equals_the_torch_predictor(bundle_dir, scaled_blob, kind):
    shape = scaled_blob(3)
    if kind == "cloud":
        shape = Shape.from_arrays(shape.vertices)
    reference = Predictor(load_bundle(bundle_dir))
    runtime = NumpyPredictor(bundle_dir)
    state, expected_state = runtime.register(shape, seed=2), reference.register(shape, seed=2)
    assert state.residual == pytest.approx(expected_state.residual, rel=1e-5)
    assert state.ood_score == pytest.approx(expected_state.ood_score, rel=1e-5, abs=1e-5)
    for sources, targets in [([0, 5, 17], None), ([4], [4, 9, 100]), (np.arange(300), "all")]:
        got = runtime.distances(state, sources, targets)
        want = reference.distances(expected_state, sources, targets)
        assert got.dtype == np.float32 and got.shape == want.shape
        np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-5 * float(np.abs(want).max()))
    field = runtime.distances(state, [9])[0]
    assert field[9] == 0.0 and (np.delete(field, 9) > 0).all()


def _edited_copy(source, target, filename, key):
    """A copy of the bundle directory ``source`` whose JSON ``filename`` names another hash
    under ``key``."""
    shutil.copytree(source, target)
    document = json.loads((target / filename).read_text())
    document[key] = "f" * 64
    (target / filename).write_text(json.dumps(document))
    return target


@pytest.fixture(scope="module")
def small_head_dir(bundle_dir, tmp_path_factory):
    """The toy bundle with a random small head beside it (non-zero biases)."""
    directory = tmp_path_factory.mktemp("numpy-small") / bundle_dir.name
    shutil.copytree(bundle_dir, directory)
    bundle = load_bundle(directory)
    torch.manual_seed(3)
    head = SmallHead(bundle.network.width, 12, 8, output=bundle.network.output)
    with torch.no_grad():
        head.bias.normal_(0.0, 0.3)
        head.final.bias.fill_(0.05)
    save_small_head(directory, head.eval(), bundle.content_hash)
    return directory


@pytest.mark.parametrize(
    ("head", "lattice"), [("small", "full"), ("full", "stride2"), ("small", "bcc")]
)
def test_small_head_and_lattices_equal_the_torch_predictor(
    small_head_dir, scaled_blob, head, lattice
):
    shape = scaled_blob(4)
    reference = Predictor(load_bundle(small_head_dir), head=head, descriptor_lattice=lattice)
    runtime = NumpyPredictor(small_head_dir, head=head, lattice=lattice)
    assert (runtime.head, runtime.lattice) == (head, lattice)
    state, expected_state = runtime.register(shape, seed=1), reference.register(shape, seed=1)
    assert state.residual == pytest.approx(expected_state.residual, rel=1e-5)
    got = runtime.distances(state, [0, 7, 40], "all")
    want = reference.distances(expected_state, [0, 7, 40], "all")
    np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-5 * float(np.abs(want).max()))
    plain = NumpyPredictor(small_head_dir, head="full", lattice="full")  # as trained
    full = plain.distances(plain.register(shape, seed=1), [0])
    assert not np.allclose(got[0], full[0])  # the options change the answer


def test_small_head_is_refused_without_a_sidecar_or_from_another_bundle(
    bundle_dir, small_head_dir, tmp_path
):
    with pytest.raises(InputError, match="no small head"):
        NumpyPredictor(bundle_dir, head="small")
    with pytest.raises(InputError, match="head must be"):
        NumpyPredictor(bundle_dir, head="tiny")
    with pytest.raises(InputError, match="lattice must be"):
        NumpyPredictor(bundle_dir, lattice="sparse")
    other = _edited_copy(
        small_head_dir, tmp_path / "other", SMALL_HEAD_CONFIG, "teacher_content_hash"
    )
    with pytest.raises(InputError, match="distil it again"):
        NumpyPredictor(other, head="small")
    with pytest.raises(InputError, match="distil it again"):
        NumpyPredictor(other)  # the default takes the sidecar it finds
    assert NumpyPredictor(other, head="full").head == "full"  # which the full head never reads
    assert NumpyPredictor(small_head_dir).head == "small"
    assert NumpyPredictor(bundle_dir).head == "full"  # no sidecar: the trained head


@pytest.mark.parametrize("name", shipped_bundles())
def test_shipped_models_match(scaled_blob, name):
    shape = scaled_blob(1, subdivisions=4)
    reference = Predictor(load_shipped(name))
    runtime = NumpyPredictor.shipped(name)
    state, expected_state = runtime.register(shape), reference.register(shape)
    assert state.ood_score == pytest.approx(expected_state.ood_score, rel=1e-4)
    got = runtime.distances(state, [0, 100, 2000])
    want = reference.distances(expected_state, [0, 100, 2000])
    np.testing.assert_allclose(got, want, rtol=1e-4, atol=1e-4 * float(want.max()))
    assert (runtime.head, runtime.lattice) == ("small", "stride2")  # the shipped defaults
    fast = NumpyPredictor.shipped(name, head="full", lattice="full")
    reference = Predictor(load_shipped(name), head="full", descriptor_lattice="full")
    got = fast.distances(fast.register(shape), [0, 100, 2000])
    want = reference.distances(reference.register(shape), [0, 100, 2000])
    np.testing.assert_allclose(got, want, rtol=1e-4, atol=1e-4 * float(want.max()))


@pytest.mark.parametrize("name", shipped_bundles())
@pytest.mark.parametrize("n_points", [300, 2000])
def test_shipped_fusion_equals_the_torch_predictor(scaled_blob, name, n_points):
    """The default (``fusion="auto"``: the shipped calibration) on a cloud, a mesh and a noisy
    mesh (smoothed before its graph): the same veto, graph, normal limit, smoothing and blend as
    the torch predictor."""
    mesh = scaled_blob(2, subdivisions=4)
    rng = np.random.default_rng(n_points)
    cloud = Shape.from_arrays(mesh.vertices[rng.choice(mesh.n_points, n_points, replace=False)])
    edge = float(np.linalg.norm(mesh.vertices[mesh.faces[0, 0]] - mesh.vertices[mesh.faces[0, 1]]))
    noisy = Shape.from_arrays(
        mesh.vertices + rng.normal(0.0, 0.5 * edge, (mesh.n_points, 3)), mesh.faces
    )
    runtime, reference = NumpyPredictor.shipped(name), Predictor(load_shipped(name))
    assert runtime.fusion is not None and runtime.fusion == reference.fusion
    assert runtime.fusion.mesh_smooth_noise is not None
    network = NumpyPredictor.shipped(name, fusion="none")
    for shape in (cloud, mesh, noisy):
        got = runtime.distances(runtime.register(shape), [0, 7, 150], "all")
        want = reference.distances(reference.register(shape), [0, 7, 150], "all")
        np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-5 * float(want.max()))
        alone = network.distances(network.register(shape), [0, 7, 150], "all")
        assert np.abs(alone - got).mean() > 1e-3 * float(want.mean())  # the blend did act
    state = runtime.register(noisy)
    runtime.distances(state, [0], "all")
    assert any(key.startswith("fusion.mesh_denoised.") for key in state._kept)  # smoothed


@pytest.mark.parametrize("name", shipped_bundles())
def test_a_mesh_evaluates_no_network(scaled_blob, name, monkeypatch):
    """A mesh its ring graph spans is answered by the graph alone (the fusion's weight of the
    network on a mesh is 0): the runtime embeds no point, and answers as the torch predictor."""
    mesh = scaled_blob(2, subdivisions=3)
    runtime, reference = NumpyPredictor.shipped(name), Predictor(load_shipped(name))
    state = runtime.register(mesh)

    def refuse(*args, **kwargs):
        raise AssertionError("the network was evaluated")

    monkeypatch.setattr(runtime, "_network", refuse)
    got = runtime.distances(state, [0, 7, 150], "all")
    want = reference.distances(reference.register(mesh), [0, 7, 150], "all")
    np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-5 * float(want.max()))


@pytest.mark.parametrize("name", shipped_bundles())
def test_agreement_equals_the_torch_predictors(scaled_blob, name):
    mesh = scaled_blob(3, subdivisions=4)
    cloud = Shape.from_arrays(mesh.vertices[::2])
    runtime, reference = NumpyPredictor.shipped(name), Predictor(load_shipped(name))
    for shape in (cloud, mesh):
        got = runtime.agreement(runtime.register(shape))
        want = reference.agreement(reference.register(shape))
        assert got == pytest.approx(want, rel=1e-4) and want > 0
    plain = NumpyPredictor.shipped(name, fusion="none")
    assert np.isnan(plain.agreement(plain.register(cloud)))


def test_errors_at_the_boundary(bundle_dir, scaled_blob, tmp_path):
    runtime = NumpyPredictor(bundle_dir)
    state = runtime.register(scaled_blob(0, subdivisions=2))
    with pytest.raises(IndexOutOfRangeError):
        runtime.distances(state, [state.n_points])
    with pytest.raises(ArrayShapeError):
        runtime.distances(state, [])
    with pytest.raises(InputError, match="xyz"):
        runtime.distances(state, np.zeros((1, 3)))
    with pytest.raises(InputError, match="expected a Shape"):
        runtime.register(np.zeros((10, 3)))
    with pytest.raises(InputError, match="unknown model"):
        NumpyPredictor.shipped("dragons")

    other = _edited_copy(bundle_dir, tmp_path / "other", MANIFEST, "content_hash")
    with pytest.raises(InputError, match="not registered with this bundle"):
        NumpyPredictor(other).distances(state, [0])

    damaged = tmp_path / "damaged"
    shutil.copytree(bundle_dir, damaged)
    (damaged / NETWORK_FILE).write_bytes(b"not safetensors")
    with pytest.raises(ArtifactError, match="hash"):
        NumpyPredictor(damaged)


def test_never_imports_torch():
    code = (
        "import sys, numpy as np\n"
        "from litege_core.learned.numpy_predictor import NumpyPredictor\n"
        "from litege_core.shape import Shape\n"
        "runtime = NumpyPredictor.shipped('quadrupeds', head='small', lattice='stride2')\n"
        "points = np.random.default_rng(0).normal(size=(300, 3)) * [2.0, 0.6, 0.8]\n"
        "state = runtime.register(Shape.from_arrays(points))\n"
        "assert runtime.distances(state, [0, 1]).shape == (2, 300)\n"
        "print(sorted(m for m in sys.modules if m == 'torch' or m.startswith('torch.')))\n"
    )
    result = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True
    )
    assert result.stdout.strip() == "[]"
