"""Evaluation metrics of the paper's protocols (reference-spec §5.4 and §7.1).

* Geodesic-distance error: absolute error with the ground truth rescaled so its mean is 100,
  normalized by the mean of the *evaluated* ground truth (the authors divided by the training
  mean; we record which normalization was used). Reported as mean and median.
* Matching error: the geodesic distance, on the target shape scaled to unit area, between the
  predicted and the true point, ×100.
* AUC: recall at ``n_thresholds`` thresholds ``linspace(0, max_threshold)``, integrated by the
  trapezoid rule, divided by ``max_threshold``, ×100 (0.1 for template pairs, 0.2 otherwise).
* Ranking AUC (the diagnoses' detectors, not the paper's): the area under the ROC curve of a
  score that should rank positives first.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from litege_core.errors import ArrayShapeError, EmptyShapeError, IndexOutOfRangeError

AUC_THRESHOLDS = 40


class GeodesicErrorReport(NamedTuple):
    """Geodesic regression error with ground truth rescaled to mean 100.

    Attributes:
        mean: mean absolute error (ground-truth mean = 100).
        median: median absolute error (same scale).
        gt_mean: the ground-truth mean used for normalization, in input units.
        n_pairs: number of evaluated (source, target) pairs.
    """

    mean: float
    median: float
    gt_mean: float
    n_pairs: int


class MatchingReport(NamedTuple):
    """Matching accuracy: errors ×100 on the unit-area target, and AUC ×100."""

    mean: float
    median: float
    auc: float
    auc_max_threshold: float
    n_matches: int


def _finite_pairs(predicted: ArrayLike, ground_truth: ArrayLike) -> tuple[NDArray, NDArray]:
    pred = np.asarray(predicted, dtype=np.float64).ravel()
    gt = np.asarray(ground_truth, dtype=np.float64).ravel()
    if pred.shape != gt.shape:
        raise ArrayShapeError(
            f"predicted and ground truth differ in size: {pred.size} vs {gt.size}"
        )
    keep = np.isfinite(gt)
    if not keep.any():
        raise EmptyShapeError("no finite ground-truth distances to evaluate")
    if not np.isfinite(pred[keep]).all():
        raise ArrayShapeError("predicted distances contain NaN or inf")
    return pred[keep], gt[keep]


def geodesic_error(
    predicted: ArrayLike, ground_truth: ArrayLike, gt_mean: float | None = None
) -> GeodesicErrorReport:
    """Absolute geodesic error with the ground truth rescaled to mean 100.

    Args:
        predicted: any shape, distances in the same units as ``ground_truth``.
        ground_truth: same size; non-finite entries (unreachable pairs) are skipped.
        gt_mean: normalization constant; default the mean of the evaluated ground truth.
    """
    pred, gt = _finite_pairs(predicted, ground_truth)
    norm = float(gt.mean()) if gt_mean is None else float(gt_mean)
    if not norm > 0:
        raise ArrayShapeError(f"ground-truth mean must be positive, got {norm}")
    errors = np.abs(pred - gt) * (100.0 / norm)
    return GeodesicErrorReport(float(errors.mean()), float(np.median(errors)), norm, gt.size)


def auc(errors: ArrayLike, max_threshold: float, n_thresholds: int = AUC_THRESHOLDS) -> float:
    """Area under the recall curve of ``errors`` over ``linspace(0, max_threshold, n)``, ×100.

    Recall(t) is the fraction of errors ≤ t; trapezoid rule, divided by ``max_threshold``.
    """
    values = np.sort(np.asarray(errors, dtype=np.float64).ravel())
    if values.size == 0:
        raise EmptyShapeError("no errors to evaluate")
    if not max_threshold > 0 or n_thresholds < 2:
        raise ArrayShapeError("need max_threshold > 0 and at least 2 thresholds")
    thresholds = np.linspace(0.0, max_threshold, n_thresholds)
    recall = np.searchsorted(values, thresholds, side="right") / values.size
    return float(np.trapezoid(recall, thresholds) / max_threshold * 100.0)


def matching_errors(gt_distance_rows: ArrayLike, predicted: ArrayLike) -> NDArray:
    """Per-match geodesic errors from a table of ground-truth distances on the target.

    Args:
        gt_distance_rows: ``(Q, N)``: row q holds the geodesic distances on the target shape
            (unit area) from the *true* match of query q to every target vertex.
        predicted: ``(Q,)`` predicted target vertex indices.

    Returns:
        ``(Q,)`` errors in unit-area units (multiply by 100 for the reported figure).
    """
    rows = np.asarray(gt_distance_rows, dtype=np.float64)
    index = np.asarray(predicted)
    if rows.ndim != 2 or index.shape != (rows.shape[0],):
        raise ArrayShapeError(
            f"need rows (Q, N) and predictions (Q,), got {rows.shape} and {index.shape}"
        )
    if not np.issubdtype(index.dtype, np.integer):
        raise ArrayShapeError("predicted indices must be integers")
    if index.size and (index.min() < 0 or index.max() >= rows.shape[1]):
        raise IndexOutOfRangeError(f"predicted index outside [0, {rows.shape[1]})")
    return rows[np.arange(rows.shape[0]), index]


def matching_report(errors: ArrayLike, max_threshold: float) -> MatchingReport:
    """Summarize per-match errors (unit-area units) as ×100 mean/median and AUC×100."""
    values = np.asarray(errors, dtype=np.float64).ravel()
    if values.size == 0:
        raise EmptyShapeError("no matches to evaluate")
    return MatchingReport(
        mean=float(values.mean() * 100.0),
        median=float(np.median(values) * 100.0),
        auc=auc(values, max_threshold),
        auc_max_threshold=float(max_threshold),
        n_matches=int(values.size),
    )


def ranking_auc(scores: ArrayLike, positive: ArrayLike) -> float:
    """The probability that a random positive scores above a random negative (ties: half), the
    area under the ROC curve; ``nan`` without positives or without negatives.

    Args:
        scores: ``(E,)`` the scores; positive: ``(E,)`` bool, the labels.
    """
    from scipy.stats import rankdata

    values, labels = np.asarray(scores, dtype=np.float64), np.asarray(positive, dtype=bool)
    n_pos, n_neg = int(labels.sum()), int((~labels).sum())
    if n_pos == 0 or n_neg == 0:
        return float("nan")
    ranks = rankdata(values)
    return float((ranks[labels].sum() - n_pos * (n_pos + 1) / 2) / (n_pos * n_neg))


__all__ = [
    "AUC_THRESHOLDS",
    "GeodesicErrorReport",
    "MatchingReport",
    "auc",
    "geodesic_error",
    "matching_errors",
    "matching_report",
    "ranking_auc",
]
