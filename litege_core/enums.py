"""A string enum that parses user input with a precise LiteGE error."""

from __future__ import annotations

import enum
from typing import ClassVar, Self

from litege_core.errors import InputError


class ParsableEnum(enum.StrEnum):
    """``StrEnum`` with :meth:`parse`. Subclasses set ``_noun`` (and optionally ``_error``)
    wrapped in :func:`enum.nonmember`, so they stay attributes instead of becoming members."""

    _noun: ClassVar[str] = enum.nonmember("value")
    _error: ClassVar[type[InputError]] = enum.nonmember(InputError)

    @classmethod
    def parse(cls, value: str | Self) -> Self:
        """``value`` as a member; an unknown value raises ``cls._error`` listing the choices."""
        try:
            return cls(value)
        except ValueError as exc:
            raise cls._error(
                f"unknown {cls._noun} {value!r}; expected one of {[m.value for m in cls]}"
            ) from exc
