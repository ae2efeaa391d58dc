"""scripts/frame_agreement.py: the agreement score of candidate frames."""

from __future__ import annotations

import numpy as np

from tests.scripts.conftest import load_script

frame_agreement = load_script("frame_agreement")


def _reference(seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).uniform(0.1, 2.0, size=(6, 40))


def test_the_frame_whose_rows_follow_the_reference_up_to_scale_scores_lowest():
    reference = _reference()
    noise = np.random.default_rng(1).normal(0.0, 0.3, size=reference.shape)
    predictions = np.stack(
        [
            reference * np.exp(noise),  # the default frame: scattered around the reference
            0.8 * reference,  # a frame that follows the reference, 20 % short throughout
            reference[:, ::-1],  # a frame that answers other pairs
        ]
    )
    scores = frame_agreement.agreement_scores(predictions, np.ones(3), reference)
    assert int(np.argmin(scores)) == 1
    assert scores[1] < scores[0] and scores[1] < scores[2]


def test_the_residual_breaks_an_agreement_tie():
    reference = _reference(2)
    predictions = np.stack([1.1 * reference * np.exp(0.01 * np.sin(np.arange(40)))] * 2)
    scores = frame_agreement.agreement_scores(predictions, np.array([2.0, 1.0]), reference)
    assert scores[1] < scores[0]
    assert np.isclose(scores[0] - scores[1], np.log(2.0))


def test_pairs_without_a_finite_reference_are_left_out():
    reference = _reference(3)
    scattered = reference * np.exp(np.random.default_rng(4).normal(0.0, 0.3, reference.shape))
    holed = reference.copy()
    holed[0, :5] = np.inf  # unreachable in the graph
    holed[1, 0] = 0.0  # the source itself
    predictions = np.stack([reference, scattered])
    scores = frame_agreement.agreement_scores(predictions, np.ones(2), holed)
    assert np.all(np.isfinite(scores))
    assert scores[0] < scores[1]


def test_error_sums_skip_the_sources_own_zero():
    gt = np.array([[0.0, 1.0, 2.0]])
    pred = np.array([[5.0, 1.5, 1.0]])
    assert np.allclose(frame_agreement.error_sums(pred, gt), [1.5, 3.0])


def test_turn_labels_name_the_axes_each_frame_puts_first():
    assert frame_agreement.turn_label(np.eye(3)) == "+x +y +z"
    quarter = np.array([[1, 0, 0], [0, 0, -1], [0, 1, 0]])
    assert frame_agreement.turn_label(quarter) == "+x −z +y"


def test_per_frame_rows_pool_errors_and_count_each_shapes_best_frame():
    rotations = np.stack(frame_agreement.candidate_rotations("all"))
    sums = np.zeros((3, len(rotations), 2))
    sums[:, :, 1] = 100.0
    sums[:, :, 0] = 20.0  # every frame errs by 20 ...
    sums[0, 0, 0] = sums[1, 0, 0] = 5.0  # ... but the first two shapes err least unturned
    sums[2, 12, 0] = 1.0  # and the third in a frame that moves the first axis
    rows = frame_agreement.per_frame_rows("toy", "cloud_300", sums, rotations)
    frames = [int(row.split(" | ")[2]) for row in rows]
    assert frames == [0, 1, 2, 3, 4, 5, 6, 7, 12]
    first = rows[0].split(" | ")
    assert first[3] == "+x +y +z" and float(first[4]) == 10.0 and first[5] == "2 |"  # 30/300
    assert rows[1].endswith("| 0 |") and float(rows[1].split(" | ")[4]) == 20.0
    assert rows[-1].endswith("| 1 |") and float(rows[-1].split(" | ")[4]) == 13.67  # 41/300
