"""``litege geodesic --fusion graph`` (issue 14): the bundle's calibrated graph fusion from the
command line, and a clear error where the bundle has no calibration."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from litege_core.cli import main
from litege_core.io import load_shape, save_shape
from litege_core.learned import Predictor, load_bundle
from litege_core.learned.fusion_calibration import FUSIONS, FusionCalibration, save_fusion


def _calibrate(directory) -> None:
    """Save a fusion calibration beside the bundle in ``directory`` (a cloud's weight: 1/2)."""
    calibration = FusionCalibration(
        8,
        1e9,
        (3.0,),
        (1.0,),
        (0.0, 0.0, 0.0, 0.0),
        mesh_bias=1.0,
        bundle_hash=load_bundle(directory).content_hash,
    )
    save_fusion(directory, calibration)


def test_geodesic_with_graph_fusion(tmp_path, toy_bundle_dir_with_ood, blob, capsys) -> None:
    directory = tmp_path / "toy"
    shutil.copytree(toy_bundle_dir_with_ood, directory)
    mesh_file = tmp_path / "blob.ply"
    save_shape(blob(3), mesh_file)
    out = tmp_path / "d.npy"
    args = ["geodesic", str(mesh_file), "--sources", "0,7", "--bundle", str(directory)]
    assert main([*args, "--fusion", "graph", "-o", str(out)]) == 2
    assert "no graph-fusion calibration" in capsys.readouterr().err and not out.exists()
    plain_out = tmp_path / "plain.npy"
    assert main([*args, "-o", str(plain_out)]) == 0  # auto: no calibration, the network alone
    assert json.loads(capsys.readouterr().out)["fusion"] == "none"

    _calibrate(directory)
    fused = Predictor(load_bundle(directory), fusion="graph")
    expected = fused.distances(fused.register(load_shape(mesh_file)), [0, 7])
    for option in (["--fusion", "graph"], [], ["--runtime", "torch"]):  # auto: graph now
        assert main([*args, *option, "-o", str(out)]) == 0
        report = json.loads(capsys.readouterr().out)
        assert report["fusion"] == "graph"
        assert report["runtime"] == ("torch" if option == ["--runtime", "torch"] else "numpy")
        np.testing.assert_allclose(np.load(out), expected, rtol=1e-5, atol=1e-6)
    assert main([*args, "--fusion", "none", "-o", str(out)]) == 0
    assert json.loads(capsys.readouterr().out)["fusion"] == "none"
    np.testing.assert_array_equal(np.load(out), np.load(plain_out))
    assert not np.allclose(np.load(plain_out), expected)


def test_the_fusion_option_is_the_predictor_option() -> None:
    from litege_core.cli.common import FUSIONS as CLI_FUSIONS
    from litege_core.cli.common import ROUTES as CLI_ROUTES
    from litege_core.learned.paths import ROUTES

    assert CLI_FUSIONS == FUSIONS and CLI_ROUTES == ROUTES


def test_path_routes_with_and_without_fusion(tmp_path, toy_bundle_dir_with_ood, blob, capsys):
    directory = tmp_path / "toy"
    shutil.copytree(toy_bundle_dir_with_ood, directory)
    _calibrate(directory)
    mesh_file = tmp_path / "blob.ply"
    save_shape(blob(3), mesh_file)
    out = tmp_path / "p.npy"
    args = ["path", str(mesh_file), "--source", "3", "--target", "200", "--bundle", str(directory)]
    reports = {}
    for option in ([], ["--route", "learned"], ["--fusion", "none"], ["--route", "surface"]):
        assert main([*args, *option, "-o", str(out)]) == 0
        reports[" ".join(option)] = (json.loads(capsys.readouterr().out), np.load(out))
    auto, polyline = reports[""]
    assert auto["fusion"] == "graph" and auto["route"] == "auto" and auto["n_steps"] == 0
    assert auto["segments"][0][1] in ("edge-flip", "mesh-edges")  # the fused mesh's surface
    np.testing.assert_array_equal(polyline, reports["--route surface"][1])
    assert reports["--fusion none"][0]["fusion"] == "none"
    for option in ("--route learned", "--fusion none"):  # the walk
        assert reports[option][0]["n_steps"] > 0
    with pytest.raises(SystemExit):  # argparse refuses an unknown route
        main([*args, "--route", "shortest", "-o", str(out)])


def test_auto_picks_the_model_of_the_shapes_category(tmp_path, capsys) -> None:
    """``--model auto`` registers the shape under every shipped model and answers with the one
    ``choose_model`` keeps (the numpy and the torch runtime alike)."""
    from litege_core.learned import load_shipped
    from litege_core.shape import Shape
    from litege_core.synth import families, generate_shape
    from litege_core.variants import point_cloud

    for category, expected in (("quadruped", "quadrupeds"), ("biped", "humans")):
        generated = generate_shape(category, families(category)[0], 2_000_005)
        cloud = point_cloud(generated.vertices, generated.faces, 800, 0).points
        path = tmp_path / f"{category}.npy"
        np.save(path, cloud)
        named = Predictor(load_shipped(expected))
        want = named.distances(named.register(Shape.from_arrays(cloud)), [0, 3])
        for runtime in ("numpy", "torch"):
            out = tmp_path / f"{category}-{runtime}.npy"
            argv = ["geodesic", str(path), "--sources", "0,3", "--model", "auto"]
            assert main([*argv, "--runtime", runtime, "-o", str(out)]) == 0
            report = json.loads(capsys.readouterr().out)
            assert report["model"] == expected
            assert set(report["model_scores"]) == {"quadrupeds", "humans"}
            np.testing.assert_allclose(np.load(out), want, rtol=1e-4, atol=1e-4 * float(want.max()))
