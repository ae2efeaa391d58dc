"""Cache keys of the artifact store: ``litege:{bundle_hash}:{shape_id}:{artifact}``.

Every part is validated so that a key can always be split back into its parts and never
collides with another shape's key (no ``:`` or whitespace inside a part).
"""

from __future__ import annotations

import re

from litege_core.errors import InputError

KEY_PREFIX = "litege"
_BAD_CHARS = re.compile(r"[:\s]")


def _check_part(name: str, value: str) -> None:
    if not isinstance(value, str):
        raise InputError(
            f"{name} must be a string, got {type(value).__name__}", part=name, value=repr(value)
        )
    if not value:
        raise InputError(f"{name} must not be empty", part=name)
    if _BAD_CHARS.search(value):
        raise InputError(
            f"{name} {value!r} must not contain ':' or whitespace", part=name, value=value
        )


def artifact_key(bundle_hash: str, shape_id: str, artifact: str) -> str:
    """Return the store key ``litege:{bundle_hash}:{shape_id}:{artifact}``.

    Raises :class:`~litege_core.errors.InputError` when a part is empty, not a string, or
    contains ``:`` or whitespace.
    """
    _check_part("bundle_hash", bundle_hash)
    _check_part("shape_id", shape_id)
    _check_part("artifact", artifact)
    return f"{KEY_PREFIX}:{bundle_hash}:{shape_id}:{artifact}"


__all__ = ["KEY_PREFIX", "artifact_key"]
