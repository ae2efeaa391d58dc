"""A string enum that parses user input with a precise LiteGE error."""

from __future__ import annotations

import enum
from typing import Any, ClassVar, Self

from litege_core.errors import InputError


class ParsableEnum(enum.StrEnum):
    """``StrEnum`` with :meth:`parse`. A subclass names what its values are and the error an
    unknown one raises as class keywords (attributes, not members)::

        class ShapeKind(ParsableEnum, noun="shape kind", error=ArrayShapeError): ...
    """

    _noun: ClassVar[str]
    _error: ClassVar[type[InputError]]

    def __init_subclass__(
        cls, *, noun: str = "value", error: type[InputError] = InputError, **kwargs: Any
    ) -> None:
        super().__init_subclass__(**kwargs)
        cls._noun = noun
        cls._error = error

    @classmethod
    def parse(cls, value: str | Self) -> Self:
        """``value`` as a member; an unknown value raises ``cls._error`` listing the choices."""
        try:
            return cls(value)
        except ValueError as exc:
            raise cls._error(
                f"unknown {cls._noun} {value!r}; expected one of {[m.value for m in cls]}"
            ) from exc


__all__ = ["ParsableEnum"]
