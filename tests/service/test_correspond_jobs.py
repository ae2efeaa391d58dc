"""Large requests run as several compute jobs: a big correspondence lets a small geodesic
request through between its chunks, answers the same as one call of the library, and stops
computing once its caller has given up (deadline or cancellation). A refined correspondence
(``refine``) runs in the same chunks: the first computes the pair's refined map, which the
library keeps, and every chunk answers through it."""

from __future__ import annotations

import asyncio
import importlib.util
import threading
from collections.abc import Iterator
from typing import Any

import httpx
import numpy as np
import pytest

from litege_core.matching.model import MatchingModel
from litege_core.query import parse_query
from service.errors import DeadlineExceededError

SEED = 3
CHUNK = 64


@pytest.fixture(scope="module")
def service(live_service_factory):
    service = live_service_factory(matching=MatchingModel.tiny_random(SEED))
    service.runtime.correspond_chunk = CHUNK
    return service


@pytest.fixture(scope="module")
def ids(service, test_shape) -> list[str]:
    out = []
    for seed in (1, 2):
        shape = test_shape(seed)
        response = httpx.post(
            f"{service.base_url}/shapes",
            json={"vertices": shape.vertices.tolist(), "faces": shape.faces.tolist()},
        )
        assert response.status_code in (200, 201), response.text
        out.append(response.json()["shape_id"])
    return out


class Recorder:
    """Wraps the service's matching model and geodesic handler: records what the compute
    thread runs, in order, and can hold the first correspondence chunk until released."""

    def __init__(self, service: Any, hold_first: bool) -> None:
        self.events: list[tuple[str, int]] = []
        self.refines: list[str] = []
        self.first_started = threading.Event()
        self.release = threading.Event()
        if not hold_first:
            self.release.set()
        runtime = service.runtime
        self.model = runtime.matching.models["tiny"]
        self.real_match = self.model.match
        self.real_geodesic = runtime.batcher.handlers["geodesic"]
        self.handlers = runtime.batcher.handlers

    def match(self, source: Any, target: Any, queries: Any = None, **options: Any) -> Any:
        self.events.append(("match", parse_query(queries).count(source.n_points)))
        self.refines.append(options.get("refine", "none"))
        if len(self.events) == 1:
            self.first_started.set()
            self.release.wait(30)
        return self.real_match(source, target, queries, **options)

    def geodesic(self, jobs: list[Any]) -> list[Any]:
        self.events.append(("geodesic", len(jobs)))
        return self.real_geodesic(jobs)

    def __enter__(self) -> Recorder:
        self.model.match = self.match
        self.handlers["geodesic"] = self.geodesic
        return self

    def __exit__(self, *exc: object) -> None:
        self.release.set()
        del self.model.match
        self.handlers["geodesic"] = self.real_geodesic


@pytest.fixture
def recorder(service) -> Iterator[Recorder]:
    with Recorder(service, hold_first=True) as r:
        yield r


def _queued(service, count: int) -> None:
    async def wait() -> None:
        while service.runtime.batcher.depth < count:
            await asyncio.sleep(0.005)

    service.call(wait(), timeout_s=30)


def test_a_small_request_runs_between_the_chunks_of_a_large_one(
    service, ids, recorder, thread_pool
):
    n_points = service.runtime.matching.get(ids[0], "tiny").n_points
    large = thread_pool.submit(
        httpx.post,
        f"{service.base_url}/correspondences",
        json={"source_shape_id": ids[0], "target_shape_id": ids[1], "queries": "all"},
        timeout=60,
    )
    assert recorder.first_started.wait(30)
    small = thread_pool.submit(
        httpx.post,
        f"{service.base_url}/geodesic",
        json={"shape_id": ids[0], "sources": [0], "targets": [1]},
        timeout=60,
    )
    _queued(service, 1)  # the small request waits behind the first chunk
    recorder.release.set()
    assert small.result(60).status_code == 200
    answer = large.result(60)
    assert answer.status_code == 200, answer.text
    kinds = [kind for kind, _ in recorder.events]
    assert kinds[:2] == ["match", "geodesic"], kinds
    sizes = [size for kind, size in recorder.events if kind == "match"]
    assert sizes == [CHUNK] * (n_points // CHUNK) + [n_points % CHUNK] * bool(n_points % CHUNK)
    reference = MatchingModel.tiny_random(SEED)
    prepared = [reference.prepare(service.runtime.repository.shape(i), seed=0) for i in ids]
    np.testing.assert_array_equal(answer.json()["matches"], reference.match(*prepared).indices)


def test_a_request_past_its_deadline_stops_computing(service, ids, recorder, thread_pool):
    runtime = service.runtime

    async def late() -> Any:
        return await runtime.correspond(ids[0], ids[1], "all", timeout_s=0.2)

    pending = thread_pool.submit(service.call, late())
    assert recorder.first_started.wait(30)
    with pytest.raises(DeadlineExceededError):
        pending.result(30)  # the caller has given up while the first chunk computes
    recorder.release.set()
    ok = httpx.post(  # runs after whatever the compute thread still had to do
        f"{service.base_url}/geodesic", json={"shape_id": ids[0], "sources": [0]}, timeout=60
    )
    assert ok.status_code == 200
    computed = sum(size for kind, size in recorder.events if kind == "match")
    assert computed == CHUNK, "only the chunk running at the deadline was computed"


def test_a_cancelled_request_stops_computing(service, ids, recorder):
    runtime = service.runtime
    task: dict[str, asyncio.Task[Any]] = {}

    async def start() -> None:
        task["t"] = asyncio.ensure_future(runtime.correspond(ids[0], ids[1], "all"))

    service.call(start())
    assert recorder.first_started.wait(30)

    async def cancel() -> bool:
        task["t"].cancel()
        try:
            await task["t"]
        except asyncio.CancelledError:
            return True
        return False

    assert service.call(cancel())
    recorder.release.set()
    ok = httpx.post(
        f"{service.base_url}/geodesic", json={"shape_id": ids[0], "sources": [0]}, timeout=60
    )
    assert ok.status_code == 200
    computed = sum(size for kind, size in recorder.events if kind == "match")
    assert computed == CHUNK


@pytest.mark.skipif(
    importlib.util.find_spec("pyFM") is None,
    reason="refine='zoomout' needs pyFM (PyPI pyfmaps, the 'eval' extra)",
)
def test_a_refined_request_runs_in_chunks_through_one_kept_map(service, blob):
    """More queries than a chunk: the unrefined and the refined request both run in chunks,
    ``refine`` passed to the library with each; the refined map of the pair is computed once
    (kept on the prepared source shape) and each request answers what one call of the library
    answers."""
    shapes = [blob(seed, subdivisions=2) for seed in (31, 32)]  # 162 vertices: > 2 chunks
    ids = []
    for shape in shapes:
        response = httpx.post(
            f"{service.base_url}/shapes",
            json={"vertices": shape.vertices.tolist(), "faces": shape.faces.tolist()},
        )
        assert response.status_code in (200, 201), response.text
        ids.append(response.json()["shape_id"])
    n_points = shapes[0].n_points
    assert n_points > 2 * CHUNK
    body = {"source_shape_id": ids[0], "target_shape_id": ids[1], "queries": "all"}
    with Recorder(service, hold_first=False) as recorder:
        plain = httpx.post(f"{service.base_url}/correspondences", json=body, timeout=60)
        refined = httpx.post(
            f"{service.base_url}/correspondences", json=body | {"refine": "zoomout"}, timeout=60
        )
    assert plain.status_code == 200 and refined.status_code == 200, refined.text
    sizes = [size for kind, size in recorder.events if kind == "match"]
    n_chunks = -(-n_points // CHUNK)
    assert sizes[:n_chunks] == [CHUNK] * (n_chunks - 1) + [n_points - CHUNK * (n_chunks - 1)]
    assert sizes[n_chunks:] == sizes[:n_chunks], "the refined request runs in the same chunks"
    assert recorder.refines == ["none"] * n_chunks + ["zoomout"] * n_chunks
    model = service.runtime.matching.default_model
    source = service.runtime.matching._live.peek((model, ids[0]))
    assert len(source._lazy["refined"]) == 1, "one refined map serves every chunk"
    assert plain.json()["refinement"] == "none" and refined.json()["refinement"] == "zoomout"
    reference = MatchingModel.tiny_random(SEED)
    prepared = [reference.prepare(shape, seed=0) for shape in shapes]
    expected = reference.match(*prepared, refine="zoomout")
    np.testing.assert_array_equal(refined.json()["matches"], expected.indices)
    np.testing.assert_array_equal(plain.json()["matches"], reference.match(*prepared).indices)
