"""scripts/zoomout_floor.py: its settings grid and its re-ranking of spectral candidates."""

from __future__ import annotations

import numpy as np
import pytest

from tests.scripts.conftest import load_script


@pytest.fixture(scope="module")
def zoomout_floor():
    return load_script("zoomout_floor")


def test_grid_entries_are_refinement_settings(zoomout_floor) -> None:
    grid = zoomout_floor.parse_grid("20:100,50:150:2,20:100:5:0")
    assert [(s.k_init, s.n_eigen, s.step) for s in grid] == [
        (20, 100, 5),
        (50, 150, 2),
        (20, 100, 5),
    ]
    assert grid[0].smoothing == grid[1].smoothing > 0 and grid[2].smoothing == 0
    assert grid[0].registration_rounds > 0 and grid[0].registration_anchor > 0
    (fit_only, tied) = zoomout_floor.parse_grid("20:100:5:3e-6:0,20:100:5:1e-5:4:0.1")
    assert fit_only.smoothing == 3e-6 and fit_only.registration_rounds == 0
    assert (tied.smoothing, tied.registration_rounds, tied.registration_anchor) == (1e-5, 4, 0.1)
    for bad in ("20", "20:100:5:0:0:0:0"):
        with pytest.raises(SystemExit, match="k_init:n_eigen"):
            zoomout_floor.parse_grid(bad)
    assert zoomout_floor.parse_list("", int) == [] and zoomout_floor.parse_list("1,2", float) == [
        1.0,
        2.0,
    ]


def test_rerank_follows_the_network_alone_or_the_blend(zoomout_floor) -> None:
    spectral = np.array([[0.1, 0.2, 0.9], [0.1, 0.5, 0.2]])
    network = np.array([[5.0, 1.0, 0.5], [1.0, 1.0, 9.0]])
    assert zoomout_floor.rerank(spectral, network, None).tolist() == [2, 0]
    # spectral / median + λ · network / median: λ = 0 keeps the spectral order
    assert zoomout_floor.rerank(spectral, network, 0.0).tolist() == [0, 0]
    assert zoomout_floor.rerank(spectral, network, 1.0).tolist() == [1, 0]
