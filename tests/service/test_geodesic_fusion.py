"""``LITEGE_GEODESIC_FUSION`` (issue 14) over real HTTP: by default (``auto``) and with ``graph``
the service answers learned geodesics with the shipped model's graph fusion, exactly as the
library does, says so on ``/readyz``, and keeps paths on the network's field; under ``graph`` a
model without a calibration refuses to start the service, under ``auto`` it answers with the
network alone."""

from __future__ import annotations

import asyncio

import numpy as np
import pytest
import torch

from litege_core.errors import InputError
from litege_core.learned import Predictor, load_shipped
from litege_core.shape import Shape
from litege_core.synth import generate_shape
from service.client import LiteGEClient
from service.runtime import Runtime
from service.settings import Settings

from .conftest import TEST_MODEL, service_settings


@pytest.fixture(scope="module")
def dog() -> Shape:
    generated = generate_shape("quadruped", "dog", seed=4, reject=False)
    return Shape.from_arrays(generated.vertices, generated.faces)


@pytest.fixture(scope="module", params=["auto", "graph"])
def fused_service(request, live_service_factory):
    return live_service_factory(geodesic_fusion=request.param)


def test_the_setting_defaults_to_the_shipped_calibrations() -> None:
    assert Settings().geodesic_fusion == "auto"
    with pytest.raises(ValueError):
        Settings(geodesic_fusion="average")


def test_fused_answers_are_the_library_answers(fused_service, dog) -> None:
    library = Predictor(load_shipped(TEST_MODEL), torch.device("cpu"), fusion="graph")
    plain = Predictor(load_shipped(TEST_MODEL), torch.device("cpu"), fusion="none")
    state = library.register(dog)
    sources = [0, 250, 1000]
    with LiteGEClient(fused_service.base_url) as client:
        assert client.ready()["models"][TEST_MODEL]["fusion"] == "graph"
        shape_id = client.register_arrays(dog.vertices, dog.faces)["shape_id"]
        answer = client.geodesic(shape_id, sources)
        path = client.path(shape_id, 0, 1000)
    np.testing.assert_allclose(answer, library.distances(state, sources), rtol=1e-5, atol=1e-6)
    assert not np.allclose(answer, plain.distances(plain.register(dog), sources), rtol=1e-3)
    # a fused model's path is the surface route its distances follow, not the network's walk
    expected = library.path(state, 0, 1000)
    assert expected.segments == ((0, "edge-flip"),) and expected.n_steps == 0
    assert path["length"] == pytest.approx(expected.length, rel=1e-4)
    assert [(s["start"], s["method"]) for s in path["segments"]] == [(0, "edge-flip")]
    assert path["length"] != pytest.approx(plain.path(plain.register(dog), 0, 1000).length)
    assert path["distance"] == pytest.approx(float(answer[0][1000]), rel=1e-5)  # as /geodesic
    assert path["predicted_distance"] == pytest.approx(expected.predicted_distance, rel=1e-4)


def test_a_model_without_calibration_stops_the_start(monkeypatch) -> None:
    import litege_core.learned.fusion_calibration as fusion

    monkeypatch.setattr(fusion, "FUSION_CONFIG", "missing-fusion.json")
    with pytest.raises(InputError, match="no graph-fusion calibration"):
        asyncio.run(Runtime.start(service_settings(geodesic_fusion="graph")))


def test_auto_answers_with_the_network_where_a_model_has_no_calibration(monkeypatch) -> None:
    import litege_core.learned.fusion_calibration as fusion

    monkeypatch.setattr(fusion, "FUSION_CONFIG", "missing-fusion.json")

    async def fusion_of_the_loaded_model() -> str:
        runtime = await Runtime.start(service_settings(geodesic_fusion="auto"))
        try:
            return runtime.readiness().detail["models"][TEST_MODEL]["fusion"]
        finally:
            await runtime.close()

    assert asyncio.run(fusion_of_the_loaded_model()) == "none"
