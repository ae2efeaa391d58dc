"""Where a shape's bytes live: the one owner of the store layout.

Per shape id the store holds its **geometry** once (``litege:{<shape_id>}:geometry``: the
vertices, the faces of a mesh, the kind; the source of truth, without which the shape is
gone) and, beside it, what each model bundle computed from it
(``litege:{<shape_id>}:<bundle_hash>:<artifact>``). Everything that reads or writes shape
bytes (the shape repository, the matching repository, the viewer through the repository)
goes through :class:`ShapeStore`; nothing else builds keys or calls the codec.

Reading geometry validates it again within the upload limits and checks that it hashes to
its shape id. Geometry or an artifact that cannot be decoded or parsed is deleted and reads
as missing. Thread-safe (the store is).
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Generic, TypeVar

import numpy as np

from litege_core.errors import ArtifactError, LiteGEError
from litege_core.shape import Shape
from litege_core.validate import ShapeLimits
from service.store.base import ArtifactStore
from service.store.codec import decode_arrays, encode_arrays
from service.store.keys import artifact_key, geometry_key

log = logging.getLogger("litege.repository")

T = TypeVar("T")
Arrays = dict[str, np.ndarray]


@dataclass(frozen=True)
class Artifact:
    """One bundle's artifact of a shape: ``name`` (e.g. ``"record"``) by ``bundle_hash``."""

    bundle_hash: str
    name: str


@dataclass
class Stored(Generic[T]):
    """What one read found for a shape (see :meth:`ShapeStore.read`).

    Attributes:
        shape_id: the shape read.
        exists: its geometry is in the store.
        artifacts: the parsed artifacts asked for, in order (``None``: missing or corrupt).
        corrupt: how many entries were corrupt (and deleted).
    """

    shape_id: str
    exists: bool
    artifacts: list[T | None]
    corrupt: int = 0
    _raw: bytes | None = field(default=None, repr=False)
    _decode: Callable[[str, bytes], Shape | None] | None = field(default=None, repr=False)
    _shape: Shape | None = field(default=None, repr=False)

    def shape(self) -> Shape | None:
        """The geometry (decoded and verified on first use); ``None`` if missing or corrupt
        (then deleted)."""
        if self._shape is None and self._raw is not None and self._decode is not None:
            raw, self._raw = self._raw, None
            self._shape = self._decode(self.shape_id, raw)
            if self._shape is None:
                self.exists = False
                self.corrupt += 1
        return self._shape


class ShapeStore:
    """Geometry once per shape id, artifacts per bundle beside it (see the module docstring).

    Args:
        store: the byte store (in-process, Redis, or both tiers).
        limits: what stored geometry must satisfy when read back (the upload limits).
        ttl_s: lifetime of what is written (sliding where the store supports it).
    """

    def __init__(self, store: ArtifactStore, *, limits: ShapeLimits, ttl_s: float | None) -> None:
        self.store = store
        self.limits = limits
        self.ttl_s = ttl_s

    # -- reads ------------------------------------------------------------------------------

    def read(
        self,
        shape_id: str,
        artifacts: Sequence[Artifact],
        parse: Callable[[Arrays], T],
        *,
        geometry: bool = True,
    ) -> Stored[T]:
        """A shape's geometry and ``artifacts`` in one round trip.

        Args:
            shape_id: the shape's content hash.
            artifacts: the artifacts wanted, each parsed with ``parse`` (which raises
                :class:`ArtifactError` for malformed arrays: the artifact is then deleted).
            parse: arrays → artifact object.
            geometry: read the geometry too (else ``exists`` is ``False`` and ``shape()``
                ``None``); it is decoded only when ``shape()`` is called.
        """
        keys = [artifact_key(shape_id, a.bundle_hash, a.name) for a in artifacts]
        if geometry:
            keys.insert(0, geometry_key(shape_id))
        raws = self.store.get_many(keys) if keys else []
        raw_geometry = raws.pop(0) if geometry else None
        found: Stored[T] = Stored(
            shape_id, raw_geometry is not None, [], _raw=raw_geometry, _decode=self._decode
        )
        for key, raw in zip(keys[1:] if geometry else keys, raws, strict=True):
            value = None if raw is None else self._parse(key, raw, parse)
            if raw is not None and value is None:
                found.corrupt += 1
            found.artifacts.append(value)
        return found

    def geometry(self, shape_id: str) -> Shape | None:
        """The shape's own geometry, or ``None`` (missing, or corrupt and deleted)."""
        raw = self.store.get(geometry_key(shape_id))
        return None if raw is None else self._decode(shape_id, raw)

    def _decode(self, shape_id: str, raw: bytes) -> Shape | None:
        """Stored geometry bytes as a verified :class:`Shape`; ``None`` (and the entry
        deleted) when they do not decode, validate or hash to ``shape_id``."""
        key = geometry_key(shape_id)
        try:
            arrays, meta = decode_arrays(raw)
            shape = Shape.from_arrays(
                arrays["vertices"], arrays.get("faces"), kind=meta.get("kind"), limits=self.limits
            )
            if shape.content_hash != shape_id:
                raise ArtifactError("stored geometry does not hash to its shape id")
        except (LiteGEError, KeyError) as exc:
            log.warning("deleting corrupt geometry %s: %s", key, exc)
            self.store.delete([key])
            return None
        return shape

    def _parse(self, key: str, raw: bytes, parse: Callable[[Arrays], T]) -> T | None:
        try:
            arrays, _ = decode_arrays(raw)
            return parse(arrays)
        except ArtifactError as exc:
            log.warning("deleting corrupt artifact %s: %s", key, exc)
            self.store.delete([key])
            return None

    # -- writes -----------------------------------------------------------------------------

    def write(
        self,
        shape_id: str,
        artifacts: Mapping[Artifact, tuple[Arrays, Mapping[str, str]]],
        *,
        shape: Shape | None = None,
    ) -> bool:
        """Write ``artifacts`` (arrays and string metadata each), and the geometry of
        ``shape`` when given, in one batch; ``False`` when the store did not take them now."""
        items: dict[str, bytes] = {}
        if shape is not None:
            if shape.content_hash != shape_id:
                raise ArtifactError("geometry written under another shape's id")
            arrays: Arrays = {"vertices": np.asarray(shape.vertices)}
            if shape.faces is not None:
                arrays["faces"] = np.asarray(shape.faces)
            items[geometry_key(shape_id)] = encode_arrays(arrays, {"kind": shape.kind.value})
        for artifact, (arrays, meta) in artifacts.items():
            key = artifact_key(shape_id, artifact.bundle_hash, artifact.name)
            items[key] = encode_arrays(arrays, meta)
        ok = self.store.put_many(items, ttl_s=self.ttl_s)
        if not ok:
            log.warning("shape %s not written to the shared store now (degraded)", shape_id)
        return ok

    def discard(self, shape_id: str, artifact: Artifact) -> None:
        """Delete an artifact found unusable after parsing (e.g. refused by its model)."""
        self.store.delete([artifact_key(shape_id, artifact.bundle_hash, artifact.name)])

    def delete(self, shape_id: str, artifacts: Sequence[Artifact], *, geometry: bool) -> int:
        """Delete ``artifacts`` (and the geometry if asked); how many existed."""
        keys = [artifact_key(shape_id, a.bundle_hash, a.name) for a in artifacts]
        if geometry:
            keys.append(geometry_key(shape_id))
        return self.store.delete(keys) if keys else 0


__all__ = ["Artifact", "ShapeStore", "Stored"]
