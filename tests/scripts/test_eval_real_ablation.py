"""scripts/eval_real_eval_real_ablation.py: the model options a row is named by."""

from __future__ import annotations

import numpy as np
import pytest

from litege_core.evaluation.geodesic import frame_turns


def test_tta_option_names_the_frame_turns(eval_real_ablation):
    assert eval_real_ablation.frame_turns_of("quadrupeds") is None
    assert eval_real_ablation.frame_turns_of("quadrupeds@fullhead+full") is None
    np.testing.assert_array_equal(
        eval_real_ablation.frame_turns_of("humans@tta4"), frame_turns(4, 10.0)
    )
    np.testing.assert_array_equal(
        eval_real_ablation.frame_turns_of("out/b@fullhead+tta2x15"), frame_turns(2, 15.0)
    )


def test_sign_flip_options_turn_the_pca_axes(eval_real_ablation):
    flip = eval_real_ablation.frame_turns_of("humans@fusion+ttaflip")
    np.testing.assert_array_equal(flip, np.stack([np.eye(3), np.diag([1.0, -1.0, -1.0])]))
    signs = eval_real_ablation.frame_turns_of("humans@ttasigns")
    assert signs.shape == (4, 3, 3)
    np.testing.assert_array_equal(signs[0], np.eye(3))
    for turn in signs:  # proper sign flips: ±1 on the diagonal, determinant 1
        np.testing.assert_array_equal(np.abs(turn), np.eye(3))
        assert np.linalg.det(turn) == pytest.approx(1.0)
    predictor = eval_real_ablation.load_predictor("humans@fusion+ttaflip")
    assert predictor.fusion is not None


def test_load_predictor_reads_the_other_options_beside_tta(eval_real_ablation):
    predictor = eval_real_ablation.load_predictor("quadrupeds@fullhead+full+tta4")
    assert predictor.head == "full" and predictor.descriptor_lattice == "full"
    assert predictor.embed_precision == "float32"
    int8 = eval_real_ablation.load_predictor("quadrupeds@int8")
    assert (int8.precision, int8.embed_precision) == ("int8", "int8")
    with pytest.raises(SystemExit, match="unknown model options"):
        eval_real_ablation.load_predictor("quadrupeds@tta")


def test_per_shape_table_sorts_by_the_first_model(eval_real_ablation):
    table = eval_real_ablation.per_shape_table(
        ["cat0", "cat1", "dog0"], {"old": [3.0, 9.5, 5.25], "new": [2.0, 4.0, 6.0]}
    )
    lines = table.strip().splitlines()
    assert lines[0] == "| shape (mesh) | old | new |"
    assert lines[2:] == [
        "| cat1 | 9.50 | 4.00 |",
        "| dog0 | 5.25 | 6.00 |",
        "| cat0 | 3.00 | 2.00 |",
    ]


def test_the_per_shape_table_names_its_setting(eval_real_ablation):
    table = eval_real_ablation.per_shape_table(["cat0"], {"old": [3.0]}, "cloud_300")
    assert table.strip().splitlines()[0] == "| shape (cloud_300) | old |"
