"""``litege render`` and ``litege render-match``: PNG files of the right size with real
content, straight from the library (a toy geodesic bundle, a tiny matching bundle)."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
import trimesh
from PIL import Image

from litege_core.cli import main
from litege_core.descriptor import VoxelGrid, fit_basis
from litege_core.learned import save_bundle
from litege_core.matching.testing import save_tiny_matching_bundle
from litege_core.nets import GeodesicNet
from litege_core.synth import generate_shape


@pytest.fixture(scope="module")
def geodesic_bundle(tmp_path_factory):
    mesh = trimesh.creation.icosphere(subdivisions=2)
    shapes = []
    for seed in range(5):
        stretch = np.random.default_rng(seed).uniform(0.3, 0.6, 3)
        shapes.append((np.asarray(mesh.vertices) * stretch, np.asarray(mesh.faces)))
    basis = fit_basis(
        shapes,
        grid=VoxelGrid(resolution=17, pitch=0.12),
        std_threshold=0.05,
        n_components=3,
        n_udf_samples=300,
        seed=0,
    )
    torch.manual_seed(0)
    net = GeodesicNet(width=32, descriptor_dim=3)
    net.set_coord_normalization([0.0, 0.0, 0.0], [0.4, 0.3, 0.2])
    directory = tmp_path_factory.mktemp("render") / "toy"
    save_bundle(directory, name="toy", category="toy", basis=basis, network=net.eval())
    return directory


@pytest.fixture(scope="module")
def matching_bundle(tmp_path_factory):
    directory = tmp_path_factory.mktemp("render-match") / "tiny-matching"
    save_tiny_matching_bundle(directory)
    return directory


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    directory = tmp_path_factory.mktemp("render-shapes")
    paths = []
    for family in ("dog", "cat"):
        shape = generate_shape("quadruped", family, 7)
        path = directory / f"{family}.obj"
        trimesh.Trimesh(shape.vertices, shape.faces, process=False).export(path)
        paths.append(path)
    return paths


def _content(path) -> np.ndarray:
    image = np.asarray(Image.open(path).convert("RGB"))
    return image


def test_render_heatmap_with_path(geodesic_bundle, files, tmp_path, capsys):
    out = tmp_path / "heat.png"
    args = ["render", str(files[0]), "--bundle", str(geodesic_bundle), "--path", "10,2000"]
    code = main([*args, "--size", "240x180", "--ssaa", "1", "-o", str(out)])
    assert code == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["source"] == 10 and summary["path"]["target"] == 2000
    image = _content(out)
    assert image.shape == (180 + 44, 240 + 130, 3)  # title band, colour bar
    view = image[44:, :240].reshape(-1, 3)
    shape_pixels = view[(view != 255).any(axis=1)]
    assert 0.05 < len(shape_pixels) / len(view) < 0.9
    assert len(np.unique(shape_pixels // 8, axis=0)) > 40  # a field, not a flat colour
    reds = (view[:, 0] > 180) & (view[:, 1] < 90) & (view[:, 2] < 90)
    assert reds.sum() > 20  # the path


def test_render_point_cloud_default_source(geodesic_bundle, files, tmp_path, capsys):
    out = tmp_path / "cloud.png"
    code = main(
        [
            "render",
            str(files[1]),
            "--kind",
            "point_cloud",
            "--bundle",
            str(geodesic_bundle),
            "--size",
            "160x120",
            "--ssaa",
            "1",
            "-o",
            str(out),
        ]
    )
    assert code == 0
    assert json.loads(capsys.readouterr().out)["source"] == 0
    assert _content(out).shape == (120 + 44, 160 + 130, 3)


def test_render_errors_exit_2(geodesic_bundle, files, tmp_path, capsys):
    base = ["render", str(files[0]), "--bundle", str(geodesic_bundle)]
    assert main([*base, "--path", "1", "-o", str(tmp_path / "a.png")]) == 2
    assert main([*base, "--size", "big", "-o", str(tmp_path / "b.png")]) == 2
    assert main([*base, "--source", "99999999", "-o", str(tmp_path / "c.png")]) == 2
    assert main([*base, "-o", str(tmp_path / "missing" / "d.png")]) == 2
    err = capsys.readouterr().err
    assert "--path takes two indices" in err and "--size" in err and "cannot write" in err


def test_render_match_side_by_side(matching_bundle, files, tmp_path, capsys):
    out = tmp_path / "match.png"
    code = main(
        [
            "render-match",
            str(files[0]),
            str(files[1]),
            "--model",
            str(matching_bundle),
            "--size",
            "200x160",
            "--ssaa",
            "1",
            "-o",
            str(out),
        ]
    )
    assert code == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["model"] == "tiny" and summary["n_matched"] > 1000
    image = _content(out)
    assert image.shape == (160 + 26 + 44, 2 * 200 + 12, 3)
    left = image[70:, :200].reshape(-1, 3)
    right = image[70:, 212:].reshape(-1, 3)
    for half in (left, right):
        shape_pixels = half[(half != 255).any(axis=1)]
        assert len(shape_pixels) > 0.05 * len(half)
        assert len(np.unique(shape_pixels // 16, axis=0)) > 10  # coloured, not flat


def test_render_match_unknown_model_exits_2(files, tmp_path, capsys):
    out = tmp_path / "m.png"
    assert main(["render-match", str(files[0]), str(files[1]), "--model", "nope", "-o", str(out)])
    assert "unknown matching model" in capsys.readouterr().err


def test_cli_view_names_are_the_renderer_views():
    """``--view`` choices are spelled out in the CLI (building the parser imports no renderer)."""
    from litege_core.cli.render import VIEW_NAMES
    from litege_core.render.raster import VIEWS

    assert tuple(sorted(VIEWS)) == VIEW_NAMES
