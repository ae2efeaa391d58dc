"""``litege sample``: procedural sample shapes written in every format ``save_shape`` writes."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from litege_core import synth
from litege_core.cli import build_parser, main
from litege_core.cli.sample import CATEGORY_FAMILIES, family_choices, resolve_family
from litege_core.io import MESH_FORMATS, POINT_FORMATS, load_shape


def _run(capsys, *argv: str) -> dict:
    assert main(["sample", *argv]) == 0
    return json.loads(capsys.readouterr().out)


def test_the_spelled_out_families_are_the_generators():
    assert set(CATEGORY_FAMILIES) == set(synth.CATEGORIES)
    for category, names in CATEGORY_FAMILIES.items():
        assert names == synth.families(category)


@pytest.mark.parametrize(
    ("name", "expected"),
    [
        ("dog", ("quadruped", "dog")),
        ("Hippo", ("quadruped", "hippo")),
        ("human", ("biped", "average")),
        ("human-slim", ("biped", "slim")),
        ("child", ("biped", "child")),
    ],
)
def test_family_names(name, expected):
    assert resolve_family(name) == expected
    assert expected[1] in " ".join(family_choices())


def test_help_lists_every_family(capsys):
    with pytest.raises(SystemExit):
        build_parser(plugins=False).parse_args(["sample", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    for category in synth.CATEGORIES:
        for family in synth.families(category):
            assert family in text
        for pose in synth.pose_modes(category):
            assert pose in text


def test_dog_obj_is_the_generated_mesh(tmp_path, capsys):
    out = tmp_path / "dog.obj"
    report = _run(capsys, "dog", "-o", str(out))
    expected = synth.generate_shape("quadruped", "dog", seed=0).to_shape()
    shape = load_shape(out)
    assert shape.is_mesh and report["kind"] == "mesh"
    np.testing.assert_array_equal(shape.faces, expected.faces)
    np.testing.assert_allclose(shape.vertices, expected.vertices, atol=1e-12)
    assert report["content_hash"] == shape.content_hash
    assert report["family"] == "dog" and report["category"] == "quadruped"
    assert (report["n_points"], report["n_faces"]) == (shape.n_points, shape.n_faces)


def test_the_same_seed_gives_the_same_file_and_another_seed_another(tmp_path, capsys):
    first = _run(capsys, "cat", "-o", str(tmp_path / "a.ply"), "--seed", "4")
    again = _run(capsys, "cat", "-o", str(tmp_path / "b.ply"), "--seed", "4")
    other = _run(capsys, "cat", "-o", str(tmp_path / "c.ply"), "--seed", "5")
    assert (tmp_path / "a.ply").read_bytes() == (tmp_path / "b.ply").read_bytes()
    assert first["content_hash"] == again["content_hash"] != other["content_hash"]


@pytest.mark.parametrize("extension", sorted(MESH_FORMATS))
def test_every_mesh_format(tmp_path, capsys, extension):
    out = tmp_path / f"horse.{extension}"
    report = _run(capsys, "horse", "-o", str(out), "--seed", "1")
    shape = load_shape(out, kind="mesh")
    assert shape.is_mesh and shape.n_faces == report["n_faces"] > 0
    expected = synth.generate_shape("quadruped", "horse", seed=1).vertices
    if extension == "stl":  # a triangle soup: vertices are merged on reading, order not kept
        expected, got = np.unique(expected, axis=0), np.unique(shape.vertices, axis=0)
        np.testing.assert_allclose(got, expected.astype(np.float32), atol=1e-5)
    else:
        np.testing.assert_allclose(shape.vertices, expected, atol=1e-5)  # PLY, GLB: float32


@pytest.mark.parametrize("extension", sorted(POINT_FORMATS))
def test_point_clouds_of_vertices_or_surface_samples(tmp_path, capsys, extension):
    out = tmp_path / f"human.{extension}"
    report = _run(capsys, "human-heavy", "-o", str(out), "--kind", "point_cloud")
    cloud = load_shape(out, kind="point_cloud")
    expected = synth.generate_shape("biped", "heavy", seed=0).vertices
    assert not cloud.is_mesh and report["kind"] == "point_cloud" and report["n_faces"] == 0
    np.testing.assert_allclose(cloud.vertices, expected, atol=1e-5)

    sampled = tmp_path / f"sampled.{extension}"
    report = _run(capsys, "cow", "-o", str(sampled), "--kind", "point_cloud", "--points", "500")
    assert report["n_points"] == 500 == load_shape(sampled, kind="point_cloud").n_points


def test_xyz_defaults_to_a_point_cloud_and_the_pose_is_honoured(tmp_path, capsys):
    report = _run(capsys, "dog", "-o", str(tmp_path / "dog.xyz"), "--pose", "lying")
    assert report["kind"] == "point_cloud" and report["pose"] == "lying"
    report = _run(capsys, "cat", "-o", str(tmp_path / "cat.xyz"), "--pose", "rearing")
    assert report["pose"] == "rearing"  # a mode seeds never draw, asked for by name


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["pig", "-o", "x.obj"], "unknown family 'pig'"),
        (["dog", "-o", "x.xyz", "--kind", "mesh"], "point clouds only"),
        (["dog", "-o", "x.stl", "--kind", "point_cloud"], "meshes only"),
        (["dog", "-o", "x.obj", "--points", "100"], "--points applies"),
        (["dog", "-o", "x.xyz", "--points", "2"], "at least 4"),
        (["dog", "-o", "x.obj", "--pose", "crouching"], "unknown quadruped pose"),
        (["dog", "-o", "x.obj", "--seed", "-1"], "non-negative"),
        (["dog", "-o", "x.txt"], "unsupported file extension"),
        (["dog", "-o", "missing-dir/x.obj"], "no directory"),
    ],
)
def test_bad_requests_are_one_line_errors(tmp_path, capsys, monkeypatch, argv, message):
    monkeypatch.chdir(tmp_path)
    assert main(["sample", *argv]) == 2
    err = capsys.readouterr().err
    assert err.startswith("litege: error [") and message in err
    assert list(Path(tmp_path).iterdir()) == []


def test_console_script_writes_a_sample_in_the_working_directory(tmp_path):
    script = Path(sys.executable).with_name("litege")
    result = subprocess.run(
        [str(script), "sample", "dog", "-o", "dog.obj"],
        capture_output=True,
        text=True,
        cwd=tmp_path,
        timeout=120,
        check=False,
    )
    assert result.returncode == 0, result.stderr
    assert json.loads(result.stdout)["output"] == "dog.obj"
    assert load_shape(tmp_path / "dog.obj").n_points == 3900
