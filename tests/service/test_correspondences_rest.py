"""``POST /correspondences`` over real HTTP, on the untrained ``MatchingModel.tiny_random``
(plumbing, not accuracy): answers equal the library's, prepared shapes are computed once and
kept in the store (in-process or Redis, across a restart), bad inputs give precise problems."""

from __future__ import annotations

import asyncio
import importlib.util
import json
import sys
import typing
from typing import Any

import httpx
import numpy as np
import pytest
import redis

from litege_core.matching.model import MatchingModel
from litege_core.matching.refine import REFINE_METHODS
from litege_core.nets.folded import PRECISIONS, resolve_precision
from litege_core.shape import Shape
from service.client import LiteGEClient, ProblemError
from service.errors import UnknownModelError
from service.matching import MATCHING
from service.problems import PROBLEM_BASE_URI
from service.runtime import Runtime
from service.settings import Settings
from service.store import artifact_key

SEED = 3
MODEL = "tiny"
PROBLEM_JSON = "application/problem+json"
HAS_PYFM = importlib.util.find_spec("pyFM") is not None
NEEDS_PYFM = pytest.mark.skipif(
    not HAS_PYFM, reason="refine='zoomout' needs pyFM (PyPI pyfmaps, the 'eval' extra)"
)


def counter(service, name: str, **labels: str) -> float:
    value = service.runtime.metrics.registry.get_sample_value(name, labels)
    return 0.0 if value is None else value


def prepared_count(service) -> float:
    return counter(service, "litege_matching_prepared_total", model=MODEL)


@pytest.fixture(scope="module")
def reference() -> MatchingModel:
    """The library's model, built independently with the service's seed."""
    return MatchingModel.tiny_random(SEED)


@pytest.fixture(scope="module")
def service(live_service_factory):
    return live_service_factory(matching=MatchingModel.tiny_random(SEED))


@pytest.fixture(scope="module")
def client(service):
    with LiteGEClient(service.base_url) as c:
        yield c


@pytest.fixture(scope="module")
def pair(client, test_shape, reference):
    """Two registered meshes and their library preparations."""
    source, target = test_shape(1), test_shape(2)
    ids = [client.register_arrays(s.vertices, s.faces)["shape_id"] for s in (source, target)]
    return {
        "ids": ids,
        "shapes": (source, target),
        "prepared": [reference.prepare(s, seed=0) for s in (source, target)],
    }


def _post(service, body: dict) -> httpx.Response:
    with httpx.Client(base_url=service.base_url) as http:
        return http.post(
            "/correspondences",
            content=json.dumps(body),
            headers={"content-type": "application/json"},
        )


def assert_problem(response: httpx.Response, status: int, code: str) -> dict:
    assert response.status_code == status, response.text
    assert response.headers["content-type"].startswith(PROBLEM_JSON)
    problem = response.json()
    assert problem["status"] == status and problem["code"] == code
    assert problem["type"] == PROBLEM_BASE_URI + code
    assert problem["detail"]
    return problem


# --------------------------------------------------------------------------- answers


def test_all_queries_match_the_library(client, pair, reference):
    src, tgt = pair["ids"]
    got = client.correspondences(src, tgt, "all", return_distance=True)
    expected = reference.match(*pair["prepared"])
    n = pair["shapes"][0].n_points
    assert (got["source_shape_id"], got["target_shape_id"]) == (src, tgt)
    assert got["model"] == MODEL and got["n_queries"] == n
    assert got["matches"].shape == (n,)
    np.testing.assert_array_equal(got["matches"], expected.indices)
    assert_distances(got, expected, pair["prepared"][1])
    default = client.correspondences(src, tgt)  # queries default to "all"
    np.testing.assert_array_equal(default["matches"], expected.indices)


def test_index_queries_without_distances(service, client, pair, reference):
    src, tgt = pair["ids"]
    queries = [0, 5, 100, 5, 641]
    got = client.correspondences(src, tgt, queries)
    expected = reference.match(*pair["prepared"], np.array(queries))
    np.testing.assert_array_equal(got["matches"], expected.indices)
    assert got["distances"] is None and got["distances_unit_area"] is None
    assert got["n_queries"] == len(queries)
    raw = _post(service, {"source_shape_id": src, "target_shape_id": tgt, "queries": [7]})
    assert raw.status_code == 200 and raw.json()["distances"] is None
    assert set(raw.json()) == {
        "source_shape_id",
        "target_shape_id",
        "model",
        "n_queries",
        "matches",
        "distances",
        "distances_unit_area",
        "refinement",
        "source_frame",
        "target_frame",
    }
    assert raw.json()["refinement"] == "none" and got["refinement"] == "none"
    for role, prepared in zip(("source_frame", "target_frame"), pair["prepared"], strict=True):
        want = {"frame": prepared.frame, "check": prepared.frame_check}
        assert raw.json()[role] == got[role] == want == {"frame": "tnet", "check": "unchecked"}


def test_xyz_queries_match_the_library(client, pair, reference):
    src, tgt = pair["ids"]
    points = pair["shapes"][0].vertices[[3, 50, 400]] * 1.01  # near, not on, the surface
    got = client.correspondences(src, tgt, points, return_distance=True, model=MODEL)
    expected = reference.match(*pair["prepared"], query_points=points)
    np.testing.assert_array_equal(got["matches"], expected.indices)
    assert_distances(got, expected, pair["prepared"][1])


def assert_distances(got: dict, expected: Any, target: Any) -> None:
    """``distances_unit_area`` are the library's; ``distances`` the same in the target's
    input units."""
    np.testing.assert_allclose(got["distances_unit_area"], expected.distance, atol=1e-5, rtol=0)
    in_target_units = expected.distance / target.transform.scale
    np.testing.assert_allclose(got["distances"], in_target_units, rtol=1e-5, atol=1e-6)


def test_distances_are_in_the_target_input_units(client, pair, test_shape):
    """A target twice as large (same shape otherwise): the same matches and unit-area
    distances, and twice the input-unit distances."""
    src, tgt = pair["ids"]
    target = test_shape(2)
    big = client.register_arrays(target.vertices * 2.0, target.faces)["shape_id"]
    queries = [0, 5, 100, 300]
    small_answer = client.correspondences(src, tgt, queries, return_distance=True)
    big_answer = client.correspondences(src, big, queries, return_distance=True)
    np.testing.assert_array_equal(big_answer["matches"], small_answer["matches"])
    np.testing.assert_allclose(
        big_answer["distances_unit_area"], small_answer["distances_unit_area"], rtol=1e-4
    )
    np.testing.assert_allclose(big_answer["distances"], 2 * small_answer["distances"], rtol=1e-4)


def test_point_cloud_target_and_reverse_direction(client, pair, test_shape, reference):
    src, _ = pair["ids"]
    cloud = test_shape(4).vertices
    cloud_id = client.register_arrays(cloud, kind="point_cloud")["shape_id"]
    prepared_cloud = reference.prepare(Shape.from_arrays(cloud), seed=0)
    got = client.correspondences(src, cloud_id, [1, 2, 3], return_distance=True)
    expected = reference.match(pair["prepared"][0], prepared_cloud, np.array([1, 2, 3]))
    np.testing.assert_array_equal(got["matches"], expected.indices)
    back = client.correspondences(cloud_id, src, "all")
    np.testing.assert_array_equal(
        back["matches"], reference.match(prepared_cloud, pair["prepared"][0]).indices
    )


# --------------------------------------------------------------------------- refinement


@pytest.fixture(scope="module")
def small_pair(client, blob, reference):
    """Two small meshes (162 vertices: ZoomOut in about a second) and their library
    preparations."""
    shapes = (blob(21, subdivisions=2), blob(22, subdivisions=2))
    ids = [client.register_arrays(s.vertices, s.faces)["shape_id"] for s in shapes]
    return {
        "ids": ids,
        "shapes": shapes,
        "prepared": [reference.prepare(s, seed=0) for s in shapes],
    }


@NEEDS_PYFM
def test_refine_zoomout_on_two_meshes(service, client, small_pair, reference):
    src, tgt = small_pair["ids"]
    n_source = small_pair["shapes"][0].n_points
    n_target = small_pair["shapes"][1].n_points
    batches = counter(service, "litege_correspond_batches_total", model=MODEL)
    got = client.correspondences(src, tgt, "all", return_distance=True, refine="zoomout")
    assert counter(service, "litege_correspond_batches_total", model=MODEL) == batches + 1
    assert got["refinement"] == "zoomout" and got["n_queries"] == n_source
    assert got["matches"].shape == (n_source,)
    assert got["matches"].min() >= 0 and got["matches"].max() < n_target
    assert np.isfinite(got["distances"]).all() and np.isfinite(got["distances_unit_area"]).all()
    expected = reference.match(*small_pair["prepared"], refine="zoomout")
    assert expected.refinement == "zoomout"
    np.testing.assert_array_equal(got["matches"], expected.indices)
    queries = [0, 7, 100, 7]
    some = client.correspondences(src, tgt, queries, refine="zoomout")
    np.testing.assert_array_equal(some["matches"], got["matches"][queries])
    plain = client.correspondences(src, tgt, queries)  # unrefined answers stay unrefined
    assert plain["refinement"] == "none"
    expected_plain = reference.match(*small_pair["prepared"], np.array(queries))
    np.testing.assert_array_equal(plain["matches"], expected_plain.indices)


@NEEDS_PYFM
@NEEDS_PYFM
def test_refine_zoomout_on_a_mesh_with_faces_that_repeat_a_vertex(client, small_pair, blob):
    """Faces without area (a vertex repeated) are dropped from the spectrum's mesh, so the
    refinement answers (pyFM's eigensolver failed on them: a 500)."""
    shape = blob(21, subdivisions=2)
    faces = np.vstack([np.asarray(shape.faces), [[0, 0, 1], [2, 2, 2]]])
    broken = client.register_arrays(shape.vertices, faces)["shape_id"]
    target = small_pair["ids"][1]
    got = client.correspondences(broken, target, [0, 7, 100], refine="zoomout")
    assert got["refinement"] == "zoomout" and got["matches"].shape == (3,)
    assert got["matches"].min() >= 0 and got["matches"].max() < small_pair["shapes"][1].n_points


def test_refine_zoomout_hybrid_names_the_kept_seed(client, small_pair):
    src, tgt = small_pair["ids"]
    got = client.correspondences(src, tgt, [0, 1, 2], refine="zoomout-hybrid")
    assert got["refinement"] in {"zoomout:litege", "zoomout:descriptors"}
    assert got["matches"].shape == (3,) and got["matches"].max() < small_pair["shapes"][1].n_points


@pytest.mark.parametrize("refine", ["zoomout", "zoomout-hybrid"])
@pytest.mark.parametrize("cloud_is", ["source", "target"])
def test_refine_with_a_point_cloud_is_not_applicable(
    service, client, small_pair, test_shape, refine, cloud_is
):
    mesh = small_pair["ids"][0]
    cloud = client.register_arrays(test_shape(4).vertices, kind="point_cloud")["shape_id"]
    src, tgt = (cloud, mesh) if cloud_is == "source" else (mesh, cloud)
    body = {"source_shape_id": src, "target_shape_id": tgt, "queries": [0, 1], "refine": refine}
    problem = assert_problem(_post(service, body), 422, "method-not-applicable")
    assert "point cloud" in problem["detail"] and cloud_is in problem["detail"]
    assert client.correspondences(src, tgt, [0, 1])["refinement"] == "none"  # unrefined: fine


def test_refine_without_pyfm_is_a_missing_dependency(service, client, blob, monkeypatch):
    """pyFM not importable on the server: 501 missing-dependency, never a 500. Fresh shapes: a
    pair refined before keeps its map (smoothed matches are read without pyFM)."""
    monkeypatch.setitem(sys.modules, "pyFM", None)  # `import pyFM` now raises ImportError
    shapes = (blob(41, subdivisions=2), blob(42, subdivisions=2))
    src, tgt = (client.register_arrays(s.vertices, s.faces)["shape_id"] for s in shapes)
    body = {"source_shape_id": src, "target_shape_id": tgt, "queries": [0], "refine": "zoomout"}
    problem = assert_problem(_post(service, body), 501, "missing-dependency")
    assert "pyFM" in problem["detail"]
    assert client.correspondences(src, tgt, [0])["n_queries"] == 1  # unrefined still works


# --------------------------------------------------------------------------- caching


def test_each_shape_is_prepared_once(service, client, test_shape):
    a, b = test_shape(5), test_shape(6)
    ids = [client.register_arrays(s.vertices, s.faces)["shape_id"] for s in (a, b)]
    before = prepared_count(service)
    first = client.correspondences(*ids, [0, 1, 2])
    assert prepared_count(service) == before + 2
    live = {"tier": "matching_state"}
    hits = counter(service, "litege_cache_requests_total", **live, result="hit")
    misses = counter(service, "litege_cache_requests_total", **live, result="miss")
    second = client.correspondences(*ids, "all")
    again = client.correspondences(ids[1], ids[0], [9])  # reverse: same prepared shapes
    assert prepared_count(service) == before + 2, "a second request must not recompute"
    assert counter(service, "litege_cache_requests_total", **live, result="hit") >= hits + 4
    assert counter(service, "litege_cache_requests_total", **live, result="miss") == misses
    np.testing.assert_array_equal(second["matches"][:3], first["matches"])
    assert again["n_queries"] == 1


def test_prepared_state_is_restored_from_the_store(service, client, pair):
    """The live LRU is dropped (an eviction): the store's copy is used, not recomputed."""
    src, tgt = pair["ids"]
    before = client.correspondences(src, tgt, "all", return_distance=True)
    computed = prepared_count(service)
    store_hits = counter(
        service, "litege_cache_requests_total", tier="matching_store", result="hit"
    )
    service.runtime.matching.forget_live()
    after = client.correspondences(src, tgt, "all", return_distance=True)
    assert prepared_count(service) == computed
    assert (
        counter(service, "litege_cache_requests_total", tier="matching_store", result="hit")
        == store_hits + 2
    )
    np.testing.assert_array_equal(after["matches"], before["matches"])
    np.testing.assert_allclose(after["distances"], before["distances"], atol=1e-6)


def test_redis_store_survives_an_api_restart(live_service_factory, shared_redis_url, test_shape):
    model = MatchingModel.tiny_random(SEED)
    a, b = test_shape(7), test_shape(8)
    keys = [artifact_key(s.content_hash, model.content_hash, MATCHING) for s in (a, b)]
    redis_client = redis.Redis.from_url(shared_redis_url)
    redis_client.delete(*keys)  # a previous run's copies

    first = live_service_factory(redis_url=shared_redis_url, matching=model)
    with LiteGEClient(first.base_url) as client:
        ids = [client.register_arrays(s.vertices, s.faces)["shape_id"] for s in (a, b)]
        before = client.correspondences(*ids, "all", return_distance=True)
        client.correspondences(*ids, [0])
    assert prepared_count(first) == 2
    assert all(redis_client.exists(k) for k in keys), "prepared shapes are written to Redis"
    first.stop()

    second = live_service_factory(
        redis_url=shared_redis_url, matching=MatchingModel.tiny_random(SEED)
    )
    with LiteGEClient(second.base_url) as client:
        after = client.correspondences(*ids, "all", return_distance=True)
    assert prepared_count(second) == 0, "the restarted API must not recompute"
    assert counter(second, "litege_cache_requests_total", tier="matching_store", result="hit") == 2
    np.testing.assert_array_equal(after["matches"], before["matches"])
    np.testing.assert_allclose(after["distances"], before["distances"], atol=1e-6)
    redis_client.close()


def test_delete_forgets_the_prepared_shape(service, client, test_shape):
    a, b = test_shape(9), test_shape(10)
    ids = [client.register_arrays(s.vertices, s.faces)["shape_id"] for s in (a, b)]
    client.correspondences(*ids, [0])
    client.delete_shape(ids[0])
    with pytest.raises(ProblemError) as gone:
        client.correspondences(*ids, [0])
    assert gone.value.status == 404 and gone.value.code == "shape-not-found"
    assert ids[0] in gone.value.problem["detail"]
    computed = prepared_count(service)
    client.register_arrays(a.vertices, a.faces)
    assert client.correspondences(*ids, [0])["n_queries"] == 1
    assert prepared_count(service) == computed + 1


# --------------------------------------------------------------------------- bad inputs

UNKNOWN = "f" * 64

DROP = object()
BAD_BODIES: dict[str, tuple[dict, int, str]] = {
    # case: (fields replacing those of a good body, status, problem code)
    "unknown source id": ({"source_shape_id": UNKNOWN}, 404, "shape-not-found"),
    "unknown target id": ({"target_shape_id": UNKNOWN}, 404, "shape-not-found"),
    "index out of range": ({"queries": [0, 10**6]}, 422, "index-out-of-range"),
    "negative index": ({"queries": [-1]}, 422, "index-out-of-range"),
    "NaN point": ({"queries": [[float("nan"), 0, 0]]}, 422, "non-finite-coordinates"),
    "absurd point": ({"queries": [[1e40, 0, 0]]}, 422, "coordinate-out-of-range"),
    "empty query list": ({"queries": []}, 422, "bad-array-shape"),
    "points not triples": ({"queries": [[0.0, 1.0]]}, 422, "bad-array-shape"),
    "queries not 'all'": ({"queries": "some"}, 422, "bad-array-shape"),
    "fractional index": ({"queries": [1.5]}, 422, "bad-array-shape"),
    "integral float index": ({"queries": [1.0]}, 422, "bad-array-shape"),
    "id not a string": ({"source_shape_id": 5}, 422, "invalid-request"),
    "missing target": ({"target_shape_id": DROP}, 422, "invalid-request"),
    "return_distance not a bool": ({"return_distance": "maybe"}, 422, "invalid-request"),
    "extra field": ({"beams": 4}, 422, "invalid-request"),
    "unknown model": ({"model": "quadrupeds-x"}, 422, "unknown-model"),
    "unknown refine": ({"refine": "zoom-out"}, 422, "invalid-request"),
    "refine in capitals": ({"refine": "ZOOMOUT"}, 422, "invalid-request"),
    "refine null": ({"refine": None}, 422, "invalid-request"),
    "refine a bool": ({"refine": True}, 422, "invalid-request"),
}


@pytest.mark.parametrize("case", list(BAD_BODIES))
def test_bad_inputs_give_problems_and_the_service_still_answers(service, client, pair, case):
    src, tgt = pair["ids"]
    before = client.correspondences(src, tgt, [0, 1, 2], return_distance=True)
    fields, status, code = BAD_BODIES[case]
    body = {"source_shape_id": src, "target_shape_id": tgt, "queries": [0]} | fields
    body = {k: v for k, v in body.items() if v is not DROP}
    assert_problem(_post(service, body), status, code)
    after = client.correspondences(src, tgt, [0, 1, 2], return_distance=True)
    np.testing.assert_array_equal(after["matches"], before["matches"])
    np.testing.assert_array_equal(after["distances"], before["distances"])


def test_too_many_queries(live_service_factory, test_shape):
    service = live_service_factory(max_queries=100, matching=MatchingModel.tiny_random(SEED))
    with LiteGEClient(service.base_url) as client:
        ids = [
            client.register_arrays(s.vertices, s.faces)["shape_id"]
            for s in (test_shape(1), test_shape(2))
        ]
        assert client.correspondences(*ids, list(range(100)))["n_queries"] == 100
        for queries in (list(range(101)), "all"):  # 642 points
            with pytest.raises(ProblemError) as error:
                client.correspondences(*ids, queries)
            assert error.value.status == 422 and error.value.code == "too-many-queries"
        assert client.correspondences(*ids, [0])["n_queries"] == 1


def test_without_a_matching_model_answers_unknown_model(live_service_factory, test_shape):
    service = live_service_factory(matching_model="")  # LITEGE_MATCHING_MODEL="": off
    assert not service.runtime.matching.models
    with LiteGEClient(service.base_url) as client:
        sid = client.register_arrays(test_shape(1).vertices, test_shape(1).faces)["shape_id"]
        with pytest.raises(ProblemError) as error:
            client.correspondences(sid, sid, [0])
    assert error.value.status == 422 and error.value.code == "unknown-model"


def test_openapi_documents_the_operation(service):
    schema = httpx.get(f"{service.base_url}/openapi.json").json()
    operation = schema["paths"]["/correspondences"]["post"]
    assert operation["requestBody"]["content"]["application/json"]
    response = schema["components"]["schemas"]["CorrespondenceResponse"]
    assert "input units" in response["properties"]["distances"]["description"]
    assert "unit-area" in response["properties"]["distances_unit_area"]["description"]
    assert "zoomout" in response["properties"]["refinement"]["description"]
    request = operation["requestBody"]["content"]["application/json"]["schema"]
    refine = request["properties"]["refine"]
    assert refine["enum"] == list(REFINE_METHODS) and refine["default"] == "none"


def test_matching_model_setting_loads_a_bundle_directory(live_service_factory, tmp_path):
    """``LITEGE_MATCHING_MODEL`` may name a bundle directory; an explicit name that does not
    load stops the start-up (the unset default is only skipped)."""
    from litege_core.matching.testing import save_tiny_matching_bundle

    manifest = save_tiny_matching_bundle(tmp_path / "bundle", SEED, name="dir-model")
    second = save_tiny_matching_bundle(tmp_path / "second", SEED + 1, name="dir-two")
    # a comma-separated list loads every bundle; the first is the default
    service = live_service_factory(matching_model=f"{tmp_path / 'bundle'}, {tmp_path / 'second'}")
    with LiteGEClient(service.base_url) as client:
        ready = client.ready()
        assert ready["matching_models"] == {
            "dir-model": {
                "bundle_hash": manifest["content_hash"],
                "category": "test",
                "precision": resolve_precision("auto"),
            },
            "dir-two": {
                "bundle_hash": second["content_hash"],
                "category": "test",
                "precision": resolve_precision("auto"),
            },
        }
        sid = client.register_arrays(tiny_shape_vertices())["shape_id"]  # a point cloud
        assert client.correspondences(sid, sid, [0, 1])["model"] == "dir-model"
        assert client.correspondences(sid, sid, [0, 1], model="dir-two")["model"] == "dir-two"
    settings = Settings(
        models=("quadrupeds",), device="cpu", matching_model="no-such-matching-model"
    )
    with pytest.raises(UnknownModelError, match="no-such-matching-model"):
        asyncio.run(Runtime.start(settings))


def tiny_shape_vertices() -> np.ndarray:
    rng = np.random.default_rng(0)
    return rng.normal(size=(300, 3)) * [1.5, 1.0, 0.5]


def test_matching_precision_setting_runs_the_search_head_in_bfloat16(
    live_service_factory, tmp_path, test_shape
):
    """``LITEGE_MATCHING_PRECISION=bfloat16``: ``/readyz`` says so and the answers are the
    library's bfloat16 search; an unknown precision is refused by the settings."""
    from litege_core.matching.testing import save_tiny_matching_bundle

    save_tiny_matching_bundle(tmp_path / "bundle", SEED, name="bf16-model")
    service = live_service_factory(
        matching_model=str(tmp_path / "bundle"), matching_precision="bfloat16"
    )
    library = MatchingModel.load(tmp_path / "bundle", precision="bfloat16")
    source, target = test_shape(1), test_shape(2)
    with LiteGEClient(service.base_url) as client:
        assert client.ready()["matching_models"]["bf16-model"]["precision"] == "bfloat16"
        ids = [client.register_arrays(s.vertices, s.faces)["shape_id"] for s in (source, target)]
        got = client.correspondences(*ids, [0, 7, 19], return_distance=True)
    x, y = (library.prepare(s, seed=0) for s in (source, target))
    expected = library.match(x, y, [0, 7, 19])
    np.testing.assert_array_equal(got["matches"], expected.indices)
    with pytest.raises(ValueError):
        Settings(matching_precision="float16")
    # the setting offers exactly what the library resolves
    choices = typing.get_args(Settings.model_fields["matching_precision"].annotation)
    assert choices == ("auto", *PRECISIONS)
