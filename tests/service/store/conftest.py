"""Fixtures of the artifact-store tests: a fake clock, a raw client on the shared test Redis
and a unique key prefix per test (its keys are deleted afterwards; nothing else in that database
is touched). The Redis servers themselves come from ``tests/service/conftest.py``."""

from __future__ import annotations

import uuid
from collections.abc import Iterator

import pytest
import redis


class FakeClock:
    """A monotonic clock that only moves when told (seconds)."""

    def __init__(self, start: float = 1000.0) -> None:
        self.now = start

    def __call__(self) -> float:
        return self.now

    def advance(self, seconds: float) -> None:
        self.now += seconds


@pytest.fixture
def fake_clock() -> FakeClock:
    return FakeClock()


@pytest.fixture
def raw_redis(shared_redis_url: str) -> Iterator[redis.Redis]:
    """A plain client on the shared test Redis, to inspect what the store wrote."""
    client = redis.Redis.from_url(shared_redis_url)
    yield client
    client.close()


@pytest.fixture
def key_prefix(raw_redis: redis.Redis) -> Iterator[str]:
    """A unique key prefix for this test; its keys are deleted afterwards."""
    prefix = f"litege-test-{uuid.uuid4().hex[:12]}:"
    yield prefix
    stale = list(raw_redis.scan_iter(match=f"{prefix}*", count=1000))
    if stale:
        raw_redis.delete(*stale)
