"""Micro-batching of compute jobs from concurrent requests onto one worker thread.

Requests ``await submit(kind, payload)``; one asyncio task gathers up to ``max_batch`` queued
jobs (waiting at most ``max_wait_s`` for more once the first arrives), groups them by kind, and
runs each group's handler in a single dedicated thread, so the event loop never blocks and the
device sees one batched call per group. The queue is bounded: a full queue raises
:class:`OverloadedError` at once (HTTP 503 + Retry-After, gRPC RESOURCE_EXHAUSTED).

A handler takes a list of payloads and returns a list of the same length holding, per job,
its result or the exception to raise in that job's caller.

A job submitted with a :class:`CancelToken` is skipped once the token is cancelled; the token
is cancelled when its caller stops waiting (deadline, cancellation), so work nobody waits for
is not started. Payloads may carry the token too, for handlers that run their jobs one by one.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import threading
import time
from collections.abc import Callable, Mapping
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any

from service.errors import DeadlineExceededError, NotReadyError, OverloadedError
from service.metrics import ServiceMetrics

log = logging.getLogger("litege.batcher")

Handler = Callable[[list[Any]], list[Any]]

MAX_RETRY_AFTER_S = 60.0
"""Cap of the Retry-After estimate."""


class CancelToken:
    """Set once the request that submitted some jobs no longer waits for them (thread-safe:
    read on the compute thread)."""

    def __init__(self) -> None:
        self._event = threading.Event()

    def cancel(self) -> None:
        self._event.set()

    @property
    def cancelled(self) -> bool:
        return self._event.is_set()


@dataclass
class _Job:
    kind: str
    payload: Any
    future: asyncio.Future[Any]
    token: CancelToken | None = None
    enqueued: float = field(default_factory=time.perf_counter)

    @property
    def live(self) -> bool:
        """Whether somebody still waits for this job."""
        return not self.future.done() and not (self.token is not None and self.token.cancelled)


class MicroBatcher:
    """Bounded queue + one compute thread (see the module docstring).

    Args:
        handlers: job kind → batch handler.
        max_batch: most jobs per gathered batch.
        max_wait_s: longest wait for more jobs after the first one of a batch.
        queue_size: most jobs waiting; one more raises :class:`OverloadedError`.
    """

    def __init__(
        self,
        handlers: Mapping[str, Handler],
        *,
        max_batch: int,
        max_wait_s: float,
        queue_size: int,
        metrics: ServiceMetrics,
        thread_initializer: Callable[[], None] | None = None,
    ) -> None:
        self.handlers = dict(handlers)
        self.max_batch = int(max_batch)
        self.max_wait_s = float(max_wait_s)
        self.metrics = metrics
        self._queue: asyncio.Queue[_Job] = asyncio.Queue(maxsize=queue_size)
        self._executor = ThreadPoolExecutor(
            max_workers=1, thread_name_prefix="litege-compute", initializer=thread_initializer
        )
        self._task: asyncio.Task[None] | None = None
        self._closing = False
        self._batch_seconds = 0.01  # running mean of a gathered batch, for Retry-After
        self._waiting = 0

    def start(self) -> None:
        if self._task is None:
            self._task = asyncio.get_running_loop().create_task(self._run(), name="litege-batcher")

    @property
    def accepting(self) -> bool:
        """Whether :meth:`submit` takes jobs (started and not shutting down)."""
        return self._task is not None and not self._closing

    @property
    def depth(self) -> int:
        """Jobs queued and not yet taken into a batch."""
        return self._queue.qsize()

    @property
    def waiting(self) -> int:
        """Callers of :meth:`submit` waiting for their job (queued or computing)."""
        return self._waiting

    async def submit(
        self,
        kind: str,
        payload: Any,
        timeout_s: float | None = None,
        token: CancelToken | None = None,
    ) -> Any:
        """Queue one job and wait for its result (or its exception). When the wait ends
        without one (deadline, cancellation), ``token`` is cancelled.

        Raises:
            OverloadedError: the queue is full.
            DeadlineExceededError: no result within ``timeout_s``.
            NotReadyError: the batcher is shutting down.
        """
        if not self.accepting:
            raise NotReadyError("the service is shutting down")
        if kind not in self.handlers:
            raise KeyError(kind)
        future: asyncio.Future[Any] = asyncio.get_running_loop().create_future()
        try:
            self._queue.put_nowait(_Job(kind, payload, future, token))
        except asyncio.QueueFull:
            self.metrics.rejected.labels("queue_full").inc()
            raise OverloadedError(
                f"the compute queue is full ({self._queue.maxsize} jobs); retry later",
                retry_after_s=self.retry_after_s(),
            ) from None
        self.metrics.queue_depth.set(self._queue.qsize())
        self._waiting += 1
        try:
            return await asyncio.wait_for(future, timeout_s)
        except TimeoutError:
            if token is not None:
                token.cancel()
            raise DeadlineExceededError(
                f"no result within {timeout_s:.3g} s (queue depth {self._queue.qsize()})"
            ) from None
        except asyncio.CancelledError:
            if token is not None:
                token.cancel()
            raise
        finally:
            self._waiting -= 1

    def retry_after_s(self) -> float:
        """A Retry-After estimate in whole seconds: the time to work off the queued batches
        and the running one at the measured mean batch time (1 to 60 s)."""
        batches = math.ceil(self._queue.qsize() / max(1, self.max_batch)) + 1
        return float(min(MAX_RETRY_AFTER_S, max(1, math.ceil(batches * self._batch_seconds))))

    async def close(self, timeout_s: float | None = None) -> None:
        """Stop taking jobs, finish the queued ones, stop the worker thread. Jobs still queued
        after ``timeout_s`` answer :class:`NotReadyError`; the batch running then finishes
        (a compute job is at most one chunk of a request)."""
        self._closing = True
        if self._task is not None:
            try:
                await asyncio.wait_for(self._queue.join(), timeout_s)
            except TimeoutError:
                self._fail_queued(NotReadyError("the service shut down before this job ran"))
                log.warning("shutdown: jobs still queued after %.3g s were dropped", timeout_s)
                await self._queue.join()  # the running batch
            self._task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._task
            self._task = None
        self._executor.shutdown(wait=True)

    def _fail_queued(self, error: Exception) -> None:
        while True:
            try:
                job = self._queue.get_nowait()
            except asyncio.QueueEmpty:
                return
            if not job.future.done():
                job.future.set_exception(error)
            self._queue.task_done()

    async def _gather(self) -> list[_Job]:
        batch = [await self._queue.get()]
        deadline = time.perf_counter() + self.max_wait_s
        while len(batch) < self.max_batch:
            try:
                batch.append(self._queue.get_nowait())
                continue
            except asyncio.QueueEmpty:
                pass
            remaining = deadline - time.perf_counter()
            if remaining <= 0:
                break
            try:
                batch.append(await asyncio.wait_for(self._queue.get(), remaining))
            except TimeoutError:
                break
        return batch

    async def _run(self) -> None:
        loop = asyncio.get_running_loop()
        while True:
            batch = await self._gather()
            try:
                started = time.perf_counter()
                live = [job for job in batch if job.live]  # skip abandoned jobs
                for job in batch:
                    if not job.live and not job.future.done():
                        job.future.set_exception(
                            DeadlineExceededError("the request was abandoned before this job ran")
                        )
                for job in live:
                    self.metrics.queue_wait.observe(started - job.enqueued)
                groups: dict[str, list[_Job]] = {}
                for job in live:
                    groups.setdefault(job.kind, []).append(job)
                for kind, jobs in groups.items():
                    self.metrics.batch_size.labels(kind).observe(len(jobs))
                    await self._execute(loop, kind, jobs)
                elapsed = time.perf_counter() - started
                self._batch_seconds = 0.9 * self._batch_seconds + 0.1 * elapsed
            finally:
                for _ in batch:
                    self._queue.task_done()
                self.metrics.queue_depth.set(self._queue.qsize())

    async def _execute(self, loop: asyncio.AbstractEventLoop, kind: str, jobs: list[_Job]) -> None:
        payloads = [job.payload for job in jobs]
        try:
            results = await loop.run_in_executor(self._executor, self.handlers[kind], payloads)
            if len(results) != len(jobs):
                raise RuntimeError(f"handler {kind!r} returned {len(results)} results")
        except Exception as exc:  # a handler bug: every job of the group gets it
            log.exception("batch handler %r failed", kind)
            results = [exc] * len(jobs)
        for job, result in zip(jobs, results, strict=True):
            if job.future.done():
                continue
            if isinstance(result, BaseException):
                job.future.set_exception(result)
            else:
                job.future.set_result(result)
