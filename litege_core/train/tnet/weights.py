"""T-Net weights files (safetensors with the network config and a training summary), warm starts,
and one cloud's predicted rotation."""

from __future__ import annotations

import json
import logging
import os
from pathlib import Path
from typing import Any

import numpy as np
import torch
from numpy.typing import ArrayLike, NDArray
from safetensors import SafetensorError, safe_open
from safetensors.torch import save_file

from litege_core.errors import ArtifactError, InputError
from litege_core.nets import TNet, load_state, state_to_tensors
from litege_core.sampling import as_points

LOG = logging.getLogger("litege.train.tnet")

TNET_FORMAT = "litege-tnet"
"""``format`` entry of the safetensors metadata of a T-Net weights file."""

PREDICT_MAX_POINTS = 2000
""":func:`predict_rotation` feeds at most this many points (the authors' training count)."""


def save_tnet(net: TNet, path: str | Path, training: dict[str, Any] | None = None) -> None:
    """Weights (:func:`state_to_tensors`) + config in the metadata, written atomically."""
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    temporary = target.with_name(f"{target.name}.tmp-{os.getpid()}")
    metadata = {
        "format": TNET_FORMAT,
        "config": json.dumps(net.config(), sort_keys=True),
        "training": json.dumps(training or {}, sort_keys=True),
    }
    try:
        save_file(state_to_tensors(net), str(temporary), metadata=metadata)
        os.replace(temporary, target)
    finally:
        if temporary.exists():
            temporary.unlink()


def read_tnet_metadata(path: str | Path) -> dict[str, Any]:
    """``{"config": …, "training": …}`` of a weights file written by :func:`save_tnet`."""
    return _read(path)[1]


def _read(path: str | Path) -> tuple[dict[str, torch.Tensor], dict[str, Any]]:
    try:
        with safe_open(str(path), framework="pt") as handle:
            metadata = handle.metadata() or {}
            tensors = {name: handle.get_tensor(name) for name in handle.keys()}  # noqa: SIM118
    except (OSError, SafetensorError, ValueError) as exc:
        raise ArtifactError(f"cannot read T-Net weights {path}: {exc}") from exc
    if metadata.get("format") != TNET_FORMAT or "config" not in metadata:
        raise ArtifactError(f"{path} is not a LiteGE T-Net weights file")
    try:
        info = {
            "config": json.loads(metadata["config"]),
            "training": json.loads(metadata.get("training", "{}")),
        }
    except ValueError as exc:
        raise ArtifactError(f"{path}: T-Net metadata is not valid JSON: {exc}") from exc
    return tensors, info


def start_from(net: TNet, init: str | Path) -> None:
    """Load into ``net`` the weights of ``init`` (see
    :class:`~litege_core.train.tnet.config.TNetOptimConfig`'s ``init``).

    Raises:
        InputError: ``init`` names no weights file or matching bundle, or its T-Net's widths or
            pre-alignment differ from ``net``'s.
        ArtifactError: a damaged weights file or bundle.
    """
    from litege_core.matching.bundle import load_matching_bundle, resolve_matching_bundle

    path = Path(init)
    if path.is_file():
        source = load_tnet(path)
    else:
        source = load_matching_bundle(resolve_matching_bundle(str(init))).tnet
    if source.config() != net.config():
        raise InputError(
            f"train.init {str(init)!r} is a T-Net {source.config()}, the config asks for "
            f"{net.config()}: set [network] to match it"
        )
    load_state(net, state_to_tensors(source))
    LOG.info("started from the T-Net of %s", init)


def load_tnet(path: str | Path, device: str | torch.device = "cpu") -> TNet:
    """The T-Net of a weights file, on ``device``, in eval mode (ArtifactError if damaged)."""
    tensors, info = _read(path)
    try:
        net = TNet.from_config(info["config"])
    except InputError as exc:
        raise ArtifactError(f"{path}: bad T-Net config: {exc}") from exc
    load_state(net, tensors)
    return net.to(device).eval()


@torch.no_grad()
def predict_rotation(net: TNet, points: ArrayLike) -> NDArray:
    """``R_pred`` ``(3, 3)`` float64 for one cloud; align it with ``points @ R_pred``.

    ``points`` ``(N, 3)`` must be scale-normalized (unit-area mesh samples or a Poisson-scaled
    cloud, spec §1.3–§1.4). Clouds of more than :data:`PREDICT_MAX_POINTS` points are subsampled
    deterministically (``default_rng(0)``, without replacement); the subset is centred on its
    own mean (as in training: a translation does not change the rotation). Runs in eval mode.
    """
    cloud = as_points(points)
    if cloud.shape[0] > PREDICT_MAX_POINTS:
        keep = np.random.default_rng(0).choice(cloud.shape[0], PREDICT_MAX_POINTS, replace=False)
        cloud = cloud[np.sort(keep)]
    cloud = cloud - cloud.mean(axis=0)
    reference = next(net.parameters())
    was_training = net.training
    net.eval()
    try:
        tensor = torch.as_tensor(cloud, dtype=reference.dtype, device=reference.device)
        R_pred = net.rotation(tensor[None])[0]
    finally:
        net.train(was_training)
    return R_pred.double().cpu().numpy()


__all__ = [
    "PREDICT_MAX_POINTS",
    "TNET_FORMAT",
    "load_tnet",
    "predict_rotation",
    "read_tnet_metadata",
    "save_tnet",
    "start_from",
]
