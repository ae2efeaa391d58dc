"""``litege geodesic --head small`` and ``litege path --head small`` (issue 17): the bundle's
distilled head from the command line, and a clear error where the bundle has none."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
import torch

from litege_core.cli import main
from litege_core.io import load_shape, save_shape
from litege_core.learned import Predictor, load_bundle
from litege_core.learned.small_head import save_small_head
from litege_core.nets.small_head import SmallHead


@pytest.fixture(scope="module")
def bundle_dir(tmp_path_factory, toy_predictor):
    directory = tmp_path_factory.mktemp("cli-head") / "toy"
    shutil.copytree(toy_predictor.bundle.path, directory)
    torch.manual_seed(2)
    bundle = load_bundle(directory)
    save_small_head(directory, SmallHead(bundle.network.width, 12, 8), bundle.content_hash)
    return directory


@pytest.fixture(scope="module")
def mesh_file(tmp_path_factory, blob):
    path = tmp_path_factory.mktemp("cli-head-shapes") / "blob.ply"
    save_shape(blob(3), path)
    return path


def _assert_same_answers(got: np.ndarray, want: np.ndarray) -> None:
    """The CLI's answer equals the predictor's to float32 rounding (the numpy runtime, or torch
    on another thread count)."""
    np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-5 * float(np.abs(want).max()))


def test_geodesic_and_path_with_the_small_head(tmp_path, bundle_dir, mesh_file, capsys) -> None:
    out = tmp_path / "d.npy"
    args = ["geodesic", str(mesh_file), "--sources", "0,7", "--bundle", str(bundle_dir)]
    assert main([*args, "--head", "small", "-o", str(out)]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["head"] == "small" and report["shape"][0] == 2
    assert report["runtime"] == "numpy"  # the torch-free runtime runs the small head too
    small = Predictor(load_bundle(bundle_dir), head="small")
    state = small.register(load_shape(mesh_file))
    _assert_same_answers(np.load(out), small.distances(state, [0, 7]))
    assert main([*args, "--head", "small", "--runtime", "torch", "-o", str(out)]) == 0
    assert json.loads(capsys.readouterr().out)["runtime"] == "torch"
    _assert_same_answers(np.load(out), small.distances(state, [0, 7]))
    default_out = tmp_path / "default.npy"
    assert main([*args, "-o", str(default_out)]) == 0  # the default: the small head it ships
    assert json.loads(capsys.readouterr().out)["head"] == "small"
    _assert_same_answers(np.load(default_out), np.load(out))
    full_out = tmp_path / "full.npy"
    assert main([*args, "--head", "full", "-o", str(full_out)]) == 0
    assert json.loads(capsys.readouterr().out)["head"] == "full"
    assert not np.allclose(np.load(full_out), np.load(out))
    polyline = tmp_path / "p.npy"
    path_args = ["path", str(mesh_file), "--source", "0", "--target", "300"]
    code = main([*path_args, "--bundle", str(bundle_dir), "--head", "small", "-o", str(polyline)])
    assert code == 0 and json.loads(capsys.readouterr().out)["head"] == "small"
    assert np.load(polyline).shape[1] == 3


def test_a_bundle_without_a_small_head_is_a_clear_error(
    tmp_path, toy_predictor, mesh_file, capsys
) -> None:
    out = tmp_path / "d.npy"
    args = ["geodesic", str(mesh_file), "--sources", "0", "--head", "small", "-o", str(out)]
    assert main([*args, "--bundle", str(toy_predictor.bundle.path)]) == 2
    assert "has no small head" in capsys.readouterr().err and not out.exists()


def test_the_lattice_option_is_the_predictor_option(tmp_path, bundle_dir, mesh_file, capsys):
    from litege_core.cli.common import LATTICE_CHOICES
    from litege_core.descriptor.basis import LATTICE_CHOICES as LIBRARY_LATTICES

    assert LATTICE_CHOICES == LIBRARY_LATTICES
    out = tmp_path / "d.npy"
    args = ["geodesic", str(mesh_file), "--sources", "0,7", "--bundle", str(bundle_dir)]
    assert main([*args, "--head", "small", "--lattice", "stride2", "-o", str(out)]) == 0
    assert json.loads(capsys.readouterr().out)["lattice"] == "stride2"
    fast = Predictor(load_bundle(bundle_dir), head="small", descriptor_lattice="stride2")
    state = fast.register(load_shape(mesh_file))
    _assert_same_answers(np.load(out), fast.distances(state, [0, 7]))
    with pytest.raises(SystemExit):
        main([*args, "--lattice", "sparse", "-o", str(out)])
