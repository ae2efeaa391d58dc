"""Cache keys of the artifact store, one layout for the whole service.

- ``litege:{<shape_id>}:geometry``: a shape's own vertices and faces, once per shape id
  (:func:`geometry_key`);
- ``litege:{<shape_id>}:<bundle_hash>:<artifact>``: what one model bundle computed from it
  (:func:`artifact_key`), e.g. a geodesic bundle's ``record`` or a matching bundle's
  ``matching``.

The braces are a Redis Cluster hash tag: all keys of one shape live in one slot, so a shape's
geometry and artifacts can be read and written in one multi-key command. Every part is
validated so that a key always splits back into its parts and never collides with another
shape's key (no ``:``, braces or whitespace inside a part). Keys of the earlier layout
(``litege:<bundle_hash>:<shape_id>:<artifact>``) are never read: they expire on their TTL.
"""

from __future__ import annotations

import re

from litege_core.errors import InputError

KEY_PREFIX = "litege"
GEOMETRY = "geometry"
_BAD_CHARS = re.compile(r"[:{}\s]")


def _check_part(name: str, value: str) -> None:
    if not isinstance(value, str):
        raise InputError(
            f"{name} must be a string, got {type(value).__name__}", part=name, value=repr(value)
        )
    if not value:
        raise InputError(f"{name} must not be empty", part=name)
    if _BAD_CHARS.search(value):
        raise InputError(
            f"{name} {value!r} must not contain ':', braces or whitespace", part=name, value=value
        )


def geometry_key(shape_id: str) -> str:
    """``litege:{<shape_id>}:geometry``: where a shape's own arrays live.

    Raises :class:`~litege_core.errors.InputError` for an empty or malformed ``shape_id``.
    """
    _check_part("shape_id", shape_id)
    return f"{KEY_PREFIX}:{{{shape_id}}}:{GEOMETRY}"


def artifact_key(shape_id: str, bundle_hash: str, artifact: str) -> str:
    """``litege:{<shape_id>}:<bundle_hash>:<artifact>``: what one bundle computed for a shape.

    Raises :class:`~litege_core.errors.InputError` when a part is empty, not a string, or
    contains ``:``, braces or whitespace.
    """
    _check_part("shape_id", shape_id)
    _check_part("bundle_hash", bundle_hash)
    _check_part("artifact", artifact)
    return f"{KEY_PREFIX}:{{{shape_id}}}:{bundle_hash}:{artifact}"


__all__ = ["GEOMETRY", "KEY_PREFIX", "artifact_key", "geometry_key"]
