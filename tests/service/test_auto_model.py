"""``model: auto`` (issue 13 item 7) over real REST and gRPC on loopback: a shape is scored under
every loaded model and kept under the one of lowest OOD score, which answers its queries; the
response names it and gives every score; ``auto`` is the default with several models loaded
(``LITEGE_DEFAULT_MODEL``), a named default still works; and a stored shape is queried under
another model without uploading it again."""

from __future__ import annotations

import asyncio

import numpy as np
import pytest
import torch

from litege_core.learned import Predictor, load_shipped
from litege_core.learned.router import CategoryRouter, RouterNet
from litege_core.shape import Shape
from litege_core.synth import generate_shape
from service.client import LiteGEClient, ProblemError
from service.errors import UnknownModelError
from service.grpc_client import GrpcClient
from service.runtime import _load_router
from service.settings import Settings

MODELS = ("quadrupeds", "humans")


def _procedural(category: str, family: str, seed: int = 3) -> Shape:
    generated = generate_shape(category, family, seed=seed, reject=False)
    return Shape.from_arrays(generated.vertices, generated.faces)


@pytest.fixture(scope="module")
def dog() -> Shape:
    return _procedural("quadruped", "dog")


@pytest.fixture(scope="module")
def human() -> Shape:
    return _procedural("biped", "slim")


@pytest.fixture(scope="module")
def predictors() -> dict[str, Predictor]:
    return {name: Predictor(load_shipped(name), torch.device("cpu")) for name in MODELS}


@pytest.fixture(scope="module")
def scores(predictors, dog, human) -> dict[str, dict[str, float]]:
    """The library's OOD scores of both shapes under both models."""
    return {
        label: {name: p.register(shape).ood_score for name, p in predictors.items()}
        for label, shape in (("dog", dog), ("human", human))
    }


@pytest.fixture(scope="module")
def auto_service(live_service_factory):
    """Both models, the settings' own default (``auto``), routed by the OOD score alone."""
    return live_service_factory(
        grpc=True, models=MODELS, default_model=Settings().default_model, router="none"
    )


def _fixed_router(directory, human_logit: float) -> str:
    """A router that gives every shape the same ``p(biped) = sigmoid(human_logit)``."""
    net = RouterNet(2)
    with torch.no_grad():
        net.classifier[-1].weight.zero_()
        net.classifier[-1].bias.copy_(torch.tensor([0.0, human_logit]))
    CategoryRouter(net, ("quadruped", "biped")).save(directory)
    return str(directory)


@pytest.fixture(scope="module")
def named_service(live_service_factory):
    """Both models, a named default (``quadrupeds``)."""
    return live_service_factory(models=MODELS, default_model="quadrupeds")


def test_auto_is_the_default_setting():
    assert Settings().default_model == "auto"
    assert Settings(models=("humans",)).default_model == "auto"
    with pytest.raises(ValueError, match="reserved"):
        Settings(models=("quadrupeds", "auto"))
    with pytest.raises(ValueError, match="LITEGE_DEFAULT_MODEL"):
        Settings(models=("quadrupeds",), default_model="humans")


def test_upload_picks_the_model_of_lowest_ood_score(auto_service, dog, human, scores):
    assert scores["human"]["humans"] < scores["human"]["quadrupeds"]  # the premise
    assert scores["dog"]["quadrupeds"] < scores["dog"]["humans"]
    with LiteGEClient(auto_service.base_url) as client:
        for label, shape, expected in (("dog", dog, "quadrupeds"), ("human", human, "humans")):
            info = client.register_arrays(shape.vertices, shape.faces)  # no model: auto
            assert info["model"] == expected and info["created"] is True
            assert set(info["model_scores"]) == set(MODELS)
            for name in MODELS:
                assert info["model_scores"][name] == pytest.approx(scores[label][name], abs=1e-4)
            assert info["ood_score"] == min(info["model_scores"].values())
            again = client.register_arrays(shape.vertices, shape.faces, model="auto")
            assert again["created"] is False and again["model"] == expected
            assert again["model_scores"] == info["model_scores"]


def test_queries_run_under_the_chosen_model(auto_service, human, predictors):
    with LiteGEClient(auto_service.base_url, binary=False) as client:
        shape_id = client.register_arrays(human.vertices, human.faces)["shape_id"]
        state = predictors["humans"].register(human)
        for model in (None, "auto"):
            # the same query history as the service's state: the first query embeds its two
            # sources alone, the second reads them from the feature table the first one built
            # (float32 rounding of a 2-row and an N-row product may differ in the last bits)
            expected = predictors["humans"].distances(state, [0, 9])
            np.testing.assert_allclose(
                client.geodesic(shape_id, [0, 9], "all", model=model), expected, rtol=1e-5
            )
            assert client.path(shape_id, 0, 100, model=model)["model"] == "humans"
            info = client.get_shape(shape_id, model=model)
            assert info["model"] == "humans" and set(info["model_scores"]) == set(MODELS)
        named = client.get_shape(shape_id, model="quadrupeds")  # a named model: its own
        assert named["model"] == "quadrupeds" and named["model_scores"] is None


def test_the_choice_survives_a_restart_without_recomputing(auto_service, dog):
    runtime = auto_service.runtime
    with LiteGEClient(auto_service.base_url) as client:
        shape_id = client.register_arrays(dog.vertices * 1.5, dog.faces)["shape_id"]
        first = client.get_shape(shape_id)
        runtime.repository.forget_live()  # a restart: only the store is left
        recomputed = _recomputes(runtime)
        again = client.get_shape(shape_id)
    assert again["model"] == first["model"] == "quadrupeds"
    assert again["model_scores"] == first["model_scores"]
    assert _recomputes(runtime) == recomputed  # both records restored, none recomputed


def _recomputes(runtime) -> float:
    value = runtime.metrics.registry.get_sample_value(
        "litege_cache_requests_total", {"tier": "store", "result": "recompute"}
    )
    return value or 0.0


def test_registered_under_one_model_queried_under_another(named_service, human, predictors):
    """No re-upload: the other model's record is computed from the stored geometry."""
    with LiteGEClient(named_service.base_url, binary=False) as client:
        info = client.register_arrays(human.vertices, human.faces, model="quadrupeds")
        assert info["model"] == "quadrupeds" and info["model_scores"] is None
        shape_id = info["shape_id"]
        got = client.geodesic(shape_id, [0, 5], [7, 8, 9], model="humans")
        state = predictors["humans"].register(human)
        np.testing.assert_allclose(
            got, predictors["humans"].distances(state, [0, 5], [7, 8, 9]), rtol=1e-5
        )
        humans = client.get_shape(shape_id, model="humans")
        assert humans["model"] == "humans" and humans["created"] is False
        # the named default: a query naming no model uses the model it is registered under
        assert client.get_shape(shape_id)["model"] == "quadrupeds"
        # auto on a named-default service: every model scored, the best answers
        best = client.get_shape(shape_id, model="auto")
        assert best["model"] == "humans" and set(best["model_scores"]) == set(MODELS)
        with pytest.raises(ProblemError) as unknown:
            client.get_shape(shape_id, model="cats")
        assert unknown.value.status == 422 and "auto" in unknown.value.problem["detail"]


def test_one_model_loaded_auto_is_that_model(live_service_factory, dog):
    service = live_service_factory(models=("quadrupeds",), default_model="auto")
    with LiteGEClient(service.base_url) as client:
        info = client.register_arrays(dog.vertices, dog.faces)
    assert info["model"] == "quadrupeds" and list(info["model_scores"]) == ["quadrupeds"]


def test_grpc_upload_and_queries_with_auto(auto_service, human, dog):
    with GrpcClient(auto_service.grpc_target, timeout_s=60) as client:
        info = client.register_arrays(human.vertices * 2.0, human.faces, model="auto")
        assert info["model"] == "humans" and set(info["model_scores"]) == set(MODELS)
        assert info["ood_score"] == min(info["model_scores"].values())
        plain = client.register_arrays(dog.vertices * 2.0, dog.faces)  # the default: auto
        assert plain["model"] == "quadrupeds" and plain["model_scores"]
        named = client.get_shape(plain["shape_id"], model="humans")
        assert named["model"] == "humans" and named["model_scores"] is None
        assert client.geodesic(info["shape_id"], [0], [1], model="auto").shape == (1, 1)
        assert client.path(info["shape_id"], 0, 50)["model"] == "humans"


def test_auto_registrations_in_one_batch(auto_service, dog, human):
    """Concurrent auto uploads (one compute job when they queue together) each get their own
    choice."""
    runtime = auto_service.runtime
    shapes = [Shape.from_arrays(s.vertices * 3.0, s.faces) for s in (dog, human)]

    async def both() -> list:
        return await asyncio.gather(*(runtime.register_shape(s, "auto") for s in shapes))

    infos = auto_service.call(both())
    assert [i.model for i in infos] == ["quadrupeds", "humans"]
    assert all(i.created and set(i.model_scores) == set(MODELS) for i in infos)


def test_a_confident_router_decides_and_an_unsure_one_leaves_the_ood_rule(
    live_service_factory, tmp_path_factory, dog, scores
):
    assert scores["dog"]["quadrupeds"] < scores["dog"]["humans"]  # the OOD rule: quadrupeds
    for logit, expected in ((8.0, "humans"), (0.5, "quadrupeds")):  # p(human) 0.9997, 0.62
        router = _fixed_router(tmp_path_factory.mktemp("router"), logit)
        service = live_service_factory(models=MODELS, default_model="auto", router=router)
        with LiteGEClient(service.base_url) as client:
            info = client.register_arrays(dog.vertices, dog.faces)
            assert info["model"] == expected
            assert info["model_scores"]["quadrupeds"] == pytest.approx(
                scores["dog"]["quadrupeds"], abs=1e-4
            )
            ready = client.ready()
            assert ready["router"]["categories"] == ["quadruped", "biped"]


def test_correspondences_naming_no_model_follow_the_router(
    live_service_factory, tmp_path_factory, dog, human
):
    # both shipped matching models; the fixed router calls every shape a biped (p 0.9997),
    # then nothing with confidence (p 0.62): the humans model, then (one geodesic model, so
    # no other category to take) the first (quadrupeds)
    for logit, expected in ((8.0, "humans"), (0.5, "quadrupeds")):
        router = _fixed_router(tmp_path_factory.mktemp("router"), logit)
        service = live_service_factory(models=("quadrupeds",), router=router)
        with LiteGEClient(service.base_url) as client:
            source = client.register_arrays(dog.vertices, dog.faces)["shape_id"]
            target = client.register_arrays(human.vertices, human.faces)["shape_id"]
            answer = client.correspondences(source, target, [0, 5])
            assert answer["model"] == expected and answer["matches"].shape == (2,)
            named = client.correspondences(source, target, [0, 5], model="quadrupeds")
            assert named["model"] == "quadrupeds"


def test_correspondences_naming_no_model_follow_the_auto_category_where_the_router_is_unsure(
    live_service_factory, tmp_path_factory, dog, human
):
    # an unsure router (p 0.62): the category of the shape's auto geodesic model decides (the
    # OOD rule: a human is registered as one, so it is matched by the humans model)
    router = _fixed_router(tmp_path_factory.mktemp("router"), 0.5)
    service = live_service_factory(models=MODELS, default_model="auto", router=router)
    with LiteGEClient(service.base_url) as client:
        person = client.register_arrays(human.vertices, human.faces)
        animal = client.register_arrays(dog.vertices, dog.faces)
        assert (person["model"], animal["model"]) == ("humans", "quadrupeds")
        ids = (person["shape_id"], animal["shape_id"])
        assert client.correspondences(*ids, [0, 5])["model"] == "humans"
        assert client.correspondences(*ids[::-1], [0, 5])["model"] == "quadrupeds"


def test_router_setting():
    assert Settings().router == "shipped"
    assert _load_router("none") is None
    with pytest.raises(UnknownModelError, match="router"):
        _load_router("/nonexistent/router")
