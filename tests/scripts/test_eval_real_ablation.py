"""scripts/eval_real_ablation.py: the model options a row is named by."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest

from litege_core.evaluation.geodesic import frame_turns

REPO = Path(__file__).resolve().parents[2]


def _load_script():
    spec = importlib.util.spec_from_file_location(
        "litege_eval_real_ablation", REPO / "scripts/eval_real_ablation.py"
    )
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


ablation = _load_script()


def test_tta_option_names_the_frame_turns():
    assert ablation.frame_turns_of("quadrupeds") is None
    assert ablation.frame_turns_of("quadrupeds@fullhead+full") is None
    np.testing.assert_array_equal(ablation.frame_turns_of("humans@tta4"), frame_turns(4, 10.0))
    np.testing.assert_array_equal(
        ablation.frame_turns_of("out/b@fullhead+tta2x15"), frame_turns(2, 15.0)
    )


def test_load_predictor_reads_the_other_options_beside_tta():
    predictor = ablation.load_predictor("quadrupeds@fullhead+full+tta4")
    assert predictor.head == "full" and predictor.descriptor_lattice == "full"
    with pytest.raises(SystemExit, match="unknown model options"):
        ablation.load_predictor("quadrupeds@tta")
