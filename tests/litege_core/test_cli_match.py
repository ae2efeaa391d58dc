"""``litege match``: output file, agreement with the library, errors."""

from __future__ import annotations

import json

import numpy as np
import pytest
import trimesh

from litege_core.cli import main
from litege_core.io import load_shape
from litege_core.matching import MatchingModel
from litege_core.matching.testing import save_tiny_matching_bundle
from litege_core.synth import families, generate_shape


@pytest.fixture(scope="module")
def bundle_dir(tmp_path_factory):
    directory = tmp_path_factory.mktemp("match") / "tiny-matching"
    save_tiny_matching_bundle(directory)
    return directory


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    directory = tmp_path_factory.mktemp("shapes")
    paths = []
    for k, family in enumerate(families("quadruped")[:2]):
        shape = generate_shape("quadruped", family, 2_000_000 + k)
        path = directory / f"{family}.obj"
        trimesh.Trimesh(shape.vertices, shape.faces, process=False).export(path)
        paths.append(path)
    return paths


def test_match_writes_int64_indices_equal_to_the_library(bundle_dir, files, tmp_path, capsys):
    out = tmp_path / "m.npy"
    code = main(
        [
            "match",
            str(files[0]),
            str(files[1]),
            "--bundle",
            str(bundle_dir),
            "--queries",
            "0,5,17",
            "-o",
            str(out),
        ]
    )
    assert code == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["n_queries"] == 3 and summary["scaling"] == ["unit_area", "unit_area"]
    matches = np.load(out)
    assert matches.dtype == np.int64 and matches.shape == (3,)
    model = MatchingModel.load(bundle_dir, precision="auto")  # the CLI's default
    x, y = model.prepare_many([load_shape(files[0]), load_shape(files[1])])
    np.testing.assert_array_equal(matches, model.match(x, y, [0, 5, 17]).indices)


def test_match_precision_runs_the_search_head_in_bfloat16(bundle_dir, files, tmp_path):
    out = tmp_path / "bf16.npy"
    args = ["match", str(files[0]), str(files[1]), "--bundle", str(bundle_dir)]
    assert main([*args, "--queries", "0,5,17", "--precision", "bfloat16", "-o", str(out)]) == 0
    model = MatchingModel.load(bundle_dir, precision="bfloat16")
    x, y = model.prepare_many([load_shape(files[0]), load_shape(files[1])])
    np.testing.assert_array_equal(np.load(out), model.match(x, y, [0, 5, 17]).indices)


def test_match_all_queries_covers_every_point_of_x(bundle_dir, files, tmp_path):
    out = tmp_path / "all.npy"
    assert (
        main(["match", str(files[0]), str(files[1]), "--bundle", str(bundle_dir), "-o", str(out)])
        == 0
    )
    assert np.load(out).shape == (load_shape(files[0]).n_points,)


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--queries", "0,999999"], "outside"),
        (["--queries", "a,b"], "integer"),
        (["--precision", "float16"], "precision"),
        (["--seed", "-1"], "seed must be a non-negative integer"),
    ],
)
def test_match_reports_bad_input_with_exit_code_2(
    bundle_dir, files, tmp_path, capsys, extra, message
):
    out = tmp_path / "bad.npy"
    code = main(
        ["match", str(files[0]), str(files[1]), "--bundle", str(bundle_dir), *extra, "-o", str(out)]
    )
    assert code == 2
    assert message in capsys.readouterr().err
    assert not out.exists()


def test_match_unknown_model_is_a_clear_error(files, tmp_path, capsys):
    code = main(
        ["match", str(files[0]), str(files[1]), "--model", "nope", "-o", str(tmp_path / "x.npy")]
    )
    assert code == 2
    assert "unknown matching model" in capsys.readouterr().err


def test_match_reports_frames_and_refines_on_request(tmp_path, capsys):
    """--frames and --refine reach the model; the answer says which frame and refinement ran."""
    import json

    import numpy as np

    from litege_core.cli import main
    from litege_core.io import save_shape
    from litege_core.shape import Shape
    from litege_core.synth import generate_shape

    files = []
    for family, seed in (("dog", 2_000_001), ("cat", 2_000_002)):
        shape = generate_shape("quadruped", family, seed)
        path = tmp_path / f"{family}.ply"
        save_shape(Shape.from_arrays(shape.vertices, shape.faces), path)
        files.append(str(path))
    out = tmp_path / "m.npy"
    argv = ["match", *files, "--queries", "0,5,9", "--frames", "tnet", "--refine", "zoomout"]
    assert main([*argv, "-o", str(out)]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["frames"] == ["tnet", "tnet"] and report["refinement"]
    assert report["frame_checks"] == ["unchecked", "unchecked"]  # --frames tnet runs no check
    assert np.load(out).shape == (3,)
    # --smoothing reaches the refinement: 0 keeps the spectral map, a negative weight is refused
    raw = tmp_path / "raw.npy"
    assert main([*argv, "--smoothing", "0", "-o", str(raw)]) == 0
    capsys.readouterr()
    assert np.load(raw).shape == (3,)
    assert main([*argv, "--smoothing", "-1", "-o", str(raw)]) != 0
    assert "smoothing" in capsys.readouterr().err
    # --registration-rounds too: 0 keeps the fitted displacement, a negative count is refused
    assert main([*argv, "--registration-rounds", "0", "-o", str(raw)]) == 0
    capsys.readouterr()
    assert np.load(raw).shape == (3,)
    assert main([*argv, "--registration-rounds", "-1", "-o", str(raw)]) != 0
    assert "registration_rounds" in capsys.readouterr().err
    # --distortion-tolerance too: inf never checks, a non-positive tolerance is refused
    assert main([*argv, "--distortion-tolerance", "inf", "-o", str(raw)]) == 0
    capsys.readouterr()
    assert main([*argv, "--distortion-tolerance", "0", "-o", str(raw)]) != 0
    assert "distortion_tolerance" in capsys.readouterr().err
