"""Matching evaluation: metrics, flips, baselines, pair sets and ``litege eval matching``."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import trimesh

from litege_core.evaluation.matching import (
    FLIP_MARGIN,
    ModelChooser,
    NearestNeighbourMethod,
    SettingResult,
    ZoomOutSettings,
    auc_threshold,
    auc_x100,
    evaluate_pairs,
    flips,
    mean_error_x100,
    results_table,
)
from litege_core.evaluation.matching_data import (
    EvalShape,
    ExactRows,
    MatchPair,
    SurfacePointRows,
    eval_data_pairs,
    match_errors,
    read_pid,
    read_sym_info,
    read_vts,
)
from litege_core.shape import Shape

EVAL_DATA = Path(__file__).resolve().parents[3] / ".." / "shared" / "eval-data"


# ----------------------------------------------------------------------------- metrics


def test_perfect_matches_score_zero_error_and_full_auc():
    errors = np.zeros(50)
    assert mean_error_x100(errors) == 0.0
    assert auc_x100(errors, 0.1) == pytest.approx(100.0)
    assert auc_x100(errors, 0.2) == pytest.approx(100.0)


def test_known_offsets():
    assert mean_error_x100([0.01, 0.03]) == pytest.approx(2.0)
    assert auc_x100([0.5, 0.3], 0.2) == 0.0  # every error above the last threshold
    # Constant error e: recall steps from 0 to 1 at the first threshold ≥ e.
    thresholds = np.linspace(0.0, 0.1, 40)
    e = 0.05
    recall = (thresholds >= e).astype(float)
    expected = 100 * np.sum((recall[1:] + recall[:-1]) / 2 * np.diff(thresholds)) / 0.1
    assert auc_x100(np.full(10, e), 0.1) == pytest.approx(expected)
    assert expected == pytest.approx(100 * (1 - e / 0.1), abs=100 / 39)
    # Half perfect, half hopeless: half the area.
    assert auc_x100([0.0, 1.0], 0.2) == pytest.approx(50.0)
    assert auc_threshold("template") == 0.1
    assert auc_threshold("remesh5k") == auc_threshold("tosca") == 0.2


def test_flip_rule():
    errors = np.array([0.30, 0.30, 0.02, 0.10])
    mirrored = np.array([0.01, 0.20, 0.00, 0.01])
    # far and much closer to the mirror / not much closer / too small a gap / flipped
    np.testing.assert_array_equal(flips(errors, mirrored), [True, False, False, True])
    assert FLIP_MARGIN <= 0.09


@pytest.fixture(scope="module")
def symmetric_toy():
    """An ellipsoid symmetric under x → −x, unit area, with its exact mirror map."""
    mesh = trimesh.creation.icosphere(subdivisions=2)
    vertices = np.asarray(mesh.vertices) * [2.0, 1.0, 0.7]
    vertices /= np.sqrt(trimesh.Trimesh(vertices, mesh.faces).area)
    faces = np.asarray(mesh.faces)
    from scipy.spatial import cKDTree

    mirror = cKDTree(vertices).query(vertices * [-1.0, 1.0, 1.0])[1]
    assert np.allclose(vertices[mirror], vertices * [-1.0, 1.0, 1.0], atol=1e-9)
    return vertices, faces, mirror


def test_flip_detection_on_symmetric_toy(symmetric_toy):
    vertices, faces, mirror = symmetric_toy
    shape = Shape.from_arrays(vertices, faces)
    ids = np.arange(len(vertices))
    rows = ExactRows(vertices, faces)
    target = EvalShape("toy", shape, ids, rows, mirror)
    pair = MatchPair("template", target, target, ids, ids, mirror)
    far = np.abs(vertices[:, 0]) > 0.3  # the mirror lies far on the surface
    assert far.sum() > 20

    err, mirrored = pair.errors(ids)  # perfect
    assert np.all(err == 0) and not flips(err, mirrored).any()

    err, mirrored = pair.errors(mirror)  # every match mirrored
    flipped = flips(err, mirrored)
    assert flipped[far].all()
    assert not flipped[np.abs(vertices[:, 0]) < 1e-9].any()  # on the plane: no flip

    results = evaluate_pairs("template", [pair], [_Oracle(mirror)])
    assert results[0].flip_rate == pytest.approx(100 * flipped.mean())
    assert results[0].matches == len(vertices) and results[0].pairs == 1


class _Oracle:
    """Answers a fixed map (a method stub)."""

    name = "oracle"
    prep_key = "oracle"

    def __init__(self, answer):
        self.answer = answer

    def prepare(self, shape):
        return shape

    def match(self, x, y, queries):
        return self.answer[queries]


def test_match_errors_look_up_rows(symmetric_toy):
    vertices, faces, _ = symmetric_toy
    rows = ExactRows(vertices, faces)
    truth = np.array([3, 3, 10])
    predicted = np.array([5, 3, 0])
    expected = [*rows(np.array([3]))[0, [5, 3]].tolist(), rows(np.array([10]))[0, 0]]
    np.testing.assert_allclose(match_errors(rows, truth, predicted), expected)


def test_surface_point_rows_close_to_exact(blob):
    from litege_core.engines import compute_distances, insert_surface_points
    from litege_core.sampling import sample_surface
    from litege_core.variants import SurfaceLocation

    shape = blob(3, subdivisions=3)
    samples = sample_surface(shape.vertices, shape.faces, 200, seed=1)
    location = SurfaceLocation(samples.face_index, samples.barycentric)
    rows = SurfacePointRows(shape.vertices, shape.faces, location)
    sources = np.array([0, 7, 50])
    approx = rows(sources)
    # Exact: every sample inserted as a vertex, rows from the three sources.
    refined = insert_surface_points(
        shape.vertices, shape.faces, samples.face_index, samples.barycentric
    )
    mesh = Shape.from_arrays(refined.vertices, refined.faces)
    exact = compute_distances(mesh, refined.point_vertex[sources]).distances
    exact = exact[:, refined.point_vertex] * rows.scale
    assert approx.shape == (3, 200)
    np.testing.assert_allclose(approx[np.arange(3), sources], 0.0)
    assert np.abs(approx - exact).mean() < 2e-3


# ----------------------------------------------------------------------------- baselines


def test_nn_baseline_finds_identity_on_identical_shapes(blob):
    from litege_core.matching import MatchingModel

    shape = blob(5, subdivisions=3)
    method = NearestNeighbourMethod(MatchingModel.tiny_random(0))
    prepared = method.prepare(shape)
    queries = np.arange(0, shape.n_points, 7)
    np.testing.assert_array_equal(method.match(prepared, prepared, queries), queries)


def test_zoomout_baseline_on_two_copies_has_low_error(blob):
    pytest.importorskip("pyFM")
    from litege_core.evaluation.matching import ZoomOutMethod

    shape = blob(2, subdivisions=3)
    settings = ZoomOutSettings(n_eigen=40, n_descriptors=40, k_init=15, n_samples=300)
    method = ZoomOutMethod(settings)
    prepared_x, prepared_y = method.prepare(shape), method.prepare(shape)
    queries = np.arange(0, shape.n_points, 5)
    predicted = method.match(prepared_x, prepared_y, queries)
    errors = match_errors(ExactRows(shape.vertices, shape.faces), queries, predicted)
    assert 100 * errors.mean() < 3.0


# ----------------------------------------------------------------------------- pair sets


def test_landmark_and_correspondence_files(tmp_path):
    (tmp_path / "a.vts").write_text("1\n5\n3\n")
    np.testing.assert_array_equal(read_vts(tmp_path / "a.vts"), [0, 4, 2])
    (tmp_path / "c.pid").write_text("  12 0 0 0\n 7 0 0 0\n")
    np.testing.assert_array_equal(read_pid(tmp_path / "c.pid"), [12, 7])
    (tmp_path / "c.sym.info").write_text("2 3\n4 10\n\n0\n1\n\n")
    mirror = read_sym_info(tmp_path / "c.sym.info", 11)
    assert mirror[2] == 3 and mirror[3] == 2 and mirror[10] == 4 and mirror[0] == 0


def test_real_sets_skip_cleanly_without_eval_data(tmp_path):
    for name in ("tosca", "tosca-landmarks", "faust"):
        assert eval_data_pairs(name, tmp_path / "absent", 2, 5) == []


def test_missing_category_model_is_reported(monkeypatch):
    import litege_core.evaluation.matching as evaluation
    from litege_core.errors import InputError

    class Quadrupeds:
        category = "quadruped"
        precision = "float32"

    def no_model(name, device="cpu", precision="float32"):
        raise InputError(f"unknown matching model {name!r}")

    monkeypatch.setattr(evaluation, "load_matching_model", no_model)
    chooser = ModelChooser(Quadrupeds())
    assert chooser.for_category("quadruped")[0] is chooser.model
    assert chooser.for_category("biped") == (None, "no humans matching model")
    table = results_table([SettingResult("faust", "litege", note="no humans matching model")])
    assert "no humans matching model" in table


def test_synthetic_pairs_truth_and_mirror():
    from litege_core.evaluation.matching_data import SyntheticPool
    from litege_core.synth import symmetry_map

    pool = SyntheticPool("quadruped", n_pairs=1, n_queries=6, seed=3)
    symmetry = symmetry_map("quadruped")
    np.testing.assert_array_equal(pool.anchors[pool.anchor_mirror], symmetry[pool.anchors])
    (pair,) = pool.pairs("template")
    assert pair.x.name.split("-")[0] != pair.y.name.split("-")[0]  # different families
    np.testing.assert_array_equal(pair.queries, pool.anchors)  # vertex i ↔ vertex i
    for setting in ("template", "broken40", "cloud500"):
        (pair,) = pool.pairs(setting)
        err, mirrored = pair.errors(pair.truth)
        np.testing.assert_allclose(err, 0.0, atol=1e-12)
        assert np.all(mirrored >= 0)
        err, _ = pair.errors(pair.mirror)  # a mirrored answer is far from the truth somewhere
        assert err.max() > 0.05


@pytest.mark.evaldata
@pytest.mark.skipif(not (EVAL_DATA / "tosca_5k").is_dir(), reason="no ../shared/eval-data")
def test_tosca_pairs_are_same_class_with_valid_truth():
    pairs = eval_data_pairs("tosca", EVAL_DATA, n_pairs=1, n_queries=4, seed=0)
    (pair,) = pairs
    assert pair.x.name.rstrip("0123456789") == pair.y.name.rstrip("0123456789")
    assert pair.queries.size == pair.truth.size == 4
    err, _ = pair.errors(pair.truth)
    np.testing.assert_array_equal(err, 0.0)


# ----------------------------------------------------------------------------- CLI


@pytest.fixture(scope="module")
def tiny_bundle_dir(tmp_path_factory):
    from litege_core.matching.testing import save_tiny_matching_bundle

    directory = tmp_path_factory.mktemp("tiny-matching")
    save_tiny_matching_bundle(directory)
    return directory


def test_cli_eval_matching_end_to_end(tiny_bundle_dir, tmp_path, capsys):
    from litege_core.cli import main

    out = tmp_path / "result.json"
    code = main(
        [
            "eval",
            "matching",
            "--model",
            str(tiny_bundle_dir),
            "--pairs",
            "1",
            "--queries",
            "6",
            "--settings",
            "template",
            "--real",
            "",
            "--baselines",
            "nn",
            "--json",
            str(out),
        ]
    )
    assert code == 0
    table = capsys.readouterr().out
    assert "| template | LiteGE | 1 |" in table and "| template | NN (aligned) | 1 |" in table
    assert "model: tiny" in table
    report = json.loads(out.read_text())
    rows = {r["method"]: r for r in report["results"]}
    assert set(rows) == {"litege", "nn"}
    for row in rows.values():
        assert row["pairs"] == 1 and row["matches"] >= 6
        assert 0 <= row["auc"] <= 100 and row["mean_error"] >= 0
        assert row["flip_rate"] is not None and row["seconds_per_pair"] > 0


def test_cli_rejects_unknown_setting(tiny_bundle_dir, capsys):
    from litege_core.cli import main

    assert main(["eval", "matching", "--model", str(tiny_bundle_dir), "--settings", "bogus"]) == 2
    assert "bogus" in capsys.readouterr().err


def test_cli_eval_matching_variants(tiny_bundle_dir, tmp_path, capsys):
    from litege_core.cli import main

    out = tmp_path / "variants.json"
    argv = ["eval", "matching", "--model", str(tiny_bundle_dir), "--pairs", "1"]
    argv += ["--queries", "4", "--settings", "template", "--real", "", "--baselines", "nn"]
    code = main([*argv, "--variants", " tnet , tnet+mirror-vote", "--json", str(out)])
    assert code == 0
    table = capsys.readouterr().out
    assert "| template | LiteGE [tnet] | 1 |" in table
    assert "| template | LiteGE [tnet+mirror-vote] | 1 |" in table
    assert "| template | NN (aligned) [tnet] | 1 |" in table
    rows = {r["method"] for r in json.loads(out.read_text())["results"]}
    assert rows == {"litege[tnet]", "litege[tnet+mirror-vote]", "nn[tnet]"}


@pytest.mark.parametrize("bad", ["pca", "tnet+judged", "judged,icp", " , "])
def test_cli_rejects_a_bad_variant_with_exit_code_2(tiny_bundle_dir, capsys, bad):
    from litege_core.cli import main

    with pytest.raises(SystemExit) as exit_info:
        main(["eval", "matching", "--model", str(tiny_bundle_dir), "--variants", bad])
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert "argument --variants:" in err and "Traceback" not in err
    assert "LiteGE variant" in err


def test_eval_matching_variants_script_uses_the_cli_options(tiny_bundle_dir, tmp_path):
    script = Path(__file__).resolve().parents[3] / "scripts" / "eval_matching_variants.py"
    out = tmp_path / "script.json"
    argv = [sys.executable, str(script), "--model", str(tiny_bundle_dir), "--pairs", "1"]
    argv += ["--queries", "4", "--real", "", "--baselines", "", "--variants", "tnet"]
    result = subprocess.run([*argv, "--json", str(out)], capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
    assert "| template | LiteGE [tnet] | 1 |" in result.stdout  # --settings template default
    assert "command: python " in result.stdout
    report = json.loads(out.read_text())
    assert [r["method"] for r in report["results"]] == ["litege[tnet]"]
    bad = subprocess.run([*argv[:-1], "pca"], capture_output=True, text=True)
    assert bad.returncode == 2 and "argument --variants:" in bad.stderr


# ----------------------------------------------------------------------------- issue 15


def test_litege_variants_parse_name_and_label():
    from litege_core.errors import InputError
    from litege_core.evaluation.matching import LiteGEVariant, method_label

    default = LiteGEVariant.parse("auto")
    assert default == LiteGEVariant() and default.name == "litege"
    variant = LiteGEVariant.parse("judged+mirror-vote+zoomout")
    assert (variant.frames, variant.side, variant.refine) == ("judged", "network", "zoomout")
    assert variant.name == "litege[judged+mirror-vote+zoomout]"
    assert LiteGEVariant.parse("zoomout").name == "litege[zoomout]"
    assert method_label("litege[tnet]") == "LiteGE [tnet]"
    assert method_label("nn[judged]") == "NN (aligned) [judged]"
    assert method_label("zoomout") == "ZoomOut (pyFM)"
    assert LiteGEVariant.parse("judged+zoomout-hybrid").refine == "zoomout-hybrid"
    assert LiteGEVariant.parse("judged+zoomout-hybrid").smoothed
    raw = LiteGEVariant.parse("judged+zoomout+unsmoothed")
    assert not raw.smoothed and raw.name == "litege[judged+zoomout+unsmoothed]"
    fitted = LiteGEVariant.parse("judged+zoomout-hybrid+unregistered")
    assert fitted.smoothed and not fitted.registered
    assert fitted.name == "litege[judged+zoomout-hybrid+unregistered]"
    intrinsic = LiteGEVariant.parse("intrinsic+zoomout-hybrid")
    assert intrinsic.frames == "intrinsic" and intrinsic.name == "litege[intrinsic+zoomout-hybrid]"
    unchecked = LiteGEVariant.parse("tnet+zoomout-hybrid+unchecked")
    assert unchecked.smoothed and unchecked.registered and not unchecked.checked
    assert unchecked.name == "litege[tnet+zoomout-hybrid+unchecked]"
    both = LiteGEVariant.parse("zoomout-hybrid+unregistered+unchecked")
    assert both.name == "litege[zoomout-hybrid+unregistered+unchecked]"
    for bad in (
        "tnet+judged",
        "intrinsic+tnet",
        "pca",
        "judged+icp",
        "zoomout+zoomout-hybrid",
        "tnet+unsmoothed",
        "tnet+unregistered",
        "zoomout+unsmoothed+unregistered",
        "tnet+unchecked",
        "zoomout+unsmoothed+unchecked",
    ):
        with pytest.raises(InputError):
            LiteGEVariant.parse(bad)


def test_derived_mirror_rows_on_a_symmetric_and_an_asymmetric_toy(symmetric_toy):
    from litege_core.evaluation.matching_data import derived_mirror_rows

    vertices, faces, mirror = symmetric_toy
    rows = np.random.default_rng(0).permutation(len(vertices))  # rows cover every vertex
    found = derived_mirror_rows(vertices + np.array([3.0, 0.0, 0.0]), faces, rows)  # x = mean x
    np.testing.assert_array_equal(rows[found], mirror[rows])
    lopsided = vertices.copy()
    lopsided[:, 0] += 1.5 * np.maximum(lopsided[:, 0], 0) + 1.0 * lopsided[:, 1]
    assert derived_mirror_rows(lopsided, faces, rows) is None


@pytest.mark.evaldata
@pytest.mark.skipif(not (EVAL_DATA / "tosca_5k").is_dir(), reason="no ../shared/eval-data")
def test_tosca_pairs_have_a_derived_mirror_far_from_the_truth():
    (pair,) = eval_data_pairs("tosca", EVAL_DATA, n_pairs=1, n_queries=30, seed=0)
    assert pair.mirror is not None and pair.mirror.shape == pair.truth.shape
    err, mirrored = pair.errors(pair.mirror)  # answering the mirror: flipped where it is far
    assert np.median(err) > 0.05 and np.all(mirrored < 0.02)


def test_evaluation_variants_rows_and_refinement_notes(tiny_bundle_dir):
    from litege_core.evaluation.matching import load_matching_model, run_matching_evaluation

    pytest.importorskip("pyFM")
    model = load_matching_model(str(tiny_bundle_dir))
    results = run_matching_evaluation(
        model,
        settings=["template", "cloud500"],
        real=[],
        eval_data="absent",
        n_pairs=1,
        n_queries=4,
        baselines=["nn"],
        variants=["tnet", "tnet+mirror-vote", "tnet+zoomout", "tnet+zoomout+unsmoothed"],
    )
    rows = {(r.setting, r.method): r for r in results}
    for method in (
        "litege[tnet]",
        "litege[tnet+mirror-vote]",
        "litege[tnet+zoomout]",
        "litege[tnet+zoomout+unsmoothed]",
    ):
        assert rows[("template", method)].pairs == 1, method
        assert rows[("template", method)].flip_rate is not None
    assert rows[("template", "nn[tnet]")].pairs == 1
    assert rows[("cloud500", "litege[tnet]")].pairs == 1
    refined = rows[("cloud500", "litege[tnet+zoomout]")]
    assert refined.pairs == 0 and refined.note == "refinement needs meshes"
