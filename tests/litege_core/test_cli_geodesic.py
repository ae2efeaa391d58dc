"""`litege geodesic` and `litege path`: round trips through files, and errors with exit code 2."""

import json
import subprocess
import sys

import numpy as np
import pytest
import torch
import trimesh

from litege_core.cli import main
from litege_core.descriptor import VoxelGrid, fit_basis
from litege_core.io import load_shape, save_shape
from litege_core.learned import Predictor, load_bundle, save_bundle, shipped_bundles
from litege_core.nets import GeodesicNet
from litege_core.shape import Shape

K = 3


@pytest.fixture(scope="module")
def bundle_dir(tmp_path_factory):
    mesh = trimesh.creation.icosphere(subdivisions=2)
    shapes = []
    for seed in range(5):
        stretch = np.random.default_rng(seed).uniform(0.3, 0.6, 3)
        shapes.append((np.asarray(mesh.vertices) * stretch, np.asarray(mesh.faces)))
    basis = fit_basis(
        shapes,
        grid=VoxelGrid(resolution=17, pitch=0.12),
        std_threshold=0.05,
        n_components=K,
        n_udf_samples=300,
        seed=0,
    )
    torch.manual_seed(0)
    net = GeodesicNet(width=32, descriptor_dim=K)
    net.set_coord_normalization([0.0, 0.0, 0.0], [0.4, 0.3, 0.2])
    directory = tmp_path_factory.mktemp("cli") / "toy"
    save_bundle(directory, name="toy", category="toy", basis=basis, network=net.eval())
    return directory


@pytest.fixture(scope="module")
def mesh_file(tmp_path_factory):
    sphere = trimesh.creation.icosphere(subdivisions=3)
    vertices = np.asarray(sphere.vertices) * [30.0, 20.0, 12.0] + [100.0, -5.0, 7.0]
    vertices[:, 1] += 0.01 * (vertices[:, 0] - 100.0) ** 2
    path = tmp_path_factory.mktemp("shapes") / "blob.ply"
    save_shape(Shape.from_arrays(vertices, sphere.faces), path)
    return path


@pytest.fixture(scope="module")
def predictor(bundle_dir):
    return Predictor(load_bundle(bundle_dir))


def test_geodesic_round_trip(tmp_path, bundle_dir, mesh_file, predictor, capsys):
    out = tmp_path / "d.npy"
    code = main(
        [
            "geodesic",
            str(mesh_file),
            "--sources",
            "0,17,42",
            "--bundle",
            str(bundle_dir),
            "-o",
            str(out),
        ]
    )
    assert code == 0
    report = json.loads(capsys.readouterr().out)
    assert report["shape"] == [3, 642] and report["runtime"] == "numpy"  # torch-free default
    distances = np.load(out)
    shape = load_shape(mesh_file)
    assert distances.dtype == np.float32 and distances.shape == (3, shape.n_points)
    state = predictor.register(shape)
    expected = predictor.distances(state, [0, 17, 42])
    np.testing.assert_allclose(distances, expected, rtol=1e-5, atol=1e-5 * expected.max())
    assert report["ood_score"] == pytest.approx(state.ood_score, rel=1e-5)
    assert distances[1, 17] == 0.0
    # input units: the blob is tens of units across
    assert 5.0 < np.median(distances) < 200.0

    out_targets = tmp_path / "t.npy"
    code = main(
        [
            "geodesic",
            str(mesh_file),
            "--sources",
            "5",
            "--targets",
            "1, 2,3",
            "--bundle",
            str(bundle_dir),
            "-o",
            str(out_targets),
        ]
    )
    assert code == 0
    targets = np.load(out_targets)
    assert targets.shape == (1, 3)
    np.testing.assert_allclose(targets, predictor.distances(state, [5], [1, 2, 3]), rtol=1e-5)


def test_the_torch_runtime_is_the_predictor(tmp_path, bundle_dir, mesh_file, predictor, capsys):
    out = tmp_path / "d.npy"
    argv = ["geodesic", str(mesh_file), "--sources", "0,17", "--bundle", str(bundle_dir)]
    assert main([*argv, "--runtime", "torch", "-o", str(out)]) == 0
    assert json.loads(capsys.readouterr().out)["runtime"] == "torch"
    state = predictor.register(load_shape(mesh_file))
    np.testing.assert_array_equal(np.load(out), predictor.distances(state, [0, 17]))
    # the sparser lattice runs on the numpy runtime too, and equals the torch predictor's
    assert main([*argv, "--lattice", "stride2", "-o", str(out)]) == 0
    report = json.loads(capsys.readouterr().out)
    assert (report["runtime"], report["lattice"]) == ("numpy", "stride2")
    sparse = Predictor(predictor.bundle, descriptor_lattice="stride2")
    want = sparse.distances(sparse.register(load_shape(mesh_file)), [0, 17])
    np.testing.assert_allclose(np.load(out), want, rtol=1e-5, atol=1e-5 * float(want.max()))
    # an option only the torch predictor implements: numpy refuses it
    assert main([*argv, "--runtime", "numpy", "--device", "cuda", "-o", str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err
    assert "[invalid-input]" in err and "--device cuda" in err
    assert not (tmp_path / "x").exists()


def test_geodesic_on_a_point_cloud_file(tmp_path, bundle_dir, predictor):
    points = np.random.default_rng(0).normal(size=(400, 3)) * [3.0, 2.0, 1.0]
    cloud_file = tmp_path / "cloud.xyz"
    np.savetxt(cloud_file, points)
    out = tmp_path / "c.npy"
    code = main(
        ["geodesic", str(cloud_file), "--sources", "3", "--bundle", str(bundle_dir), "-o", str(out)]
    )
    assert code == 0
    state = predictor.register(load_shape(cloud_file))
    np.testing.assert_allclose(np.load(out), predictor.distances(state, [3]), rtol=1e-5)


# Modules `litege geodesic` on a point cloud must not import (issue 17: CLI start-up time). torch
# cost ~2 s, scipy alone ~0.3 s; it, trimesh and the engines load on first use (paths, meshes,
# baselines, and the graph fusion of a model that ships a calibration: the toy bundle does not).
NOT_FOR_A_CLOUD_GEODESIC = (
    "torch",  # the numpy runtime (about 2 s of start-up less)
    "scipy",
    "trimesh",
    "PIL",
    "litege_core.engines",
    "litege_core.matching",
    "litege_core.evaluation",
    "litege_core.datasets",
    "litege_core.train",
    "litege_core.render",
    "litege_core.synth",
    "litege_core.variants",
)


def test_geodesic_on_a_cloud_imports_only_what_it_needs(tmp_path, bundle_dir):
    cloud_file = tmp_path / "cloud.npy"
    np.save(cloud_file, np.random.default_rng(0).normal(size=(300, 3)) * [3.0, 2.0, 1.0])
    argv = ["geodesic", str(cloud_file), "--sources", "0", "--bundle", str(bundle_dir)]
    argv += ["-o", str(tmp_path / "d.npy")]
    code = (
        "import sys\n"
        "from litege_core.cli import main\n"
        f"assert main({argv!r}) == 0\n"
        f"heavy = {NOT_FOR_A_CLOUD_GEODESIC!r}\n"
        "print('LOADED', sorted({m for m in sys.modules for h in heavy "
        "if m == h or m.startswith(h + '.')}))\n"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
    assert "LOADED []" in result.stdout, result.stdout


def test_path_round_trip(tmp_path, bundle_dir, mesh_file, capsys):
    out = tmp_path / "p.npy"
    code = main(
        [
            "path",
            str(mesh_file),
            "--source",
            "3",
            "--target",
            "200",
            "--bundle",
            str(bundle_dir),
            "-o",
            str(out),
        ]
    )
    assert code == 0
    assert '"converged"' in capsys.readouterr().out
    polyline = np.load(out)
    shape = load_shape(mesh_file)
    assert polyline.dtype == np.float32 and polyline.ndim == 2 and polyline.shape[1] == 3
    np.testing.assert_allclose(polyline[0], shape.vertices[3], rtol=1e-6)  # source → target
    np.testing.assert_allclose(polyline[-1], shape.vertices[200], rtol=1e-6)


@pytest.mark.parametrize(
    ("arguments", "code_slug"),
    [
        (["--sources", "0,100000"], "index-out-of-range"),
        (["--sources", "0", "--targets", "-1"], "index-out-of-range"),
        (["--sources", "a,b"], "invalid-input"),
        (["--sources", "0", "--targets", "1,x"], "invalid-input"),
        (["--sources", "0", "--seed", "-1"], "invalid-input"),
    ],
)
def test_geodesic_errors(tmp_path, bundle_dir, mesh_file, capsys, arguments, code_slug):
    out = tmp_path / "x.npy"
    code = main(
        ["geodesic", str(mesh_file), *arguments, "--bundle", str(bundle_dir), "-o", str(out)]
    )
    assert code == 2
    assert f"[{code_slug}]" in capsys.readouterr().err
    assert not out.exists()


def test_unknown_model_and_missing_default(tmp_path, mesh_file, capsys):
    out = tmp_path / "x.npy"
    code = main(["geodesic", str(mesh_file), "--sources", "0", "--model", "nope", "-o", str(out)])
    assert code == 2
    err = capsys.readouterr().err
    assert "[invalid-input]" in err and "'nope'" in err and "shipped models" in err
    if "quadrupeds" not in shipped_bundles():
        code = main(["path", str(mesh_file), "--source", "0", "--target", "1", "-o", str(out)])
        assert code == 2
        assert "quadrupeds" in capsys.readouterr().err


def test_bad_files_bundles_and_devices(tmp_path, bundle_dir, mesh_file, capsys):
    junk = tmp_path / "junk.obj"
    junk.write_text("this is not a mesh\n")
    out = tmp_path / "x.npy"
    assert (
        main(["geodesic", str(junk), "--sources", "0", "--bundle", str(bundle_dir), "-o", str(out)])
        == 2
    )
    assert "litege: error [" in capsys.readouterr().err
    assert (
        main(
            [
                "path",
                str(mesh_file),
                "--source",
                "0",
                "--target",
                "1",
                "--bundle",
                str(tmp_path),
                "-o",
                str(out),
            ]
        )
        == 2
    )
    assert "[artifact-error]" in capsys.readouterr().err
    assert (
        main(
            [
                "path",
                str(mesh_file),
                "--source",
                "0",
                "--target",
                "1",
                "--bundle",
                str(bundle_dir),
                "--device",
                "nonsense",
                "-o",
                str(out),
            ]
        )
        == 2
    )
    assert "[invalid-input]" in capsys.readouterr().err
    missing_dir = tmp_path / "no" / "such" / "dir" / "x.npy"
    assert (
        main(
            [
                "geodesic",
                str(mesh_file),
                "--sources",
                "0",
                "--bundle",
                str(bundle_dir),
                "-o",
                str(missing_dir),
            ]
        )
        == 2
    )
    assert "cannot write" in capsys.readouterr().err


@pytest.mark.parametrize("method", ["heat", "exact", "graph"])
def test_geodesic_with_a_classical_method(tmp_path, method, mesh_file, capsys):
    """--method picks the engine; the answer says which one ran and matches the library."""
    from litege_core.engines import ClassicalSolver

    mesh = mesh_file
    out = tmp_path / "d.npy"
    assert (
        main(["geodesic", str(mesh), "--sources", "0,5", "--method", method, "-o", str(out)]) == 0
    )
    report = json.loads(capsys.readouterr().out)
    solver = ClassicalSolver(load_shape(mesh), method)
    assert report["method"] == method and report["engine"] == solver.engine
    np.testing.assert_allclose(np.load(out), solver.distances([0, 5]), rtol=1e-6)


def test_exact_method_refuses_a_large_mesh_and_a_cloud(tmp_path, mesh_file, capsys):
    mesh = mesh_file
    args = ["geodesic", str(mesh), "--sources", "0", "--method", "exact", "-o", str(tmp_path / "d")]
    assert main([*args, "--max-exact-vertices", "10"]) == 2
    assert "method-size-limit" in capsys.readouterr().err
    cloud = tmp_path / "cloud.xyz"
    np.savetxt(cloud, np.random.default_rng(0).normal(size=(50, 3)))
    out = str(tmp_path / "x.npy")
    assert main(["geodesic", str(cloud), "--sources", "0", "--method", "exact", "-o", out]) == 2
    assert "point cloud" in capsys.readouterr().err


def test_path_with_the_exact_method(tmp_path, mesh_file, capsys):
    mesh = mesh_file
    out = tmp_path / "p.npy"
    assert (
        main(
            [
                "path",
                str(mesh),
                "--source",
                "0",
                "--target",
                "7",
                "--method",
                "exact",
                "-o",
                str(out),
            ]
        )
        == 0
    )
    report = json.loads(capsys.readouterr().out)
    assert report["engine"] == "exact-mmp" and report["segments"] == [[0, "exact-mmp"]]
    points = np.load(out)
    assert points.shape == (report["n_points"], 3)
    assert report["length"] == pytest.approx(report["distance"], rel=1e-5)
