"""How well a T-Net aligns: angles on batches, the validation mean and the alignment report of a
run."""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

from litege_core.canonical import (
    POISSON_500_CLOUD,
    POISSON_BROKEN_MESH,
    PoissonScaleSetting,
    canonicalize_poisson,
)
from litege_core.nets import TNet, rotation_angle
from litege_core.sampling import poisson_disk_subsample, sample_surface
from litege_core.train.tnet.batches import ValidationSet
from litege_core.train.tnet.config import FAILURE_THRESHOLD, TNetReportConfig
from litege_core.train.tnet.shapes import ShapeSet
from litege_core.train.tnet.weights import predict_rotation
from litege_core.variants import broken_mesh


def device_of(net: torch.nn.Module) -> torch.device:
    return next(net.parameters()).device


@torch.no_grad()
def batch_angles(net: TNet, rotated: torch.Tensor, R_gt: torch.Tensor, chunk: int = 64) -> NDArray:
    """Angles (rad, float64 numpy) between the eval-mode prediction and ``R_gt``."""
    was_training = net.training
    net.eval()
    device = device_of(net)
    try:
        out = []
        for start in range(0, rotated.shape[0], chunk):
            R_pred = net.rotation(rotated[start : start + chunk].to(device))
            gt = R_gt[start : start + chunk].to(device, R_pred.dtype)
            out.append(rotation_angle(R_pred.double(), gt.double(), eps=0.0).cpu().numpy())
    finally:
        net.train(was_training)
    return np.concatenate(out)


def validate(net: TNet, val: ValidationSet) -> dict[str, float]:
    """Mean angle per input kind and over all items (``mean``)."""
    angles = {mode: batch_angles(net, b.rotated, b.R_gt) for mode, b in val.batches.items()}
    result = {mode: float(a.mean()) for mode, a in angles.items()}
    result["mean"] = float(np.concatenate(list(angles.values())).mean())
    return result


def angle_statistics(angles: ArrayLike, threshold: float = FAILURE_THRESHOLD) -> dict[str, Any]:
    """``n``, mean / std / median / p90 / p95 / max (rad) and the indices above ``threshold``."""
    values = np.asarray(angles, dtype=np.float64)
    failures = np.flatnonzero(values > threshold)
    return {
        "n": int(values.size),
        "mean": float(values.mean()),
        "std": float(values.std()),
        "median": float(np.median(values)),
        "p90": float(np.quantile(values, 0.9)),
        "p95": float(np.quantile(values, 0.95)),
        "max": float(values.max()),
        "threshold": float(threshold),
        "n_failures": int(failures.size),
        "failures": [int(i) for i in failures],
        "failure_angles": [float(values[i]) for i in failures],
    }


def _poisson_cloud(points: NDArray, setting: PoissonScaleSetting, seed: int) -> NDArray:
    """Centre and Poisson-scale a cloud as at inference (the subset itself when
    ``subset_is_cloud``: its own spacing, all of its points)."""
    n_poisson = points.shape[0] if setting.subset_is_cloud else setting.n_poisson
    transform = canonicalize_poisson(points, n_poisson, setting.target_mean_nn, seed)
    return transform.apply(points)


def _report_angles(
    net: TNet, shapes: ShapeSet, report: TNetReportConfig, salt: int, mode: str
) -> NDArray:
    """Angles of one input kind for every shape, with the reference rotations.

    The rotation of shape ``i`` is the ``i``-th of ``Rotation.random(len, default_rng(seed))``;
    ``mesh``: ``report.samples`` area-weighted samples of the unit-area mesh; ``cloud500``:
    500 samples of the rotated mesh scaled by Poisson spacing (§1.4, K=50); ``broken``:
    ``broken_fraction`` of the faces removed, ``n_cloud`` samples of the rest, their Poisson
    subset of about 7000 points is the cloud (§1.4),
    :func:`~litege_core.train.tnet.weights.predict_rotation` keeps 2000.
    """
    rotations = Rotation.random(
        len(shapes), random_state=np.random.default_rng(report.rotation_seed)
    ).as_matrix()
    angles = np.empty(len(shapes))
    for i, (verts, tris) in enumerate(zip(shapes.vertices, shapes.faces, strict=True)):
        rng = np.random.default_rng([report.rotation_seed, salt, i])
        R_gt = rotations[i]
        rotated_verts = verts @ R_gt.T
        if mode == "mesh":
            cloud = sample_surface(rotated_verts, tris, report.samples, rng).points
        elif mode == "cloud500":
            cloud = sample_surface(rotated_verts, tris, POISSON_500_CLOUD.n_cloud, rng).points
            cloud = _poisson_cloud(cloud, POISSON_500_CLOUD, int(rng.integers(2**31)))
        else:
            kept = tris[broken_mesh(tris, report.broken_fraction, rng)]
            dense = sample_surface(rotated_verts, kept, POISSON_BROKEN_MESH.n_cloud, rng).points
            subset = dense[poisson_disk_subsample(dense, POISSON_BROKEN_MESH.n_poisson, rng)]
            cloud = _poisson_cloud(subset, POISSON_BROKEN_MESH, 0)
        R_pred = predict_rotation(net, cloud)
        angles[i] = float(
            rotation_angle(torch.as_tensor(R_pred), torch.as_tensor(R_gt), eps=0.0).item()
        )
    return angles


def alignment_report(
    net: TNet, train_shapes: ShapeSet, val_shapes: ShapeSet, report: TNetReportConfig
) -> dict[str, Any]:
    """The alignment-error distributions of the module docstring (step 5)."""
    result: dict[str, Any] = {
        "units": "rad",
        "rotation_seed": report.rotation_seed,
        "samples": report.samples,
        "broken_fraction": report.broken_fraction,
    }
    threshold = report.failure_threshold
    train = angle_statistics(_report_angles(net, train_shapes, report, 0, "mesh"), threshold)
    train["failed_keys"] = [list(train_shapes.keys[i]) for i in train["failures"]]
    result["train"] = train
    for name, mode, salt in (
        ("val", "mesh", 1),
        ("val_cloud500", "cloud500", 2),
        ("val_broken", "broken", 3),
    ):
        result[name] = angle_statistics(
            _report_angles(net, val_shapes, report, salt, mode), threshold
        )
    result["failed_train_indices"] = train["failures"]
    return result


__all__ = [
    "alignment_report",
    "angle_statistics",
    "batch_angles",
    "device_of",
    "validate",
]
