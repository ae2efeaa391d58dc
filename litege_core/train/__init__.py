"""Training of the geodesic-regression network (reference-spec §3, issue 4 "Model and training").

* :mod:`~litege_core.train.config` — :class:`TrainConfig` from TOML (:func:`load_config`).
* :mod:`~litege_core.train.augment` — clean and augmented views of a shape.
* :mod:`~litege_core.train.data` — view tables built once, vectorized pair batches, fixed
  validation pairs.
* :mod:`~litege_core.train.basis` — the run's UDF-PCA basis (loaded or fitted).
* :mod:`~litege_core.train.trainer` — loop, validation, checkpoints, exact resume.
* :mod:`~litege_core.train.pipeline` — a whole run and the bundle export.
* :mod:`~litege_core.train.command` — ``litege train geodesic``.

Importing this package (or :mod:`~litege_core.train.command`, for the CLI) does not import
torch; the training modules load on first use.
"""

from __future__ import annotations

import importlib
from typing import Any

from litege_core.train.command import run_training
from litege_core.train.config import TrainConfig, load_config

_LAZY = {
    "RunResult": "litege_core.train.pipeline",
    "prepare_run": "litege_core.train.pipeline",
    "train_geodesic": "litege_core.train.pipeline",
}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = [
    "RunResult",
    "TrainConfig",
    "load_config",
    "prepare_run",
    "run_training",
    "train_geodesic",
]
