"""``LITEGE_GEODESIC_HEAD``, ``LITEGE_DESCRIPTOR_LATTICE`` and
``LITEGE_GEODESIC_PRECISION`` (issue 17) over real HTTP: by default each model runs its
own speed configuration (the shipped ones: small head, stride2 lattice; float32); the
service answers as the library does, says so on ``/readyz``, and stores the sparser lattice's
records under their own key, so a service on the full lattice never restores one."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from litege_core.learned import Predictor, load_shipped
from litege_core.nets.folded import fast_bfloat16, int8_engine
from litege_core.shape import Shape
from litege_core.synth import generate_shape
from service.client import LiteGEClient
from service.settings import Settings
from service.store import artifact_key

from .conftest import TEST_MODEL


@pytest.fixture(scope="module")
def dog() -> Shape:
    generated = generate_shape("quadruped", "dog", seed=6, reject=False)
    return Shape.from_arrays(generated.vertices, generated.faces)


def test_the_settings_default_to_each_models_own_speed_configuration() -> None:
    settings = Settings()
    assert (settings.geodesic_head, settings.descriptor_lattice) == ("auto", "auto")
    assert settings.geodesic_precision == "float32"
    with pytest.raises(ValueError):
        Settings(geodesic_head="tiny")
    with pytest.raises(ValueError):
        Settings(geodesic_precision="float16")
    with pytest.raises(ValueError):
        Settings(descriptor_lattice="sparse")


def test_fast_answers_are_the_library_answers_and_records_stay_apart(
    live_service_factory, private_redis, dog
) -> None:
    # the network alone, where the head and the lattice show (a mesh's fused answer is mostly
    # its graph's)
    fast = live_service_factory(
        geodesic_head="small",
        descriptor_lattice="stride2",
        geodesic_fusion="none",
        redis_url=private_redis.url,
    )
    cpu = torch.device("cpu")
    library = Predictor(
        load_shipped(TEST_MODEL), cpu, head="small", descriptor_lattice="stride2", fusion="none"
    )
    full = Predictor(
        load_shipped(TEST_MODEL), cpu, head="full", descriptor_lattice="full", fusion="none"
    )
    sources = [0, 300, 1200]
    with LiteGEClient(fast.base_url) as client:
        ready = client.ready()["models"][TEST_MODEL]
        assert (ready["head"], ready["lattice"]) == ("small", "stride2")
        shape_id = client.register_arrays(dog.vertices, dog.faces)["shape_id"]
        answer = client.geodesic(shape_id, sources)
    fast.stop()  # flushes the write-behind queue
    expected = library.distances(library.register(dog), sources)
    np.testing.assert_allclose(answer, expected, rtol=1e-5, atol=1e-6)
    full_answer = full.distances(full.register(dog), sources)
    assert not np.allclose(answer, full_answer, rtol=1e-3)
    bundle_hash = full.bundle.content_hash
    keys = private_redis.client()
    assert keys.exists(artifact_key(shape_id, bundle_hash, "record.stride2"))
    assert not keys.exists(artifact_key(shape_id, bundle_hash, "record"))
    # a full-lattice service on the same Redis computes its own record from the geometry
    plain = live_service_factory(
        geodesic_head="full",
        descriptor_lattice="full",
        geodesic_fusion="none",
        redis_url=private_redis.url,
    )
    with LiteGEClient(plain.base_url) as client:
        np.testing.assert_allclose(
            client.geodesic(shape_id, sources), full_answer, rtol=1e-5, atol=1e-6
        )
    plain.stop()
    assert keys.exists(artifact_key(shape_id, bundle_hash, "record"))


def test_a_default_service_runs_each_shipped_models_speed_configuration(
    live_service_factory,
) -> None:
    service = live_service_factory()
    with LiteGEClient(service.base_url) as client:
        ready = client.ready()["models"][TEST_MODEL]
    service.stop()
    assert (ready["head"], ready["lattice"]) == ("small", "stride2")


@pytest.mark.parametrize("precision", ["int8", "auto"])
def test_a_reduced_precision_service_answers_as_the_library_does(
    live_service_factory, dog, precision
) -> None:
    """``LITEGE_GEODESIC_PRECISION=int8`` (the point MLP and the small head in dynamic int8)
    or ``auto`` (both in bfloat16 where the CPU multiplies it natively, AMX / AVX512-BF16,
    float32 elsewhere): the answers are the library's in the same arithmetic."""
    if precision == "int8" and int8_engine() is None:
        pytest.skip("this torch build has no quantized engine")
    service = live_service_factory(geodesic_precision=precision, geodesic_fusion="none")
    library = Predictor(
        load_shipped(TEST_MODEL),
        torch.device("cpu"),
        precision=precision,
        embed_precision=precision,
        fusion="none",
    )
    with LiteGEClient(service.base_url) as client:
        ready = client.ready()["models"][TEST_MODEL]
        shape_id = client.register_arrays(dog.vertices, dog.faces)["shape_id"]
        field = client.geodesic(shape_id, [0])
    service.stop()
    native = "bfloat16" if fast_bfloat16("cpu") else "float32"
    arithmetic = {"int8": "int8", "auto": native}[precision]
    assert (ready["precision"], ready["embed_precision"]) == (arithmetic, arithmetic)
    expected = library.distances(library.register(dog), [0])
    np.testing.assert_allclose(field, expected, rtol=1e-5, atol=1e-6)
