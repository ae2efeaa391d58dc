import numpy as np
import pytest

from litege_core.engines import compute_distances, surface_point_distances
from litege_core.errors import InputError
from litege_core.evaluation.geodesic import (
    SETTINGS,
    EvalShape,
    evaluate,
    evaluate_methods,
    is_mesh_setting,
    make_input,
    parse_setting,
    parse_settings,
    results_table,
    spread_table,
    unit_area,
)
from litege_core.evaluation.speed import batch_query_table
from litege_core.sampling import farthest_point_sampling
from litege_core.shape import Shape


@pytest.fixture(scope="module")
def eval_shape(blob):
    shape = blob(7, subdivisions=3)
    vertices, _ = unit_area(shape.vertices, shape.faces)
    sources = farthest_point_sampling(vertices, 6)
    unit = Shape.from_arrays(vertices, shape.faces)
    gt = compute_distances(unit, sources, method="exact").distances
    return EvalShape("blob", "toy", vertices, np.asarray(shape.faces), sources, gt)


def test_unit_area_scaling(blob):
    shape = blob(1)
    vertices, scale = unit_area(shape.vertices * 3.0, shape.faces)
    assert Shape.from_arrays(vertices, shape.faces).area == pytest.approx(1.0)
    assert scale == pytest.approx(1.0 / (3.0 * np.sqrt(shape.area)))


def test_cloud_ground_truth_is_close_to_exact(eval_shape):
    item = make_input(eval_shape, "cloud_300", seed=0)
    assert item.shape.n_points == 300 and item.gt.shape == (6, 300)
    np.testing.assert_array_equal(item.source_index, np.arange(6))
    np.testing.assert_allclose(item.gt[:, :6], eval_shape.gt[:, eval_shape.sources])
    # Interpolated ground truth vs exact distances to inserted surface points.
    from litege_core.sampling import sample_surface

    samples = sample_surface(eval_shape.vertices, eval_shape.faces, 294, 0)
    exact = (
        surface_point_distances(
            Shape.from_arrays(eval_shape.vertices, eval_shape.faces),
            samples.face_index[:20],
            samples.barycentric[:20],
            to_vertices=True,
        )
        .to_vertices[:, eval_shape.sources]
        .T
    )
    relative = np.abs(item.gt[:, 6:26] - exact) / np.maximum(exact, 1e-9)
    assert np.median(relative[exact > 0.1]) < 0.01  # measured ≈ 0.2 %


def test_corruptions_keep_queries_consistent(eval_shape):
    clean = make_input(eval_shape, "cloud_2000", seed=0)
    noisy = make_input(eval_shape, "noise_0.01", seed=0)
    np.testing.assert_allclose(noisy.gt, clean.gt)  # ground truth stays clean
    offset = noisy.shape.vertices - clean.shape.vertices
    assert 0.008 < offset.std() < 0.012
    cut = make_input(eval_shape, "cut_15", seed=0)
    assert cut.shape.n_points == pytest.approx(0.85 * 2000, abs=3)
    assert cut.gt.shape == (cut.source_index.size, cut.shape.n_points)
    kept_points = cut.shape.vertices[cut.source_index]
    assert np.isin(kept_points, clean.shape.vertices[:6]).all()
    stray = make_input(eval_shape, "outliers_5", seed=0)  # 100 stray points after the 2000
    assert stray.shape.n_points == 2100 and stray.gt.shape == (6, 2100)
    np.testing.assert_array_equal(stray.shape.vertices[:2000], clean.shape.vertices)
    np.testing.assert_array_equal(stray.gt[:, :2000], clean.gt)
    assert not stray.gt[:, 2000:].any()  # 0: never scored
    twice = make_input(eval_shape, "repeats_100", seed=0)  # every point sent again
    assert twice.shape.n_points == 4000 and twice.gt.shape == (6, 4000)
    order = np.lexsort(twice.shape.vertices[2000:].T)
    again = np.lexsort(clean.shape.vertices.T)
    np.testing.assert_array_equal(twice.shape.vertices[2000:][order], clean.shape.vertices[again])
    np.testing.assert_array_equal(twice.gt[:, 2000:][:, order], clean.gt[:, again])
    moved = make_input(eval_shape, "twins_0.001", seed=0)  # every point again, moved a little
    assert moved.shape.n_points == 4000 and moved.gt.shape == (6, 4000)
    np.testing.assert_array_equal(moved.shape.vertices[:2000], clean.shape.vertices)
    np.testing.assert_array_equal(moved.gt, np.concatenate([clean.gt, clean.gt], axis=1))
    shift = moved.shape.vertices[2000:] - clean.shape.vertices
    assert 0.0008 < shift.std() < 0.0012
    some = make_input(eval_shape, "repeats_10", seed=0)
    assert some.shape.n_points == 2200
    assert np.isin(some.shape.vertices[2000:], clean.shape.vertices).all()
    uneven = make_input(eval_shape, "uneven_3", seed=0)  # denser towards +x
    assert uneven.shape.n_points == 2000 and uneven.gt.shape == (6, 2000)
    x = uneven.shape.vertices[6:, 0]
    middle = 0.5 * (x.min() + x.max())
    assert np.count_nonzero(x > middle) > 2.5 * np.count_nonzero(x <= middle)
    again = make_input(eval_shape, "uneven_3", seed=0)
    np.testing.assert_array_equal(again.shape.vertices, uneven.shape.vertices)
    flat = make_input(eval_shape, "uneven_0", seed=0)  # A = 0: a plain area-weighted draw
    x = flat.shape.vertices[6:, 0]
    assert np.count_nonzero(x > middle) < 2 * np.count_nonzero(x <= middle)
    low, high = clean.shape.vertices.min(0), clean.shape.vertices.max(0)
    margin = 0.1 * (high - low) + 1e-9
    assert (stray.shape.vertices[2000:] >= low - margin).all()
    assert (stray.shape.vertices[2000:] <= high + margin).all()


def test_setting_names_are_parsed_in_one_place(eval_shape):
    """Every default setting parses; bad names are InputErrors listing the valid forms."""
    assert [parse_setting(s) for s in SETTINGS][:3] == [
        ("mesh", 0),
        ("cloud", 2000),
        ("cloud", 300),
    ]
    assert parse_setting("noise_0.01") == ("noise", 0.01) and parse_setting("cut_10") == ("cut", 10)
    assert parse_setting("outliers_5") == ("outliers", 5)
    assert parse_setting("uneven_3") == ("uneven", 3.0)
    assert parse_setting("repeats_100") == ("repeats", 100)
    assert parse_setting("twins_0.001") == ("twins", 0.001)
    assert parse_setting("decimated_1000") == ("decimated", 1000)
    assert parse_setting("meshnoise_0.002") == ("meshnoise", 0.002)
    assert is_mesh_setting("meshnoise_0.002")
    assert is_mesh_setting("decimated_1000") and is_mesh_setting("mesh")
    assert not is_mesh_setting("cloud_300")
    assert parse_settings(None) == list(SETTINGS) and parse_settings("mesh, cut_5") == [
        "mesh",
        "cut_5",
    ]
    for bad in (
        "bogus",
        "cloud_abc",
        "cut_abc",
        "cloud_0",
        "cut_100",
        "noise_nan",
        "cloud_²",
        "outliers_x",
        "outliers_-1",
        "uneven_nan",
        "uneven_-1",
        "repeats_101",
        "twins_-1",
        "repeats_x",
        "decimated_3",
        "decimated_x",
        "meshnoise_-1",
    ):
        with pytest.raises(InputError, match="cloud_N"):
            parse_setting(bad)
    with pytest.raises(InputError, match="no setting"):
        parse_settings(",")
    with pytest.raises(InputError, match="fewer points than the 6 sources"):
        make_input(eval_shape, "cloud_1", seed=0)
    with pytest.raises(InputError, match="bogus"):
        evaluate_methods([eval_shape], lambda setting: {}, ["mesh", "bogus"])


def test_eval_geodesic_cli_refuses_a_bad_setting_before_any_work(capsys):
    """``--settings bogus`` is an invalid-input error, not a run under a bogus label."""
    from litege_core.cli import main

    code = main(["eval", "geodesic", "--bundle", "/nonexistent", "--settings", "bogus"])
    assert code == 2 and "[invalid-input]" in capsys.readouterr().err


def test_evaluate_runs_every_method_and_setting(eval_shape, toy_predictor):
    results = evaluate([eval_shape], toy_predictor, settings=SETTINGS)
    assert {r.setting for r in results} == set(SETTINGS)
    assert all(np.isfinite(r.mean) and r.n_pairs > 0 for r in results)
    by_method = {(r.setting, r.method): r for r in results}
    # The exact-ish classical baselines are far better than an untrained network.
    assert by_method[("mesh", "heat (mesh)")].mean < 10
    assert by_method[("mesh", "LiteGE")].mean > by_method[("mesh", "heat (mesh)")].mean
    assert "| toy | mesh | LiteGE |" in results_table(results)


def test_per_shape_errors_pool_to_the_row_and_name_the_worst_shape(eval_shape):
    other = EvalShape(
        "other",
        "toy",
        *[getattr(eval_shape, k) for k in ("vertices", "faces")],
        eval_shape.sources,
        eval_shape.gt,
    )
    factors = iter([1.0, 1.1])  # the methods see the shapes in order: blob, then other

    def methods(setting):
        return {"truth": lambda item: item.gt, "scaled": lambda item: item.gt * next(factors)}

    results = evaluate_methods([eval_shape, other], methods, settings=("mesh",))
    by_method = {r.method: r for r in results}
    assert [name for name, _ in by_method["truth"].per_shape] == ["blob", "other"]
    assert all(error == pytest.approx(0.0, abs=1e-9) for _, error in by_method["truth"].per_shape)
    scaled = dict(by_method["scaled"].per_shape)
    assert scaled["blob"] == pytest.approx(0.0, abs=1e-9) and scaled["other"] > 5.0
    # equal pair counts: the pooled mean is the mean of the two shapes' means
    assert by_method["scaled"].mean == pytest.approx(np.mean(list(scaled.values())))
    table = spread_table(results)
    assert "| toy | mesh | scaled | 2 |" in table and f"other {scaled['other']:.2f} |" in table


def test_batch_query_table(blob, toy_predictor):
    clouds = [Shape.from_arrays(blob(s).vertices) for s in range(2)]
    rows = batch_query_table(toy_predictor, clouds, counts=(1, 4), runs=1)
    assert [r["shapes"] for r in rows] == [1, 4]
    assert all(r["median_ms"] > 0 for r in rows)


def test_frame_selection_rows(eval_shape, toy_predictor):
    from litege_core.evaluation.geodesic import register_in_frame

    item = make_input(eval_shape, "cloud_300", seed=0)
    plain = toy_predictor.register(item.shape)
    state, choice = register_in_frame(toy_predictor, item.shape, "pca")
    assert choice.index == 0 and state.transform.allclose(plain.transform)
    np.testing.assert_array_equal(
        toy_predictor.distances(state, item.source_index),
        toy_predictor.distances(plain, item.source_index),
    )
    selected, choice = register_in_frame(toy_predictor, item.shape, "signs")
    assert choice.scores.shape == (4,) and selected.residual == pytest.approx(choice.scores.min())
    results = evaluate([eval_shape], toy_predictor, settings=("cloud_300",), frames=("signs",))
    assert {r.method for r in results} >= {"LiteGE", "LiteGE (frame: signs)"}


def test_frame_turns_and_test_time_augmentation(eval_shape, toy_predictor):
    from litege_core.evaluation.geodesic import frame_turns, litege_method

    turns = frame_turns(4, 12.0)
    assert turns.shape == (5, 3, 3)
    np.testing.assert_array_equal(turns[0], np.eye(3))  # the PCA frame itself first
    angles = np.degrees(np.arccos(np.clip((np.trace(turns, axis1=1, axis2=2) - 1) / 2, -1, 1)))
    assert angles[0] == 0 and angles[1:].min() > 0 and angles.max() <= 12.0 + 1e-9
    np.testing.assert_array_equal(frame_turns(4, 12.0), turns)  # deterministic
    item = make_input(eval_shape, "cloud_300", seed=0)
    states = toy_predictor.register_turned(item.shape, turns)
    fields = [toy_predictor.distances(s, item.source_index) for s in states]
    averaged = litege_method(toy_predictor, turns=turns)(item)
    np.testing.assert_allclose(averaged, np.mean(fields, axis=0), rtol=1e-5, atol=1e-6)
    alone = litege_method(toy_predictor, turns=turns[:1])(item)  # the identity alone: plain
    np.testing.assert_allclose(alone, litege_method(toy_predictor)(item), rtol=1e-6, atol=1e-6)


def test_real_sets_skip_cleanly_without_the_data(tmp_path):
    from litege_core.evaluation.geodesic import REAL_SETS, real_shape_paths

    assert real_shape_paths(tmp_path / "missing", "tosca") == []
    (tmp_path / "leopard").mkdir()
    (tmp_path / "leopard" / "leopard.obj").write_text("")
    assert [p.name for p in real_shape_paths(tmp_path, "leopard")] == ["leopard.obj"]
    assert REAL_SETS["faust"].model == "humans"
    with pytest.raises(Exception, match="unknown real set"):
        real_shape_paths(tmp_path, "smal")


def test_generated_held_out_shapes_and_row_cache(tmp_path):
    from litege_core.evaluation.geodesic import HELD_OUT_SEED_OFFSET, generated_eval_shapes

    first = generated_eval_shapes("quadruped", 1, 3, cache_dir=tmp_path)
    assert first[0].name.endswith(str(HELD_OUT_SEED_OFFSET)) and first[0].gt.shape[0] == 3
    assert Shape.from_arrays(first[0].vertices, first[0].faces).area == pytest.approx(1.0)
    assert len(list(tmp_path.glob("*.npz"))) == 1  # written atomically: no partial file left
    assert not list(tmp_path.glob("*partial*"))
    again = generated_eval_shapes("quadruped", 1, 3, cache_dir=tmp_path)  # from the cache
    np.testing.assert_array_equal(first[0].gt, again[0].gt)


def test_eval_geodesic_cli_offers_every_real_set():
    """The parser lists the sets literally (no evaluation import at start-up): kept equal to
    the library's :data:`REAL_SETS`."""
    from litege_core.cli import build_parser
    from litege_core.evaluation.geodesic import REAL_SETS

    args = build_parser(plugins=False).parse_args(["eval", "geodesic", "--real", *REAL_SETS])
    assert list(args.real) == list(REAL_SETS)
    with pytest.raises(SystemExit):
        build_parser(plugins=False).parse_args(["eval", "geodesic", "--real", "scape"])


def test_eval_geodesic_cli_evaluates_any_predictor_configuration(toy_predictor, capsys):
    """``--head``, ``--lattice`` and ``--fusion`` reach the evaluated predictor: a bundle
    without a fusion calibration is refused before any shape is read."""
    from litege_core.cli import build_parser, main

    options = ["--head", "small", "--lattice", "stride2", "--fusion", "graph"]
    args = build_parser(plugins=False).parse_args(["eval", "geodesic", *options])
    assert (args.head, args.lattice, args.fusion) == ("small", "stride2", "graph")
    bundle = str(toy_predictor.bundle.path)
    code = main(["eval", "geodesic", "--bundle", bundle, "--fusion", "graph", "--real", "tosca"])
    assert code == 2 and "no graph-fusion calibration" in capsys.readouterr().err


def test_eval_geodesic_cli_gives_each_real_set_its_categorys_model(monkeypatch, capsys):
    """Without ``--model`` / ``--bundle`` TOSCA goes to ``quadrupeds`` and FAUST to ``humans``;
    a named model answers both."""
    import litege_core.evaluation.geodesic as geodesic
    from litege_core.cli import main

    evaluated: list[tuple[str, list[str]]] = []
    monkeypatch.setattr(geodesic, "real_shape_paths", lambda root, key, limit: [key])
    monkeypatch.setattr(
        geodesic, "real_eval_shapes", lambda paths, group, sources: [f"{group}:{p}" for p in paths]
    )

    def fake_evaluate(shapes, model, settings, seed=0):
        evaluated.append((model.bundle.name, list(shapes)))
        return []

    monkeypatch.setattr(geodesic, "evaluate", fake_evaluate)
    monkeypatch.setattr(geodesic, "results_table", lambda results: "")
    monkeypatch.setattr(geodesic, "spread_table", lambda results: "")
    assert main(["eval", "geodesic", "--real", "tosca", "faust", "leopard"]) == 0
    by_model = dict(evaluated)
    assert set(by_model) == {"quadrupeds", "humans"}
    assert [s.split(":")[1] for s in by_model["quadrupeds"]] == ["tosca", "leopard"]
    assert [s.split(":")[1] for s in by_model["humans"]] == ["faust"]
    out = capsys.readouterr().out
    assert "bundle='quadrupeds'" in out and "bundle='humans'" in out
    evaluated.clear()
    assert main(["eval", "geodesic", "--model", "quadrupeds", "--real", "tosca", "faust"]) == 0
    assert [(name, len(shapes)) for name, shapes in evaluated] == [("quadrupeds", 2)]


class _Icospheres:
    """Stretched icospheres: a template family (one triangulation) or, with ``collection``,
    each shape its own subdivision level."""

    category = "toy"
    version = "toy-eval-1"

    def __init__(self, collection: bool) -> None:
        import trimesh

        self._sphere = trimesh.creation.icosphere
        self.collection = collection

    def _vertices(self, sphere, seed):
        scale = [np.random.default_rng(seed).uniform(1.2, 1.8), 1.0, 0.8]
        return np.asarray(sphere.vertices) * scale

    def template(self):
        sphere = self._sphere(subdivisions=2)
        return np.asarray(sphere.vertices), np.asarray(sphere.faces)

    def generate(self, family, seed):
        return self._vertices(self._sphere(subdivisions=2), seed)

    def generate_mesh(self, family, seed):
        sphere = self._sphere(subdivisions=1 + seed % 2)
        return self._vertices(sphere, seed), np.asarray(sphere.faces)


@pytest.mark.parametrize("kind", ["template", "collection"])
def test_dataset_eval_shapes_reads_either_kind_of_dataset_at_unit_area(tmp_path, kind):
    """A template and a collection dataset give the same thing: their test split's shapes at
    unit area, each with its stored rows scaled to match (rows of the unit-area mesh)."""
    from litege_core.datasets import DatasetSpec, build_dataset
    from litege_core.evaluation.geodesic import dataset_eval_shapes

    spec = DatasetSpec(
        name=f"toy-{kind}",
        category="toy",
        families=("round",),
        n_shapes={"train": 1, "val": 0, "test": 3},
        n_shared_sources=4,
        n_extra_sources=0,
        kind=kind,
    )

    def rows(vertices, faces, sources):
        return compute_distances(
            Shape.from_arrays(vertices, faces), sources, method="exact"
        ).distances

    build_dataset(
        spec, tmp_path, _Icospheres(kind == "collection"), distance_fn=rows, progress=False
    )
    shapes = dataset_eval_shapes(tmp_path, "test")
    assert [s.group for s in shapes] == [f"toy-{kind} (test)"] * 3
    assert len(dataset_eval_shapes(tmp_path, "test", limit=2, group="named")) == 2
    for shape in shapes:
        unit = Shape.from_arrays(shape.vertices, shape.faces)
        assert unit.area == pytest.approx(1.0)
        expected = compute_distances(unit, shape.sources, method="exact").distances
        np.testing.assert_allclose(shape.gt, expected, rtol=1e-4, atol=1e-6)
    if kind == "collection":  # each shape its own triangulation
        assert len({s.faces.shape for s in shapes}) == 2
    from litege_core.evaluation.geodesic import named_eval_set

    named = named_eval_set(f"{tmp_path}@quadrupeds", tmp_path / "no-eval-data", 12, None, 2)
    assert (named.model, named.group) == ("quadrupeds", f"{tmp_path.name} (test, calibration data)")
    assert [s.name for s in named.shapes] == [s.name for s in shapes[:2]]


def test_a_named_set_is_a_real_set_or_a_dataset(tmp_path) -> None:
    from litege_core.evaluation.geodesic import named_eval_set

    empty = named_eval_set("faust", tmp_path, 12, None)  # no eval data here: no shapes
    assert (empty.shapes, empty.model, empty.group) == ([], "humans", "FAUST humans (real)")
    with pytest.raises(InputError, match="unknown set"):
        named_eval_set("scape", tmp_path, 12, None)


def test_a_decimated_mesh_is_scored_against_its_own_exact_geodesics(eval_shape):
    """``decimated_N``: the mesh simplified to about N vertices, at unit area, with exact rows
    from as many farthest-point sources of its own (a new surface, so not the original's)."""
    pytest.importorskip("pymeshlab")
    item = make_input(eval_shape, "decimated_300", seed=0)
    vertices, faces = item.shape.vertices, item.shape.faces
    assert faces is not None and 240 <= vertices.shape[0] <= 360
    assert item.shape.area == pytest.approx(1.0)
    np.testing.assert_array_equal(item.source_index, farthest_point_sampling(vertices, 6))
    exact = compute_distances(item.shape, item.source_index, method="exact").distances
    np.testing.assert_allclose(item.gt, exact)
    # the same surface, simplified: its farthest pair stays about as far apart
    assert item.gt.max() == pytest.approx(eval_shape.gt.max(), rel=0.05)


def test_a_noisy_mesh_keeps_its_faces_and_the_clean_ground_truth(eval_shape):
    item = make_input(eval_shape, "meshnoise_0.002", seed=1)
    np.testing.assert_array_equal(item.shape.faces, eval_shape.faces)
    moved = np.linalg.norm(item.shape.vertices - eval_shape.vertices, axis=1)
    assert 0.001 < np.median(moved) < 0.006  # std 0.002 per axis
    np.testing.assert_array_equal(item.source_index, eval_shape.sources)
    np.testing.assert_array_equal(item.gt, eval_shape.gt)
    again = make_input(eval_shape, "meshnoise_0.002", seed=1)
    np.testing.assert_array_equal(again.shape.vertices, item.shape.vertices)  # seeded
