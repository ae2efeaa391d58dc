"""The shared artifact store on Redis, with a degraded mode for outages.

Values are plain Redis strings. Writes go in one ``MULTI``/``EXEC`` transaction of
``SET key value PX ttl`` (all keys or none); reads use ``GETEX key PX ttl`` so that the TTL
slides: an artifact that keeps being read stays cached, one that is not expires ``ttl`` after
its last use. Every read resets the TTL to ``default_ttl_s``: a per-call ``ttl_s`` of
:meth:`RedisStore.put_many` sets only the lifetime until the first read. With
``default_ttl_s=None`` reads are plain ``GET``/``MGET`` and leave any TTL alone. Batched reads
are one pipeline round trip.

Outages. The client is built with no retries and a short socket timeout. The first
connection/timeout/OS error marks the store *unavailable*: from then on every call returns a
miss / ``False`` / ``0`` at once, without touching the network, until the backoff deadline.
The first call after the deadline (and only that one: concurrent callers keep skipping) probes
Redis; a failure doubles the backoff up to ``backoff_max_s``, a success resets it. So an outage
costs at most one socket timeout per backoff period, never one per request. Other Redis errors
(``OOM``, ``WRONGTYPE``, ...) are counted, logged on ``litege.store`` and reported as a
miss / failed write; they do not mark the store unavailable. Nothing is raised to callers.

Restarts. redis-py reconnects pooled connections silently, so a Redis restarted between two
requests is not an outage to the caller, yet it may come back empty. Every new connection
therefore also reads the server's ``run_id`` (``INFO server``); :attr:`RedisStore.generation`
changes when it differs from the last one seen, as it does when the store comes back after an
outage, and the tiered store then refills Redis from its local tier.

Needs Redis >= 6.2 (``GETEX``); on an older server every read with a TTL is a counted error.
"""

from __future__ import annotations

import datetime as _dt
import enum
import logging
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from typing import Final, Literal, TypeVar
from urllib.parse import urlsplit, urlunsplit

import redis
import redis.exceptions
from redis.backoff import NoBackoff
from redis.retry import Retry

from service.store.base import StoreHealth, as_bytes, check_ttl
from service.store.lru import CacheUsage

logger = logging.getLogger("litege.store")

UNREACHABLE_ERRORS: tuple[type[BaseException], ...] = (
    redis.exceptions.ConnectionError,  # also covers BusyLoadingError, AuthenticationError
    redis.exceptions.TimeoutError,
    OSError,
)
"""Errors that mean "Redis cannot be reached now" and start the backoff."""

_LOG_EVERY_S = 10.0  # at most one WARNING per this many seconds for non-connection errors
_T = TypeVar("_T")


class _Skipped(enum.Enum):
    SKIPPED = enum.auto()


_SKIPPED: Final = _Skipped.SKIPPED  # result of an operation not attempted (backing off) or failed


def redact_url(url: str) -> str:
    """``url`` without its password (``redis://user:***@host:6379/0``)."""
    try:
        parts = urlsplit(url)
    except ValueError:
        return "<invalid redis url>"
    if parts.password is None:
        return url
    userinfo = f"{parts.username}:***" if parts.username else ":***"
    host = parts.hostname or ""
    if parts.port is not None:
        host = f"{host}:{parts.port}"
    return urlunsplit(parts._replace(netloc=f"{userinfo}@{host}"))


def _ttl_ms(ttl_s: float | None) -> int | None:
    return None if ttl_s is None else max(1, round(ttl_s * 1000.0))


class RedisStore:
    """Artifact store on one Redis server (sync ``redis`` client, thread-safe pool).

    Args:
        url: ``redis://[user:password@]host:port/db`` (or ``rediss://``, ``unix://``).
            Nothing is connected here: a Redis that is down at start-up only makes the first
            call a miss.
        default_ttl_s: sliding lifetime in seconds of entries written without ``ttl_s``;
            ``None`` keeps them until Redis evicts them (``maxmemory-policy``).
        socket_timeout_s: connect and read timeout in seconds for each round trip.
        backoff_initial_s: seconds to wait after the first failure before probing again.
        backoff_max_s: cap in seconds of the doubling backoff.
        clock: monotonic clock in seconds for the backoff (injectable for tests).
    """

    backend = "redis"

    def __init__(
        self,
        url: str,
        *,
        default_ttl_s: float | None,
        socket_timeout_s: float = 0.5,
        backoff_initial_s: float = 0.5,
        backoff_max_s: float = 30.0,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        check_ttl(default_ttl_s)
        if not 0 < backoff_initial_s <= backoff_max_s:
            raise ValueError(
                f"need 0 < backoff_initial_s <= backoff_max_s, got "
                f"{backoff_initial_s} and {backoff_max_s}"
            )
        self.url = redact_url(url)
        self.default_ttl_s = default_ttl_s
        self.backoff_initial_s = float(backoff_initial_s)
        self.backoff_max_s = float(backoff_max_s)
        self._clock = clock
        self._client = redis.Redis.from_url(
            url,
            socket_timeout=socket_timeout_s,
            socket_connect_timeout=socket_timeout_s,
            retry=Retry(NoBackoff(), 0),  # redis-py's default would retry 3x with sleeps
            health_check_interval=0,
            decode_responses=False,
            redis_connect_func=self._on_connect,
        )
        self._lock = threading.Lock()
        # Reachability state (guarded by _lock). _epoch changes at every state change or
        # probe, so that the failures of requests that raced into one outage count once.
        self._epoch = 0
        self._down_since: float | None = None  # clock() of the first failure
        self._down_since_wall: float | None = None  # time.time() of it, for humans
        self._retry_at = 0.0
        self._backoff_s = 0.0
        self._last_error = ""
        self._last_logged = -float("inf")
        self._generation = 0  # see :attr:`generation`
        self._run_id: str | None = None  # the server process last connected to
        self._counts = dict.fromkeys(
            (
                "hits",
                "misses",
                "writes",
                "write_failures",
                "errors",
                "connection_errors",
                "skipped",
                "reconnects",
                "restarts",
            ),
            0,
        )

    # -- reachability state machine -----------------------------------------------------------

    def _on_connect(self, connection: redis.connection.AbstractConnection) -> None:
        """Handshake of every new connection, plus ``INFO server``: a new ``run_id`` means
        the server restarted (possibly empty) even if no request saw it go away, because
        redis-py silently reconnects pooled connections."""
        connection.on_connect()
        try:
            connection.send_command("INFO", "server")
            info = connection.read_response()
        except redis.exceptions.ResponseError:  # INFO not allowed (ACL): no restart detection
            return
        text = info.decode("utf-8", "replace") if isinstance(info, bytes) else str(info)
        run_id = next(
            (
                line.split(":", 1)[1].strip()
                for line in text.splitlines()
                if line.startswith("run_id:")
            ),
            None,
        )
        with self._lock:
            restarted = None not in (run_id, self._run_id) and run_id != self._run_id
            if run_id is not None:
                self._run_id = run_id
            if restarted:
                self._generation += 1
                self._counts["restarts"] += 1
        if restarted:
            logger.warning(
                "redis at %s restarted (new run_id); it may have lost its data", self.url
            )

    def _count(self, name: str, n: int = 1) -> None:
        with self._lock:
            self._counts[name] += n

    def _admit(self, *, count_skip: bool = True) -> int | None:
        """An epoch token if the caller may touch the network now, else ``None``."""
        with self._lock:
            if self._down_since is None:
                return self._epoch
            now = self._clock()
            if now < self._retry_at:
                if count_skip:
                    self._counts["skipped"] += 1
                return None
            # This caller probes; the others keep skipping until it reports back.
            self._epoch += 1
            self._retry_at = now + self._backoff_s
            return self._epoch

    def _on_success(self, epoch: int) -> None:
        with self._lock:
            if self._down_since is None or epoch != self._epoch:
                return
            outage_s = self._clock() - self._down_since
            self._epoch += 1
            self._down_since = None
            self._down_since_wall = None
            self._backoff_s = 0.0
            self._retry_at = 0.0
            self._generation += 1
            self._counts["reconnects"] += 1
        logger.warning("redis at %s is reachable again after %.1f s", self.url, outage_s)

    def _on_unreachable(self, epoch: int, exc: BaseException) -> None:
        with self._lock:
            self._counts["connection_errors"] += 1
            self._counts["errors"] += 1
            if epoch != self._epoch:
                return  # another request of the same outage already moved the state
            now = self._clock()
            self._epoch += 1
            self._last_error = error = f"{type(exc).__name__}: {exc}"
            first = self._down_since is None
            if first:
                self._down_since = now
                self._down_since_wall = time.time()
                self._backoff_s = self.backoff_initial_s
            else:
                self._backoff_s = min(2.0 * self._backoff_s, self.backoff_max_s)
            self._retry_at = now + self._backoff_s
            backoff_s = self._backoff_s
        if first:
            logger.warning(
                "redis at %s is unreachable (%s); serving cache misses, next try in %.1f s",
                self.url,
                error,
                backoff_s,
            )
        else:
            logger.info(
                "redis at %s still unreachable (%s); next try in %.1f s",
                self.url,
                error,
                backoff_s,
            )

    def _on_redis_error(self, what: str, exc: BaseException) -> None:
        with self._lock:
            self._counts["errors"] += 1
            now = self._clock()
            loud = now - self._last_logged >= _LOG_EVERY_S
            if loud:
                self._last_logged = now
        logger.log(
            logging.WARNING if loud else logging.DEBUG,
            "redis at %s: %s failed: %s: %s",
            self.url,
            what,
            type(exc).__name__,
            exc,
        )

    def _run(self, what: str, fn: Callable[[], _T]) -> _T | Literal[_Skipped.SKIPPED]:
        """``fn()``, or ``_SKIPPED`` if backing off or it failed (never raises Redis errors)."""
        epoch = self._admit()
        if epoch is None:
            return _SKIPPED
        try:
            result = fn()
        except UNREACHABLE_ERRORS as exc:
            self._on_unreachable(epoch, exc)
            return _SKIPPED
        except redis.exceptions.RedisError as exc:
            self._on_success(epoch)  # the server answered, with an error
            self._on_redis_error(what, exc)
            return _SKIPPED
        self._on_success(epoch)
        return result

    # -- ArtifactStore -------------------------------------------------------------------------

    def get(self, key: str) -> bytes | None:
        """The value of ``key`` (sliding its TTL), or ``None`` on a miss or when unreachable."""
        px = _ttl_ms(self.default_ttl_s)
        if px is None:
            result = self._run("GET", lambda: self._client.get(key))
        else:
            result = self._run("GETEX", lambda: self._client.getex(key, px=px))
        if result is _SKIPPED or result is None:
            self._count("misses")
            return None
        self._count("hits")
        return result  # type: ignore[return-value]  # redis-py: sync replies typed Awaitable | Any

    def get_many(self, keys: Sequence[str]) -> list[bytes | None]:
        """The values of ``keys`` in order, in one round trip (pipelined GETEX, or MGET)."""
        keys = list(keys)
        if not keys:
            return []
        px = _ttl_ms(self.default_ttl_s)
        if px is None:
            result = self._run("MGET", lambda: self._client.mget(keys))
        else:

            def pipelined() -> list[object]:
                with self._client.pipeline(transaction=False) as pipe:
                    for key in keys:
                        pipe.getex(key, px=px)
                    return pipe.execute(raise_on_error=False)

            result = self._run("GETEX pipeline", pipelined)
        if result is _SKIPPED:
            self._count("misses", len(keys))
            return [None] * len(keys)
        values: list[bytes | None] = []
        for value in result:  # type: ignore[union-attr]  # redis-py: sync replies typed Awaitable | Any
            if isinstance(value, Exception):  # e.g. WRONGTYPE on one key
                self._on_redis_error("GETEX", value)
                value = None
            values.append(value)
        hits = sum(v is not None for v in values)
        with self._lock:
            self._counts["hits"] += hits
            self._counts["misses"] += len(values) - hits
        return values

    def put_many(self, items: Mapping[str, bytes], ttl_s: float | None = None) -> bool:
        """Write all ``items`` in one ``MULTI``/``EXEC`` with ``ttl_s`` (default the store's).

        Returns ``False`` (nothing raised) when unreachable or Redis refuses (e.g. ``OOM``:
        the transaction is then aborted as a whole).
        """
        check_ttl(ttl_s)
        values = {key: as_bytes(key, value) for key, value in items.items()}
        if not values:
            return True
        px = _ttl_ms(self.default_ttl_s if ttl_s is None else ttl_s)

        def transaction() -> list[object]:
            with self._client.pipeline(transaction=True) as pipe:
                for key, value in values.items():
                    pipe.set(key, value, px=px)
                return pipe.execute()

        result = self._run("SET transaction", transaction)
        if result is _SKIPPED:
            self._count("write_failures", len(values))
            return False
        self._count("writes", len(values))
        return True

    def delete(self, keys: Sequence[str]) -> int:
        """Delete ``keys`` with one ``DEL``; the number that existed (0 when unreachable)."""
        return self.try_delete(keys) or 0

    def try_delete(self, keys: Sequence[str]) -> int | None:
        """Like :meth:`delete`, but ``None`` when the ``DEL`` was not done (unreachable)."""
        keys = list(keys)
        if not keys:
            return 0
        result = self._run("DEL", lambda: self._client.delete(*keys))
        return None if result is _SKIPPED else int(result)  # type: ignore[arg-type]  # redis-py: sync replies typed Awaitable | Any

    def exists_many(self, keys: Sequence[str]) -> list[bool] | None:
        """Whether each key exists (one pipelined round trip of ``EXISTS``, TTLs untouched);
        ``None`` when unreachable."""
        keys = list(keys)
        if not keys:
            return []

        def pipelined() -> list[object]:
            with self._client.pipeline(transaction=False) as pipe:
                for key in keys:
                    pipe.exists(key)
                return pipe.execute()

        result = self._run("EXISTS pipeline", pipelined)
        if result is _SKIPPED:
            return None
        return [bool(n) for n in result]

    @property
    def generation(self) -> int:
        """Counts the store coming back after an outage and the server restarting: a change
        means Redis may have lost what it held and missed writes meanwhile."""
        with self._lock:
            return self._generation

    def memory_usage(self, key: str) -> int | None:
        """Bytes Redis uses for ``key`` (``MEMORY USAGE``), ``None`` if absent/unreachable."""
        result = self._run("MEMORY USAGE", lambda: self._client.memory_usage(key))
        return None if result is _SKIPPED or result is None else int(result)  # type: ignore[arg-type]  # redis-py: sync replies typed Awaitable | Any

    def health(self) -> StoreHealth:
        """PINGs Redis, except while backing off (then reports the outage without I/O)."""
        epoch = self._admit(count_skip=False)
        if epoch is None:
            return self._down_health()
        try:
            self._client.ping()
        except UNREACHABLE_ERRORS as exc:
            self._on_unreachable(epoch, exc)
            return self._down_health()
        except redis.exceptions.RedisError as exc:
            self._on_success(epoch)
            self._on_redis_error("PING", exc)
            return StoreHealth(self.backend, False, True, f"{self.url} answered PING with {exc!r}")
        self._on_success(epoch)
        return StoreHealth(self.backend, True, False, f"connected to {self.url}")

    def _down_health(self) -> StoreHealth:
        with self._lock:
            since = self._down_since_wall
            wait_s = max(0.0, self._retry_at - self._clock())
            error = self._last_error
        when = (
            _dt.datetime.fromtimestamp(since, tz=_dt.UTC).isoformat(timespec="seconds")
            if since is not None
            else "?"
        )
        return StoreHealth(
            self.backend,
            False,
            True,
            f"{self.url} unreachable since {when} ({error}); next retry in {wait_s:.1f} s",
        )

    @property
    def available(self) -> bool:
        """Whether the last contact succeeded (no I/O)."""
        with self._lock:
            return self._down_since is None

    def stats(self) -> dict[str, float]:
        """hits, misses, writes, write_failures (keys), errors (all Redis errors),
        connection_errors, skipped (calls answered without I/O while backing off),
        reconnects, restarts (new server run_id seen), available (1/0), backoff_s. No
        items/bytes/evictions: Redis is shared."""
        with self._lock:
            out: dict[str, float] = {k: float(v) for k, v in self._counts.items()}
            out["available"] = 1.0 if self._down_since is None else 0.0
            out["backoff_s"] = self._backoff_s
        return out

    def usage(self) -> dict[str, CacheUsage]:
        """Nothing in this process: Redis bounds itself (``maxmemory``)."""
        return {}

    def close(self) -> None:
        """Close the connection pool."""
        try:
            self._client.close()
        except Exception as exc:  # closing must not fail shutdown
            logger.debug("closing redis client for %s: %r", self.url, exc)


__all__ = ["UNREACHABLE_ERRORS", "RedisStore", "redact_url"]
