"""scripts/train_shortcut_scorer.py: the kept-edge cache it reads and the scores it reports."""

from __future__ import annotations

import argparse

import numpy as np

from litege_core.evaluation.cloud_edges import kept_edges
from litege_core.learned.shortcuts import ScorerWeights
from tests.litege_core.learned.conftest import scorer_state
from tests.scripts.conftest import load_script


def test_kept_edges_are_cached_and_scored(toy_fusion, tmp_path, monkeypatch) -> None:
    script = load_script("train_shortcut_scorer")
    _, predictor, shape = toy_fusion
    calls = []

    def collect(key, settings, **options):
        calls.append((key, tuple(settings), options["seed"]))
        return {settings[0]: [kept_edges(predictor, shape, settings[0], seed=options["seed"])]}

    monkeypatch.setattr(script, "collect_kept_edges", collect)
    args = argparse.Namespace(
        edges_cache=str(tmp_path), sources=12, eval_root="", cache=None, limit=None, stretch=3.0
    )
    first = script.kept_edges_of("data/x@toy", "cloud_200", 1, args)
    again = script.kept_edges_of("data/x@toy", "cloud_200", 1, args)
    assert calls == [("data/x@toy", ("cloud_200",), 1)]  # the second read is the cache's
    np.testing.assert_array_equal(first[0].i, again[0].i)
    assert [p.name for p in tmp_path.iterdir()] == ["data_x_toy-cloud_200-1-12.pkl"]
    scores = script.scores_of(ScorerWeights.from_state(scorer_state(width=8)), first[0])
    assert scores.shape == first[0].i.shape and np.all((scores > 0) & (scores < 1))
