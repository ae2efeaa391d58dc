"""A whole geodesic training run as one function (:func:`run_training`), the library side of
``litege train geodesic`` (the sub-commands live in :mod:`litege_core.cli.train`)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from litege_core.train.config import TrainConfig


def run_training(
    config: TrainConfig,
    resume: str | Path | None = None,
    out: str | Path | None = None,
    init: str | Path | None = None,
    time_budget_s: float | None = None,
) -> dict[str, Any]:
    """Train (or resume) per ``config`` and export the bundle; returns the bundle manifest.

    Args:
        config: the run configuration.
        resume: a ``checkpoints/last.safetensors`` of an earlier run of the same config.
        out: overrides ``output.dir``.
        init: warm start from a shipped model name or a bundle directory.
        time_budget_s: wall-clock budget of the training in seconds (the best checkpoint
            is exported when it runs out; resumable for more epochs).
    """
    from litege_core.train.pipeline import train_geodesic

    if out is not None:
        config = config.replace(output={"dir": str(out)})
    result = train_geodesic(config, resume=resume, init=init, time_budget_s=time_budget_s)
    if result.manifest is None:  # pragma: no cover - a full run always finishes
        raise RuntimeError("training ended without exporting a bundle")
    return result.manifest


__all__ = ["run_training"]
