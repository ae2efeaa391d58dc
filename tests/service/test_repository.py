"""ShapeRepository and MatchingRepository over an in-process store, with the shipped geodesic
bundles and a tiny matching model: one layout (geometry once per shape id, artifacts per
bundle beside it), lookups under another model computed from the stored geometry, corrupt
entries deleted, and every live cache within its own budget."""

from __future__ import annotations

import threading
from dataclasses import astuple

import numpy as np
import pytest
import torch

from litege_core.learned import Predictor, load_shipped
from litege_core.matching.model import PREPARATION_VERSION, MatchingModel
from litege_core.shape import Shape
from litege_core.validate import ShapeLimits
from service.errors import ShapeNotFoundError, UnknownModelError
from service.matching import MATCHING, MatchingRepository
from service.metrics import ServiceMetrics
from service.repository import ShapeRepository, record_artifact
from service.store import InMemoryStore, artifact_key, deep_nbytes, encode_arrays, geometry_key

MiB = 1024 * 1024


@pytest.fixture(scope="module")
def predictors() -> dict[str, Predictor]:
    cpu = torch.device("cpu")
    return {name: Predictor(load_shipped(name), cpu) for name in ("quadrupeds", "humans")}


@pytest.fixture(scope="module")
def matching_model() -> MatchingModel:
    return MatchingModel.tiny_random(0)


@pytest.fixture
def store() -> InMemoryStore:
    return InMemoryStore(256 * MiB)


def make_repository(predictors, store, *, state_cache_bytes: int = 64 * MiB, metrics=None):
    return ShapeRepository(
        predictors,
        "quadrupeds",
        store,
        state_cache_bytes=state_cache_bytes,
        ttl_s=None,
        metrics=metrics or ServiceMetrics(),
        limits=ShapeLimits(),
    )


@pytest.fixture
def repository(predictors, store) -> ShapeRepository:
    return make_repository(predictors, store)


def record_key(predictors, model: str, shape_id: str) -> str:
    return artifact_key(shape_id, *astuple(record_artifact(predictors[model])))


def sample(metrics: ServiceMetrics, name: str, **labels: str) -> float:
    """One sample's value as scraped (0 when absent)."""
    return metrics.registry.get_sample_value(name, labels) or 0.0


def cache(repository: ShapeRepository, tier: str, result: str) -> float:
    return sample(repository.metrics, "litege_cache_requests_total", tier=tier, result=result)


# -- layout and cross-model lookups ------------------------------------------------------------


def test_geometry_is_stored_once_and_records_per_model_beside_it(
    repository, predictors, store, blob
) -> None:
    shape = blob(0)
    (registered,) = repository.register_many([shape], "quadrupeds")
    assert registered.created and registered.model == "quadrupeds"
    shape_id = shape.content_hash
    assert set(store.keys()) == {
        geometry_key(shape_id),
        record_key(predictors, "quadrupeds", shape_id),
    }

    # the same shape under the other model: computed from the stored geometry, no upload
    under_humans = repository.get(shape_id, "humans")
    assert under_humans.model == "humans" and not under_humans.created
    assert under_humans.state.bundle_hash == predictors["humans"].bundle.content_hash
    assert set(store.keys()) == {
        geometry_key(shape_id),
        record_key(predictors, "quadrupeds", shape_id),
        record_key(predictors, "humans", shape_id),
    }
    assert cache(repository, "store", "recompute") == 1
    expected = predictors["humans"].register(shape)
    np.testing.assert_array_equal(under_humans.state.descriptor, expected.descriptor)

    # after a restart (no live states) both records are restored, nothing recomputed
    repository.forget_live()
    assert repository.get(shape_id, "humans").state.bundle_hash == expected.bundle_hash
    assert repository.get(shape_id).model == "quadrupeds"
    assert cache(repository, "store", "recompute") == 1
    assert cache(repository, "store", "hit") == 2


def test_without_a_model_the_one_it_is_registered_with_answers(repository, blob) -> None:
    shape = blob(1)
    repository.register_many([shape], "humans")
    repository.forget_live()
    found = repository.get(shape.content_hash)  # the default has no record: not computed
    assert found.model == "humans"
    assert cache(repository, "store", "recompute") == 0
    repository.get(shape.content_hash, "quadrupeds")
    repository.forget_live()
    assert repository.get(shape.content_hash).model == "quadrupeds"  # the default first
    with pytest.raises(UnknownModelError):
        repository.get(shape.content_hash, "cats")


def test_reupload_is_not_recomputed_and_lost_geometry_means_upload_again(
    repository, store, blob
) -> None:
    shape = blob(2)
    repository.register_many([shape], None)
    again = Shape.from_arrays(shape.vertices.copy(), shape.faces.copy())  # same content
    (second,) = repository.register_many([again], None)
    assert not second.created and cache(repository, "state", "hit") == 1

    store.delete([geometry_key(shape.content_hash)])  # evicted from the store
    repository.forget_live()
    with pytest.raises(ShapeNotFoundError, match="upload it again"):
        repository.get(shape.content_hash)
    with pytest.raises(ShapeNotFoundError):
        repository.shape(shape.content_hash)
    (third,) = repository.register_many([again], None)
    assert third.created
    assert store.get(geometry_key(shape.content_hash)) is not None


def test_keys_of_the_earlier_layout_are_ignored(repository, predictors, store, blob) -> None:
    shape = blob(3)
    bundle = predictors["quadrupeds"].bundle.content_hash
    old_arrays = encode_arrays({"vertices": shape.vertices, "faces": shape.faces}, {"kind": "mesh"})
    store.put_many({f"litege:{bundle}:{shape.content_hash}:arrays": old_arrays})
    with pytest.raises(ShapeNotFoundError):
        repository.get(shape.content_hash)


def test_delete_forgets_geometry_records_and_live_states(
    repository, predictors, store, blob
) -> None:
    shape = blob(4)
    repository.register_many([shape], None)
    repository.get(shape.content_hash, "humans")
    store.put_many({"unrelated": b"x"})
    assert repository.delete(shape.content_hash) is True
    assert store.keys() == ["unrelated"]
    with pytest.raises(ShapeNotFoundError):
        repository.get(shape.content_hash, "humans")
    assert repository.delete(shape.content_hash) is False


# -- corrupt entries ---------------------------------------------------------------------------


def test_corrupt_geometry_is_deleted_and_reads_as_missing(repository, store, blob) -> None:
    shape, other = blob(5), blob(6)
    repository.register_many([shape], None)
    repository.forget_live()
    key = geometry_key(shape.content_hash)
    store.put_many({key: b"not an artifact"})
    with pytest.raises(ShapeNotFoundError):
        repository.get(shape.content_hash)
    assert store.get(key) is None and cache(repository, "store", "corrupt") == 1

    # well-formed, but another shape's geometry: it does not hash to the id
    other_arrays = {"vertices": other.vertices, "faces": other.faces}
    store.put_many({key: encode_arrays(other_arrays, {"kind": "mesh"})})
    with pytest.raises(ShapeNotFoundError):
        repository.shape(shape.content_hash)
    assert store.get(key) is None


def test_corrupt_or_refused_records_are_deleted_and_recomputed(
    repository, predictors, store, blob
) -> None:
    shape, other = blob(7), blob(8)
    states = {s.content_hash: repository.register_many([s], None)[0].state for s in (shape, other)}
    key = record_key(predictors, "quadrupeds", shape.content_hash)
    for bad in (
        b"garbage",  # does not decode
        encode_arrays({"descriptor": np.zeros(3, np.float32)}),  # decodes, not a record
        encode_arrays(states[other.content_hash].record.to_arrays()),  # another shape's
    ):
        repository.forget_live()
        store.put_many({key: bad})
        state = repository.get(shape.content_hash).state
        np.testing.assert_array_equal(state.descriptor, states[shape.content_hash].descriptor)
        assert store.get(key) != bad  # replaced by the recomputed record
    assert cache(repository, "store", "recompute") == 3
    assert cache(repository, "store", "corrupt") == 2  # the refused one parsed fine


# -- the live states ---------------------------------------------------------------------------


def test_the_live_shape_is_handed_out_as_is_and_from_any_thread(repository, blob) -> None:
    shape = blob(9)
    repository.register_many([shape], None)
    assert repository.shape(shape.content_hash) is shape  # no rebuild, no re-hash
    repository.forget_live()
    found: list[Shape] = []
    worker = threading.Thread(target=lambda: found.append(repository.shape(shape.content_hash)))
    worker.start()
    worker.join()
    assert found[0] == shape and found[0] is not shape  # decoded from the store


def test_live_states_stay_within_their_own_budget(predictors, store, blob) -> None:
    shapes = [blob(seed) for seed in range(10, 14)]
    probe = make_repository(predictors, InMemoryStore(64 * MiB))
    probe.register_many(shapes[:1], None)
    one = probe._live.usage().bytes
    assert one >= deep_nbytes(shapes[0].vertices) + probe.get(shapes[0].content_hash).state.nbytes

    repository = make_repository(predictors, store, state_cache_bytes=int(2.5 * one))
    repository.register_many(shapes, None)
    usage = repository._live.usage()
    assert usage.entries == 2 and usage.bytes <= 2.5 * one and usage.evictions == 2
    # a projector built by an xyz query grows a state; the next insertion accounts it
    state = repository.get(shapes[-1].content_hash).state
    state.projector  # noqa: B018
    repository.get(shapes[0].content_hash)  # restored from the store: an insertion
    usage = repository._live.usage()
    assert usage.bytes <= usage.max_bytes
    assert usage.bytes == sum(
        deep_nbytes(live.shape, live.state) for _, live in repository._live.items()
    )


# -- matching ----------------------------------------------------------------------------------


def make_matching(repository, model, *, cache_bytes: int = 64 * MiB) -> MatchingRepository:
    return MatchingRepository(
        {model.name: model}, repository, cache_bytes=cache_bytes, metrics=repository.metrics
    )


def test_prepared_shapes_live_beside_the_geometry(repository, store, matching_model, blob) -> None:
    matching = make_matching(repository, matching_model)
    shape = blob(20)
    repository.register_many([shape], "humans")
    key = artifact_key(shape.content_hash, matching_model.content_hash, MATCHING)
    prepared = matching.get(shape.content_hash, "tiny")
    assert store.get(key) is not None
    # the key names the preparation's version: an upgrade never reads older preparations
    assert key.endswith(f":matching-v{PREPARATION_VERSION}")
    assert matching.get(shape.content_hash, "tiny") is prepared  # live

    matching.forget_live()
    repository.forget_live()
    restored = matching.get(shape.content_hash, "tiny")  # from the store, not prepared again
    np.testing.assert_array_equal(restored.aligned, prepared.aligned)
    assert sample(repository.metrics, "litege_matching_prepared_total", model="tiny") == 1

    matching.forget_live()
    store.put_many({key: b"corrupt"})
    again = matching.get(shape.content_hash, "tiny")  # deleted, prepared from the geometry
    np.testing.assert_array_equal(again.aligned, prepared.aligned)
    assert sample(repository.metrics, "litege_matching_prepared_total", model="tiny") == 2

    with pytest.raises(ShapeNotFoundError):
        matching.get("0" * 64, "tiny")
    assert matching.delete(shape.content_hash) is True
    assert store.get(key) is None and store.get(geometry_key(shape.content_hash)) is not None


def test_every_cache_has_its_own_budget_and_is_reported(predictors, matching_model, blob) -> None:
    metrics = ServiceMetrics()
    store = InMemoryStore(8 * MiB, name="memory")
    repository = make_repository(predictors, store, state_cache_bytes=3 * MiB, metrics=metrics)
    matching = make_matching(repository, matching_model, cache_bytes=1)  # holds nothing
    shape = blob(21)
    repository.register_many([shape], None)
    matching.get(shape.content_hash, "tiny")
    matching.get(shape.content_hash, "tiny")  # not kept: prepared again from the store
    budgets = {
        name: sample(metrics, "litege_cache_budget_bytes", cache=name)
        for name in ("state", "matching", "memory")
    }
    assert budgets == {"state": 3 * MiB, "matching": 1, "memory": 8 * MiB}
    state_bytes = sample(metrics, "litege_cache_bytes", cache="state")
    assert 0 < state_bytes <= 3 * MiB
    assert sample(metrics, "litege_cache_entries", cache="matching") == 0
    assert sample(metrics, "litege_cache_evictions_total", cache="matching") == 2
    assert sample(metrics, "litege_cache_bytes", cache="memory") == store.stats()["bytes"]
    assert sample(metrics, "litege_live_states") == 1
    assert sample(metrics, "litege_live_state_bytes") == state_bytes
    assert "litege_cache_budget_bytes" in metrics.render().decode()
