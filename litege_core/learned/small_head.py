"""The distilled small head of a geodesic bundle: an optional sidecar next to the bundle files.

::

    BUNDLE/head-small.safetensors   SmallHead weights (float32, ~140 KB at m = 128, k = 64)
    BUNDLE/head-small.json          config (n, m, k, output), the teacher bundle's content hash,
                                    the weights' sha256, distillation settings, agreement

The sidecar is *not* listed in the bundle manifest, so adding one leaves the bundle's content
hash (service cache keys, shape records) unchanged; instead it names the content hash of the
bundle it was distilled from, and a sidecar whose teacher is not the bundle it sits in is
refused (:class:`InputError`: distil it again). Re-shipping a bundle (``scripts/ship_model.py``)
replaces the whole directory, sidecar included.

Written by :func:`save_small_head` (``scripts/distill_head.py``), read by
:func:`load_small_head` (``Predictor(bundle, head="small")``).
"""

from __future__ import annotations

import os
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import torch

from litege_core.errors import ArtifactError, InputError
from litege_core.files import file_sha256, read_json_object, write_json_atomic
from litege_core.learned.bundle import ModelBundle, load_weights
from litege_core.learned.manifest import (
    SMALL_HEAD_CONFIG,
    SMALL_HEAD_FORMAT,
    SMALL_HEAD_KIND,
    SMALL_HEAD_WEIGHTS,
    verified_small_head,
)
from litege_core.nets import state_to_tensors
from litege_core.nets.small_head import SmallHead


def save_small_head(
    directory: str | os.PathLike,
    head: SmallHead,
    teacher_hash: str,
    *,
    distillation: dict[str, Any] | None = None,
    agreement: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """Write ``head`` (float32) and its config into ``directory``; returns the config.

    Args:
        directory: usually the teacher bundle's directory (created if missing).
        head: the trained student.
        teacher_hash: content hash of the bundle it was distilled from.
        distillation: settings and summary of the run (free-form JSON).
        agreement: measured student-vs-teacher agreement (free-form JSON).
    """
    from safetensors.torch import save_file

    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    tensors = {k: v.float() for k, v in state_to_tensors(head).items()}
    for key, value in tensors.items():
        if not torch.isfinite(value).all():
            raise InputError(f"small head weights are not finite (e.g. {key})")
    temporary = directory / (SMALL_HEAD_WEIGHTS + ".tmp")
    save_file(tensors, str(temporary))
    os.replace(temporary, directory / SMALL_HEAD_WEIGHTS)
    config = {
        "kind": SMALL_HEAD_KIND,
        "format_version": SMALL_HEAD_FORMAT,
        "head": head.config(),
        "multiply_adds": head.multiply_adds(),
        "teacher_content_hash": str(teacher_hash),
        "weights_sha256": file_sha256(directory / SMALL_HEAD_WEIGHTS),
        "distillation": distillation or {},
        "agreement": agreement or {},
        "created": datetime.now(UTC).isoformat(timespec="seconds"),
    }
    write_json_atomic(directory / SMALL_HEAD_CONFIG, config)
    (directory / SMALL_HEAD_WEIGHTS).chmod(0o644)  # safetensors writes 0600
    return config


def small_head_config(bundle: ModelBundle) -> dict[str, Any] | None:
    """The sidecar config of ``bundle`` (unverified), or ``None`` when it has none."""
    if bundle.path is None or not (Path(bundle.path) / SMALL_HEAD_CONFIG).is_file():
        return None
    path = Path(bundle.path) / SMALL_HEAD_CONFIG
    return read_json_object(path, f"{SMALL_HEAD_CONFIG} of {bundle.name}")


def load_small_head(
    bundle: ModelBundle, device: str | torch.device = "cpu"
) -> tuple[SmallHead, dict[str, Any]]:
    """The verified small head of ``bundle`` (eval mode, on ``device``) and its config.

    Raises:
        InputError: the bundle has no small head, or its head was distilled from another
            bundle (teacher content hash ≠ the bundle's).
        ArtifactError: a damaged sidecar (hash mismatch, bad JSON, weights that do not fit).
    """
    if bundle.path is None:
        raise InputError(f"model {bundle.name!r} was not loaded from a directory: no small head")
    config, weights = verified_small_head(Path(bundle.path), bundle.name, bundle.content_hash)
    try:
        head = SmallHead.from_config(config["head"])
    except (KeyError, TypeError, ValueError) as exc:
        raise ArtifactError(f"{SMALL_HEAD_CONFIG} of {bundle.name} is inconsistent: {exc}") from exc
    network = bundle.network
    if head.width != network.width or head.output != network.output:
        raise ArtifactError(
            f"small head of {bundle.name} (width {head.width}, output {head.output!r}) does not "
            f"fit its network (width {network.width}, output {network.output!r})"
        )
    load_weights(head, weights, device)
    return head, config


__all__ = [
    "SMALL_HEAD_CONFIG",
    "SMALL_HEAD_FORMAT",
    "SMALL_HEAD_KIND",
    "SMALL_HEAD_WEIGHTS",
    "load_small_head",
    "save_small_head",
    "small_head_config",
]
