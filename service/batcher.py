"""Micro-batching of compute jobs from concurrent requests onto one worker thread.

Requests ``await submit(kind, payload)``; one asyncio task gathers up to ``max_batch`` queued
jobs (waiting at most ``max_wait_s`` for more once the first arrives), groups them by kind, and
runs each group's handler in a single dedicated thread, so the event loop never blocks and the
device sees one batched call per group. The queue is bounded: a full queue raises
:class:`OverloadedError` at once (HTTP 503 + Retry-After, gRPC RESOURCE_EXHAUSTED).

A handler takes a list of payloads and returns a list of the same length holding, per job,
its result or the exception to raise in that job's caller.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from collections.abc import Callable, Mapping
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any

from service.errors import DeadlineExceededError, NotReadyError, OverloadedError
from service.metrics import ServiceMetrics

log = logging.getLogger("litege.batcher")

Handler = Callable[[list[Any]], list[Any]]


@dataclass
class _Job:
    kind: str
    payload: Any
    future: asyncio.Future[Any]
    enqueued: float = field(default_factory=time.perf_counter)


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
        self._batch_seconds = 0.01  # running mean, for Retry-After estimates

    def start(self) -> None:
        if self._task is None:
            self._task = asyncio.get_running_loop().create_task(self._run(), name="litege-batcher")

    @property
    def accepting(self) -> bool:
        """Whether :meth:`submit` takes jobs (started and not shutting down)."""
        return self._task is not None and not self._closing

    @property
    def depth(self) -> int:
        return self._queue.qsize()

    async def submit(self, kind: str, payload: Any, timeout_s: float | None = None) -> Any:
        """Queue one job and wait for its result (or its exception).

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
            self._queue.put_nowait(_Job(kind, payload, future))
        except asyncio.QueueFull:
            self.metrics.rejected.labels("queue_full").inc()
            raise OverloadedError(
                f"the compute queue is full ({self._queue.maxsize} jobs); retry later",
                retry_after_s=self.retry_after_s(),
            ) from None
        self.metrics.queue_depth.set(self._queue.qsize())
        try:
            return await asyncio.wait_for(future, timeout_s)
        except TimeoutError:
            raise DeadlineExceededError(
                f"no result within {timeout_s:.3g} s (queue depth {self._queue.qsize()})"
            ) from None

    def retry_after_s(self) -> float:
        """A Retry-After estimate: time to work off the queue, at least one second."""
        batches = self._queue.qsize() / max(1, self.max_batch) + 1
        return max(1.0, round(batches * self._batch_seconds, 1))

    async def close(self) -> None:
        """Stop taking jobs, finish the queued ones, stop the worker thread."""
        self._closing = True
        if self._task is not None:
            await self._queue.join()
            self._task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._task
            self._task = None
        self._executor.shutdown(wait=True)

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
                live = [job for job in batch if not job.future.done()]  # skip timed-out jobs
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
