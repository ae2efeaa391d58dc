"""Module weights as a flat ``{name: tensor}`` dict, and strict loading back.

The bundle format (safetensors, no pickle) builds on these two functions: what
:func:`state_to_tensors` returns can be passed to ``safetensors.torch.save_file`` unchanged
(CPU, contiguous, no shared storage), and :func:`load_state` accepts what
``safetensors.torch.load_file`` returns. Every mismatch is an :class:`ArtifactError` naming the
offending keys, never a bare ``RuntimeError`` from :meth:`torch.nn.Module.load_state_dict`.
"""

from __future__ import annotations

from collections.abc import Mapping

import torch
from torch import nn

from litege_core.errors import ArtifactError

_MAX_NAMED = 10  # keys listed per category in an error message


def state_to_tensors(module: nn.Module) -> dict[str, torch.Tensor]:
    """Every parameter and persistent buffer of ``module`` as detached CPU tensors.

    Includes BatchNorm running statistics and ``num_batches_tracked`` and, for
    :class:`~litege_core.nets.geodesic.GeodesicNet`, the coordinate normalization buffers.
    Each tensor is a contiguous copy that shares storage with nothing (safetensors refuses
    shared storage); dtypes are kept.
    """
    return {
        name: tensor.detach().to("cpu", copy=True).contiguous()
        for name, tensor in module.state_dict().items()
    }


def _listing(keys: list[str]) -> str:
    shown = ", ".join(keys[:_MAX_NAMED])
    return shown + (f", … ({len(keys) - _MAX_NAMED} more)" if len(keys) > _MAX_NAMED else "")


def load_state(module: nn.Module, tensors: Mapping[str, torch.Tensor]) -> None:
    """Load ``tensors`` into ``module`` strictly (in place, onto the module's device).

    Floating tensors are cast to the dtype of the module's own tensor (a bundle may store
    float16); integer buffers must stay integer.

    Raises:
        ArtifactError: keys missing or unexpected, a tensor of the wrong shape, a value that is
            not a tensor, a floating/integer dtype mix-up, or NaN/inf values. ``details`` holds
            the lists ``missing``, ``unexpected`` and ``mis_shaped``.
    """
    expected = module.state_dict()
    not_tensors = sorted(k for k, v in tensors.items() if not isinstance(v, torch.Tensor))
    if not_tensors:
        raise ArtifactError(f"state entries are not tensors: {_listing(not_tensors)}")
    missing = sorted(set(expected) - set(tensors))
    unexpected = sorted(set(tensors) - set(expected))
    mis_shaped = sorted(
        f"{k} {tuple(tensors[k].shape)} (expected {tuple(expected[k].shape)})"
        for k in set(expected) & set(tensors)
        if tensors[k].shape != expected[k].shape
    )
    if missing or unexpected or mis_shaped:
        parts = [
            f"{label}: {_listing(keys)}"
            for label, keys in (
                ("missing", missing),
                ("unexpected", unexpected),
                ("mis-shaped", mis_shaped),
            )
            if keys
        ]
        raise ArtifactError(
            f"state does not fit {type(module).__name__}; " + "; ".join(parts),
            missing=missing,
            unexpected=unexpected,
            mis_shaped=mis_shaped,
        )
    wrong_kind = sorted(
        k
        for k, v in tensors.items()
        if v.is_floating_point() != expected[k].is_floating_point() or v.is_complex()
    )
    if wrong_kind:
        raise ArtifactError(f"state entries have the wrong kind of dtype: {_listing(wrong_kind)}")
    non_finite = sorted(
        k for k, v in tensors.items() if v.is_floating_point() and not bool(v.isfinite().all())
    )
    if non_finite:
        raise ArtifactError(f"state entries contain NaN or inf: {_listing(non_finite)}")
    try:
        module.load_state_dict(dict(tensors), strict=True)
    except RuntimeError as exc:  # pragma: no cover - every known cause is checked above
        raise ArtifactError(f"cannot load state into {type(module).__name__}: {exc}") from exc


__all__ = ["load_state", "state_to_tensors"]
