"""scripts/refine_gate.py: its generated pair sets, the checked error and the report."""

from __future__ import annotations

import json

import numpy as np
import pytest

from tests.scripts.conftest import load_script


@pytest.fixture(scope="module")
def refine_gate():
    return load_script("refine_gate")


def _record(pair_set: str, spectral: float, registered: float, ratio: float) -> dict:
    return {
        "model": "humans",
        "set": pair_set,
        "seed": 0,
        "error_spectral": spectral,
        "error_registered": registered,
        "distortion_spectral": 0.02,
        "distortion_registered": 0.02 * ratio,
    }


def test_checked_error_keeps_the_smoothed_map_within_the_tolerance(refine_gate) -> None:
    record = _record("one-body", 1.0, 3.0, 1.2)
    assert refine_gate.gated_error(record, 1.1) == 1.0  # distorts 1.2× the spectral: refused
    assert refine_gate.gated_error(record, 1.3) == 3.0


def test_report_tables_each_pair_set_and_all(refine_gate, tmp_path) -> None:
    records = [
        _record("families", 3.0, 2.0, 1.05),
        _record("one-body", 1.0, 3.0, 1.2),
    ]
    path = tmp_path / "gate.jsonl"
    path.write_text("".join(json.dumps(r) + "\n" for r in records))
    table = refine_gate.report([path]).splitlines()
    assert len(table) == 2 + 3  # header, rule, two sets and all
    all_row = [c.strip() for c in table[-1].strip("|").split("|")]
    assert all_row[:5] == ["humans", "all (seeds 0)", "2", "2.00", "2.50"]
    tolerances = dict(zip(refine_gate.TOLERANCES, all_row[5:-1], strict=True))
    assert tolerances[1.0] == "2.00" and tolerances[1.1] == "1.50" and all_row[-1] == "1.50"


def _edge_change(x, y) -> float:
    """Mean relative change of the template mesh's edge lengths from x to y."""
    edges = np.concatenate([x.faces[:, [0, 1]], x.faces[:, [1, 2]], x.faces[:, [2, 0]]])
    lx = np.linalg.norm(x.vertices[edges[:, 0]] - x.vertices[edges[:, 1]], axis=1)
    ly = np.linalg.norm(y.vertices[edges[:, 0]] - y.vertices[edges[:, 1]], axis=1)
    return float(np.mean(np.abs(ly - lx) / lx))


def test_one_body_pairs_are_nearer_isometric_than_two_bodies(refine_gate) -> None:
    (two_bodies,) = refine_gate.generated_pairs("biped", "same-family", 1, seed=0)
    (one_body,) = refine_gate.generated_pairs("biped", "one-body", 1, seed=0)
    for x, y in (two_bodies, one_body):
        assert x.family == y.family and x.seed != y.seed
        assert not np.allclose(x.vertices, y.vertices)  # another pose
    assert _edge_change(*one_body) < _edge_change(*two_bodies)  # the pose alone changes less
