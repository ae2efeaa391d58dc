"""A T-Net fine-tuned on a user's collection, kept in its own canonical convention.

A shipped T-Net orients the shapes of its training families; a user's characters (a rigged
human of another mesh, a scanned pet) can lie outside them, and then its turned runs disagree:
on the CesiumMan rig's walking poses the ``humans`` T-Net brings only about a third of random
rotations to one frame (BENCHMARKS.md ``rig-matching``), so matching fails whatever the
matching network learns. :func:`tune_tnet_on_collection` fine-tunes it on the collection:

1. **Target frame.** The collection's shapes share one stored frame, but that is the user's
   convention (a glTF: y up, facing +z), not the T-Net's. The target is the frame the T-Net
   already agrees on (:func:`~litege_core.train.matching_data.stored_frame_offset`: the
   consensus ``C`` of its frames over randomly turned shapes), so fine-tuning sharpens what it
   knows instead of teaching it a new convention: shape ``s`` in the canonical frame is
   ``vertices_s @ Cᵀ`` (then centred and scaled to unit area, :func:`canonical_shape_set`).
2. **Training** (:func:`~litege_core.train.tnet.training.train_tnet`): from the T-Net of the
   ``init`` matching bundle (its widths), the reference loss and augmentations, ``lr`` 1e-4
   down to 1e-6, for ``steps`` or as many as ``minutes`` allow; the best validation weights.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from litege_core.train.tnet.config import TNetTrainConfig
from litege_core.train.tnet.shapes import canonical_shape_set
from litege_core.train.tnet.training import train_tnet
from litege_core.train.tnet.weights import save_tnet

LOG = logging.getLogger("litege.train.tnet")

TUNE_LR = 1e-4
"""Peak learning rate of a fine-tune (the shipped T-Nets were trained from 1e-3)."""


def tune_tnet_on_collection(
    init: str,
    train: dict[str, NDArray],
    val: dict[str, NDArray],
    faces: NDArray,
    out: str | Path,
    *,
    steps: int,
    minutes: float = 0.0,
    seed: int = 0,
) -> dict[str, Any]:
    """Fine-tune the T-Net of matching bundle ``init`` on a collection's shapes (module doc)
    and write it to ``out`` (a T-Net weights file).

    Args:
        init: a matching bundle (shipped name or directory) whose T-Net is tuned.
        train, val: dataset splits (``vertices (S, V, 3)`` in the stored frame, ``seed (S,)``).
        faces: ``(F, 3)`` their shared triangulation.
        out: the weights file written.
        steps: optimizer steps (at most, with ``minutes``).
        minutes: when positive, the steps that fit this many minutes at the measured rate.
        seed: batches and the consensus frame's turns.

    Returns:
        What was measured: the consensus frame's share of agreeing turns before and after
        (``agreement_before``, ``agreement_after``), the validation angles, steps and seconds.
    """
    from litege_core.matching.bundle import load_matching_bundle, resolve_matching_bundle
    from litege_core.train.matching_data import stored_frame_offset

    directory = resolve_matching_bundle(init)
    bundle = load_matching_bundle(directory)
    tnet, pipeline = bundle.tnet.cpu().eval(), bundle.pipeline
    offset, before = stored_frame_offset(train, faces, tnet, pipeline, seed=seed)
    shapes = [
        canonical_shape_set([(np.asarray(v, np.float64) @ offset.T, faces) for v in split])
        for split in (train["vertices"], val["vertices"])
    ]
    config = TNetTrainConfig.from_dict(
        {
            "data": {"n_train": len(shapes[0]), "n_val": len(shapes[1])},
            "network": tnet.config(),
            "train": {
                "init": str(directory),
                "steps": steps,
                "time_budget_minutes": minutes,
                "lr": TUNE_LR,
                "eta_min": TUNE_LR / 100,
                "val_every": max(10, steps // 10),
                "log_every": max(10, steps // 20),
                "seed": seed,
            },
            "output": {"dir": str(Path(out).parent)},
        }
    )
    result = train_tnet(
        config, train_shapes=shapes[0], val_shapes=shapes[1], weights_path=out, make_report=False
    )
    _, after = stored_frame_offset(train, faces, result.net, pipeline, seed=seed)
    summary = {
        "init": str(directory),
        "agreement_before": before,
        "agreement_after": after,
        "best_val": result.best_val,
        "best_step": result.best_step,
        "steps": result.steps,
        "seconds": round(result.seconds, 1),
    }
    save_tnet(result.net, out, summary)
    LOG.info(
        "T-Net tuned on the collection: %d steps in %.0f s; turns agreeing %.0f %% → %.0f %%",
        result.steps,
        result.seconds,
        100 * before,
        100 * after,
    )
    return summary


__all__ = ["TUNE_LR", "tune_tnet_on_collection"]
