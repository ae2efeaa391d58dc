"""The viewer's routes over real HTTP: the page, its assets, the bundled examples and the
geometry of a registered shape (the service's own vertex order and faces)."""

from __future__ import annotations

import httpx
import numpy as np
import pytest

from litege_core.io import load_shape
from service import viewer

PROBLEM_JSON = "application/problem+json"


@pytest.fixture(scope="module")
def service(live_service_factory):
    return live_service_factory()


@pytest.fixture(scope="module")
def http(service):
    with httpx.Client(base_url=service.base_url, timeout=60) as client:
        yield client


def test_viewer_page_is_served_or_explains_how_to_build_it(http):
    response = http.get("/viewer")
    assert response.headers["content-type"].startswith("text/html")
    if (viewer.STATIC_DIR / "index.html").is_file():
        assert response.status_code == 200
        assert "/viewer/assets/viewer.js" in response.text
        assert http.get("/viewer/").status_code == 200
        asset = http.get("/viewer/assets/viewer.js")
        assert asset.status_code == 200
        assert asset.headers["content-type"].startswith("text/javascript")
        assert "https://" not in response.text  # nothing from a CDN
    else:
        assert response.status_code == 503 and "make viewer" in response.text


def test_unknown_assets_and_examples_are_problems(http):
    for path in ("/viewer/assets/nope.js", "/viewer/assets/..%2Fapp.py", "/viewer/examples/x.obj"):
        response = http.get(path)
        assert response.status_code == 404, path
        assert response.headers["content-type"].startswith(PROBLEM_JSON)
        assert response.json()["code"] == "not-found"


def test_examples_one_per_family_and_loadable(http):
    examples = http.get("/viewer/examples").json()["examples"]
    names = {e["name"] for e in examples}
    assert {"cat", "dog", "horse", "cow", "hippo", "human-average"} <= names
    for example in examples:
        assert example["label"] and example["model"] in ("quadrupeds", "humans")
        if example["name"] == "leopard":
            assert "CC BY 4.0" in example["attribution"]
    response = http.get("/viewer/examples/dog.obj")
    assert response.status_code == 200
    shape = load_shape(response.content, file_format="obj")
    assert shape.is_mesh and shape.n_points > 1000


def test_geometry_round_trips_the_registered_arrays(http, mesh_bytes, test_shape):
    info = http.post("/shapes", files={"file": ("g.obj", mesh_bytes(3, "obj"))}).json()
    response = http.get(f"/viewer/shapes/{info['shape_id']}/geometry")
    assert response.status_code == 200
    n, f = int(response.headers["X-N-Points"]), int(response.headers["X-N-Faces"])
    assert (n, f) == (info["n_points"], info["n_faces"])
    vertices = np.frombuffer(response.content, "<f4", n * 3).reshape(n, 3)
    faces = np.frombuffer(response.content, "<u4", f * 3, offset=n * 12).reshape(f, 3)
    shape = test_shape(3)
    np.testing.assert_allclose(vertices, shape.vertices, atol=1e-6)
    np.testing.assert_array_equal(faces, shape.faces)
    with_model = http.get(f"/viewer/shapes/{info['shape_id']}/geometry?model=quadrupeds")
    assert with_model.content == response.content


def test_geometry_of_a_point_cloud(http):
    points = np.random.default_rng(0).normal(size=(300, 3)).round(3).tolist()
    info = http.post("/shapes", json={"vertices": points, "kind": "point_cloud"}).json()
    response = http.get(f"/viewer/shapes/{info['shape_id']}/geometry")
    assert response.headers["X-N-Faces"] == "0" and response.headers["X-Kind"] == "point_cloud"
    assert len(response.content) == 300 * 12


def test_geometry_errors(http):
    missing = http.get("/viewer/shapes/" + "0" * 64 + "/geometry")
    assert missing.status_code == 404 and missing.json()["code"] == "shape-not-found"
    unknown_model = http.get("/viewer/shapes/abc/geometry?model=nope")
    assert unknown_model.status_code == 422 and unknown_model.json()["code"] == "unknown-model"


def test_geometry_needs_the_api_key_when_set(live_service_factory, mesh_bytes):
    keyed = live_service_factory(api_key="s3cret-viewer-key-0123")
    with httpx.Client(base_url=keyed.base_url, timeout=60) as client:
        assert client.get("/viewer/examples").status_code == 200  # public
        denied = client.get("/viewer/shapes/abc/geometry")
        assert denied.status_code == 401
        allowed = client.get(
            "/viewer/shapes/abc/geometry", headers={"X-API-Key": "s3cret-viewer-key-0123"}
        )
        assert allowed.status_code == 404


def test_viewer_routes_stay_out_of_the_openapi_schema(http):
    paths = http.get("/openapi.json").json()["paths"]
    assert not [p for p in paths if p.startswith("/viewer")]
