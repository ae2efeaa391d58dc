"""Admission of requests: the concurrency limit shared by REST and gRPC, and one request's
deadline shared by its compute jobs."""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable, Iterator

from service.errors import DeadlineExceededError, OverloadedError
from service.metrics import ServiceMetrics


class Admission:
    """The concurrency limit (``LITEGE_MAX_CONCURRENCY``) shared by REST and gRPC: requests
    being served at once, over both protocols. Used on the event loop only."""

    def __init__(
        self, limit: int, metrics: ServiceMetrics, retry_after_s: Callable[[], float]
    ) -> None:
        self.limit = int(limit)
        self.in_flight = 0
        self._metrics = metrics
        self._retry_after_s = retry_after_s

    @contextlib.contextmanager
    def slot(self) -> Iterator[None]:
        """Hold one slot while the block runs.

        Raises:
            OverloadedError: (status 429) every slot is taken.
        """
        if self.in_flight >= self.limit:
            self._metrics.rejected.labels("concurrency").inc()
            raise OverloadedError(
                f"more than {self.limit} concurrent requests; retry later",
                retry_after_s=self._retry_after_s(),
                status=429,
            )
        self.in_flight += 1
        try:
            yield
        finally:
            self.in_flight -= 1


class Deadline:
    """The end of one request's time budget, shared by all of its compute jobs."""

    def __init__(self, timeout_s: float) -> None:
        self.timeout_s = timeout_s
        self.at = time.monotonic() + timeout_s

    def remaining(self) -> float:
        left = self.at - time.monotonic()
        if left <= 0:
            raise DeadlineExceededError(f"no result within {self.timeout_s:.3g} s")
        return left
