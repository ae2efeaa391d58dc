"""Choosing the torch device: one rule for the library, the CLI and training."""

from __future__ import annotations

from typing import TYPE_CHECKING

from litege_core.errors import InputError

if TYPE_CHECKING:
    import torch


def resolve_device(spec: str | torch.device = "auto") -> torch.device:
    """``"auto"`` → CUDA when available, else CPU; otherwise ``spec`` parsed and checked.

    Raises:
        InputError: a malformed device, or CUDA requested on a machine without it.
    """
    import torch  # on first use: the torch-free CLI path never resolves a device

    if isinstance(spec, str) and spec == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    try:
        device = torch.device(spec)
    except (RuntimeError, TypeError, ValueError) as exc:
        raise InputError(f"invalid torch device {spec!r}: {exc}") from exc
    if device.type == "cuda" and not torch.cuda.is_available():
        raise InputError(f"device {spec!r} requested but CUDA is not available")
    return device


__all__ = [
    "resolve_device",
]
