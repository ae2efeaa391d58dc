import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from litege_core.errors import ArrayShapeError, EmptyShapeError, IndexOutOfRangeError
from litege_core.metrics import auc, geodesic_error, matching_errors, matching_report


def _auc_reference(errors, max_threshold, n=40):
    """Loop-based trapezoid integration of the recall curve (the spec's definition)."""
    thresholds = [max_threshold * i / (n - 1) for i in range(n)]
    recall = [sum(1 for e in errors if e <= t) / len(errors) for t in thresholds]
    area = sum(
        (thresholds[i + 1] - thresholds[i]) * (recall[i] + recall[i + 1]) / 2 for i in range(n - 1)
    )
    return area / max_threshold * 100


@settings(max_examples=60, deadline=None)
@given(
    arrays(np.float64, st.integers(1, 50), elements=st.floats(0, 0.5)),
    st.sampled_from([0.1, 0.2]),
)
def test_auc_matches_loop_reference(errors, max_threshold):
    assert auc(errors, max_threshold) == pytest.approx(_auc_reference(list(errors), max_threshold))


def test_auc_extremes():
    assert auc(np.zeros(10), 0.1) == pytest.approx(100.0)
    assert auc(np.full(10, 1.0), 0.1) == pytest.approx(0.0)
    # Errors spread uniformly over [0, T] give a recall line: AUC close to 50.
    assert auc(np.linspace(0, 0.2, 100001), 0.2) == pytest.approx(50.0, abs=0.1)


def test_geodesic_error_normalizes_to_mean_100():
    gt = np.array([1.0, 2.0, 3.0])
    report = geodesic_error(gt + 0.2, gt)
    assert report.gt_mean == pytest.approx(2.0)
    assert report.mean == pytest.approx(10.0)
    assert report.median == pytest.approx(10.0)
    assert report.n_pairs == 3


def test_geodesic_error_is_scale_invariant_and_skips_unreachable():
    rng = np.random.default_rng(0)
    gt = rng.uniform(0.1, 2.0, 1000)
    pred = gt + rng.normal(0, 0.05, 1000)
    a = geodesic_error(pred, gt)
    b = geodesic_error(pred * 7.0, gt * 7.0)
    assert a.mean == pytest.approx(b.mean) and a.median == pytest.approx(b.median)
    gt_inf = np.append(gt, np.inf)
    assert geodesic_error(np.append(pred, 5.0), gt_inf).mean == pytest.approx(a.mean)


def test_geodesic_error_explicit_normalization():
    gt = np.array([1.0, 3.0])
    assert geodesic_error(gt + 1.0, gt, gt_mean=4.0).mean == pytest.approx(25.0)


@pytest.mark.parametrize(
    ("pred", "gt", "error"),
    [
        (np.ones(3), np.ones(4), ArrayShapeError),
        (np.ones(2), np.array([np.inf, np.nan]), EmptyShapeError),
        (np.array([np.nan, 1.0]), np.ones(2), ArrayShapeError),
        (np.ones(2), np.zeros(2), ArrayShapeError),
    ],
)
def test_geodesic_error_rejects_bad_input(pred, gt, error):
    with pytest.raises(error):
        geodesic_error(pred, gt)


def test_matching_errors_gathers_rows():
    rows = np.array([[0.0, 0.3, 0.5], [0.2, 0.0, 0.1]])
    np.testing.assert_allclose(matching_errors(rows, np.array([2, 1])), [0.5, 0.0])
    report = matching_report(matching_errors(rows, np.array([0, 1])), 0.1)
    assert report.mean == 0.0 and report.auc == pytest.approx(100.0) and report.n_matches == 2


def test_matching_errors_rejects_bad_indices():
    rows = np.zeros((2, 3))
    with pytest.raises(IndexOutOfRangeError):
        matching_errors(rows, np.array([0, 3]))
    with pytest.raises(ArrayShapeError):
        matching_errors(rows, np.array([0.0, 1.0]))
    with pytest.raises(ArrayShapeError):
        matching_errors(rows, np.array([0]))
    with pytest.raises(EmptyShapeError):
        matching_report(np.array([]), 0.1)


def test_ranking_auc_ranks_positives_above_negatives() -> None:
    from litege_core.metrics import ranking_auc

    positive = np.array([True, True, False, False])
    assert ranking_auc(np.array([3.0, 4.0, 1.0, 2.0]), positive) == 1.0
    assert ranking_auc(np.array([1.0, 2.0, 3.0, 4.0]), positive) == 0.0
    assert ranking_auc(np.ones(4), positive) == 0.5  # ties: half
    assert ranking_auc(np.array([1.0, 3.0, 2.0, 4.0]), positive) == 0.25
    assert np.isnan(ranking_auc(np.ones(4), np.zeros(4, bool)))
