"""Boundary checks shared by the network modules (raise :mod:`litege_core.errors` only).

The checks look at shapes, dtypes and devices only: they never read tensor values, so they
cost no device synchronisation on hot paths.
"""

from __future__ import annotations

import torch

from litege_core.errors import ArrayShapeError, InputError


def as_tensor_like(
    value: object, name: str, reference: torch.Tensor, *, min_ndim: int = 1
) -> torch.Tensor:
    """``value`` as a floating tensor with the dtype of ``reference``, on its device.

    Args:
        value: a :class:`torch.Tensor` (anything else is refused: callers convert numpy
            arrays themselves, so the device a tensor lives on is always their choice).
        name: the argument name used in error messages.
        reference: a parameter or buffer of the module (gives dtype and device).
        min_ndim: smallest accepted rank.

    Raises:
        InputError: not a tensor, or on another device than the module.
        ArrayShapeError: rank below ``min_ndim`` or a non-real dtype.
    """
    if not isinstance(value, torch.Tensor):
        raise InputError(f"{name} must be a torch.Tensor, got {type(value).__name__}")
    if value.device != reference.device:
        raise InputError(
            f"{name} is on {value.device}, the network on {reference.device}; move one of them"
        )
    if value.is_complex() or value.dtype == torch.bool:
        raise ArrayShapeError(f"{name} must be real-valued, got dtype {value.dtype}")
    if value.ndim < min_ndim:
        raise ArrayShapeError(
            f"{name} must have at least {min_ndim} dimension(s), got shape {tuple(value.shape)}"
        )
    return value if value.dtype == reference.dtype else value.to(reference.dtype)


def check_last(value: torch.Tensor, size: int, name: str, what: str) -> None:
    """Raise :class:`ArrayShapeError` unless the last axis of ``value`` has ``size`` entries.

    ``what`` is the expected shape as written in the docstring, e.g. ``"(B, 3)"``."""
    if value.shape[-1] != size:
        raise ArrayShapeError(f"{name} must have shape {what}, got {tuple(value.shape)}")


def check_ndim(value: torch.Tensor, ndim: int, name: str, what: str) -> None:
    """Raise :class:`ArrayShapeError` unless ``value`` has rank ``ndim``."""
    if value.ndim != ndim:
        raise ArrayShapeError(f"{name} must have shape {what}, got {tuple(value.shape)}")


def broadcast_batch(first: tuple[int, ...], second: tuple[int, ...], names: str) -> tuple[int, ...]:
    """The broadcast of two batch shapes, or :class:`ArrayShapeError` naming ``names``."""
    try:
        return tuple(torch.broadcast_shapes(first, second))
    except RuntimeError as exc:
        raise ArrayShapeError(
            f"batch shapes of {names} do not broadcast: {first} and {second}"
        ) from exc
