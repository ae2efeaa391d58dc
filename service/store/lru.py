"""The one in-process cache class: a thread-safe LRU map bounded by a byte budget.

Every in-process cache of the service is a :class:`ByteLRU` with its own budget (one setting
each): the artifact store's local tier, the write-behind queue in front of Redis, the live
geodesic states and the live matching shapes. :meth:`ByteLRU.usage` is what ``/metrics``
reports for each of them.

Sizes are what the caller says (``nbytes``) or, for caches of live objects, a
:class:`Footprint` that ``sizeof`` takes (:func:`footprint`): the numpy arrays, torch tensors
and k-d trees reachable from the object, each buffer counted once however many views share
it. Live objects grow after they are handed out (a state builds its surface projector on the
first xyz query, a prepared shape memoizes its feature tables, cached properties fill in),
always by adding to a dict or list; a footprint remembers the lengths of the ones it walked,
so telling whether an object grew costs a few ``len()`` calls. A cache with ``sizeof``
checks the entry it hands out on every hit, and every entry on every insertion and every
:meth:`~ByteLRU.usage` report (a scrape), re-measures those that grew and evicts to the budget.
"""

from __future__ import annotations

import enum
import threading
import types
from collections import OrderedDict
from collections.abc import Callable, Hashable, Iterable, Sized
from dataclasses import dataclass, field, fields, is_dataclass
from typing import Any, Generic, TypeVar

import numpy as np
import torch
from scipy.spatial import cKDTree

K = TypeVar("K", bound=Hashable)
V = TypeVar("V")

_MAX_DEPTH = 6  # object → lazy dict → projector → tree → arrays, with room to spare
_OPAQUE = (
    type,
    types.ModuleType,
    types.FunctionType,
    types.MethodType,
    types.BuiltinFunctionType,
    enum.Enum,
    torch.device,
    torch.dtype,
    np.dtype,
    torch.nn.Module,  # a model is not a cache entry's own memory
)


@dataclass(frozen=True)
class CacheUsage:
    """What one bounded cache holds now."""

    entries: int
    bytes: int
    max_bytes: int
    evictions: int
    """Entries dropped to stay within the budget since the cache was created."""


@dataclass(frozen=True, eq=False)
class Footprint:
    """What a live object weighs now (see :func:`footprint`), and how to tell it grew."""

    nbytes: int
    _containers: tuple[tuple[Sized, int], ...] = field(default=(), repr=False)

    def changed(self) -> bool:
        """Whether a dict or list walked when measuring has changed length since."""
        return any(len(c) != n for c, n in self._containers)


def footprint(*objects: object) -> Footprint:
    """Bytes of the arrays, tensors and k-d trees reachable from ``objects`` (through
    attributes, dataclass fields, cached properties, dicts, lists and tuples, a few levels
    deep), each underlying buffer counted once; Python object overhead is not counted."""
    seen_objects: set[int] = set()
    seen_buffers: set[tuple[str, int, int]] = set()
    containers: list[tuple[Sized, int]] = []

    def buffer(kind: str, ident: int, extra: int, size: int) -> int:
        key = (kind, ident, extra)
        if key in seen_buffers:
            return 0
        seen_buffers.add(key)
        return size

    def walk(obj: Any, depth: int) -> int:
        if obj is None or isinstance(obj, str | int | float | bool) or id(obj) in seen_objects:
            return 0
        seen_objects.add(id(obj))
        if isinstance(obj, np.ndarray):
            root = obj
            while isinstance(root.base, np.ndarray):
                root = root.base
            if isinstance(root.base, bytes | bytearray):
                return buffer("bytes", id(root.base), 0, len(root.base))
            return buffer("numpy", id(root), 0, root.nbytes)
        if isinstance(obj, torch.Tensor):
            storage = obj.untyped_storage()
            device = hash(str(obj.device))
            return buffer("torch", storage.data_ptr(), device, storage.nbytes())
        if isinstance(obj, bytes | bytearray):
            return buffer("bytes", id(obj), 0, len(obj))
        if isinstance(obj, cKDTree):
            return walk(obj.data, depth + 1) + walk(obj.indices, depth + 1)
        if depth >= _MAX_DEPTH or isinstance(obj, _OPAQUE):
            return 0
        if isinstance(obj, dict | list | set):
            containers.append((obj, len(obj)))
            children: Iterable[Any] = tuple(obj.values() if isinstance(obj, dict) else obj)
        elif isinstance(obj, tuple | frozenset):
            children = tuple(obj)
        elif hasattr(obj, "__dict__"):  # attributes, dataclass fields and cached properties
            attributes = vars(obj)
            containers.append((attributes, len(attributes)))
            children = tuple(attributes.values())
        elif is_dataclass(obj):  # slotted
            children = tuple(getattr(obj, f.name, None) for f in fields(obj))
        else:
            return 0
        return sum(walk(child, depth + 1) for child in children)

    total = sum(walk(obj, 0) for obj in objects)
    return Footprint(total, tuple(containers))


def deep_nbytes(*objects: object) -> int:
    """``footprint(*objects).nbytes``."""
    return footprint(*objects).nbytes


class ByteLRU(Generic[K, V]):
    """A least-recently-used map whose entries' summed sizes stay within ``max_bytes``.

    Args:
        max_bytes: the budget (bytes).
        sizeof: measures a live value that may grow (see the module docstring); without it
            the size given to :meth:`put` is used and never changes.

    An entry larger than the whole budget is not kept. Thread-safe (one lock); ``sizeof`` is
    called with the lock held and must not call back into the cache.
    """

    def __init__(self, max_bytes: int, *, sizeof: Callable[[V], Footprint] | None = None) -> None:
        if max_bytes < 0:
            raise ValueError(f"max_bytes must be >= 0, got {max_bytes}")
        self.max_bytes = int(max_bytes)
        self._sizeof = sizeof
        self._lock = threading.Lock()
        # key -> (value, size, footprint or None); least recent first
        self._entries: OrderedDict[K, tuple[V, int, Footprint | None]] = OrderedDict()
        self._bytes = 0
        self._evictions = 0

    # -- internals (lock held) ------------------------------------------------------------------

    def _remeasure(self, key: K) -> None:
        value, size, measured = self._entries[key]
        if measured is None or not measured.changed() or self._sizeof is None:
            return
        measured = self._sizeof(value)
        self._entries[key] = (value, measured.nbytes, measured)
        self._bytes += measured.nbytes - size

    def _remeasure_all(self) -> None:
        if self._sizeof is not None:
            for key in list(self._entries):
                self._remeasure(key)

    def _evict(self) -> list[tuple[K, V]]:
        evicted = []
        while self._bytes > self.max_bytes and self._entries:
            key, (value, size, _) = self._entries.popitem(last=False)
            self._bytes -= size
            self._evictions += 1
            evicted.append((key, value))
        return evicted

    # -- reads ----------------------------------------------------------------------------------

    def get(self, key: K) -> V | None:
        """The value of ``key`` (now the most recent), or ``None``."""
        with self._lock:
            entry = self._entries.get(key)
            if entry is None:
                return None
            self._entries.move_to_end(key)
            self._remeasure(key)
            self._evict()  # a grown entry may push older ones (or itself) out
            return entry[0]

    def peek(self, key: K) -> V | None:
        """The value of ``key`` without touching its recency or size, or ``None``."""
        with self._lock:
            entry = self._entries.get(key)
            return None if entry is None else entry[0]

    def __contains__(self, key: object) -> bool:
        with self._lock:
            return key in self._entries

    def __len__(self) -> int:
        with self._lock:
            return len(self._entries)

    def keys(self) -> list[K]:
        """The keys, least recent first (a snapshot)."""
        with self._lock:
            return list(self._entries)

    def items(self) -> list[tuple[K, V]]:
        """``(key, value)`` pairs, least recent first (a snapshot)."""
        with self._lock:
            return [(k, v) for k, (v, _, _) in self._entries.items()]

    @property
    def nbytes(self) -> int:
        """The summed sizes as last measured."""
        with self._lock:
            return self._bytes

    def usage(self) -> CacheUsage:
        """Entries, bytes, budget and evictions, after re-measuring what grew."""
        with self._lock:
            self._remeasure_all()
            self._evict()
            return CacheUsage(len(self._entries), self._bytes, self.max_bytes, self._evictions)

    # -- writes ---------------------------------------------------------------------------------

    def put(self, key: K, value: V, nbytes: int | None = None) -> list[tuple[K, V]]:
        """Insert or replace ``key`` as the most recent entry; returns the evicted entries.

        ``nbytes`` defaults to what ``sizeof`` measures. A value larger than the budget is not
        kept (an older value of ``key`` is dropped) and comes back in the returned list.
        """
        result = self.put_many([(key, value, nbytes)], partial=True)
        assert result is not None  # partial puts always succeed
        return result

    def put_many(
        self, items: Iterable[tuple[K, V, int | None]], *, partial: bool = False
    ) -> list[tuple[K, V]] | None:
        """Insert ``(key, value, nbytes)`` entries as the most recent, in order.

        Without ``partial``, all or nothing: ``None`` (nothing changed) when the batch is
        larger than the whole budget. With it, each entry larger than the budget is skipped
        and reported as evicted. Returns the evicted entries (least recent first).
        """
        sized: list[tuple[K, V, int, Footprint | None]] = []
        for key, value, nbytes in items:
            if nbytes is not None:
                sized.append((key, value, int(nbytes), None))
            elif self._sizeof is None:
                raise ValueError("nbytes is required for a ByteLRU without sizeof")
            else:
                fp = self._sizeof(value)
                sized.append((key, value, fp.nbytes, fp))
        with self._lock:
            if not partial and sum(size for _, _, size, _ in sized) > self.max_bytes:
                return None
            evicted: list[tuple[K, V]] = []
            for key, value, size, measured in sized:
                old = self._entries.pop(key, None)
                if old is not None:
                    self._bytes -= old[1]
                if size > self.max_bytes:
                    self._evictions += 1
                    evicted.append((key, value))
                    continue
                self._entries[key] = (value, size, measured)
                self._bytes += size
            self._remeasure_all()
            # the batch is the most recent and fits by itself: eviction stops before it,
            # unless live entries grew past the budget
            evicted.extend(self._evict())
            return evicted

    def pop(self, key: K) -> V | None:
        """Remove ``key``; its value, or ``None`` if absent."""
        with self._lock:
            entry = self._entries.pop(key, None)
            if entry is None:
                return None
            self._bytes -= entry[1]
            return entry[0]

    def clear(self) -> None:
        """Drop every entry (not counted as evictions)."""
        with self._lock:
            self._entries.clear()
            self._bytes = 0


__all__ = ["ByteLRU", "CacheUsage", "Footprint", "deep_nbytes", "footprint"]
