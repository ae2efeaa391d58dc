"""scripts/calibrate_routing.py: the balancing weight and the routing counts."""

from __future__ import annotations

import numpy as np
import pytest

from tests.scripts.conftest import load_script


@pytest.fixture(scope="module")
def calibrate_routing():
    return load_script("calibrate_routing")


def routed(module, own, setting, z, agreement, error=None):
    error = error or {name: np.nan for name in z}
    return module.Routed(own, setting, z, agreement, error)


def test_the_weight_balances_the_median_gaps(calibrate_routing) -> None:
    rows = [
        routed(calibrate_routing, "a", "mesh", {"a": 0.0, "b": 2.0}, {"a": 0.02, "b": 0.07}),
        routed(calibrate_routing, "b", "mesh", {"a": 3.0, "b": 1.0}, {"a": 0.08, "b": 0.03}),
        routed(calibrate_routing, "a", "mesh", {"a": 0.0, "b": 2.0}, {"a": 0.01, "b": 0.06}),
    ]
    # z gaps 2, 2, 2; agreement gaps 0.05 each: weight 40
    assert calibrate_routing.balance_weight(rows) == pytest.approx(40.0)


def test_the_table_counts_each_rule_and_averages_the_chosen_errors(calibrate_routing) -> None:
    z = {"quadrupeds": 1.0, "humans": 1.2}  # the z-score alone picks quadrupeds
    agreement = {"quadrupeds": 0.10, "humans": 0.02}  # the agreement turns it to humans
    error = {"quadrupeds": 9.0, "humans": 3.0}
    rows = [routed(calibrate_routing, "humans", "mesh", z, agreement, error)]
    lines = calibrate_routing.routing_table(rows, 40.0, with_errors=True)
    assert lines[0] == "| humans | mesh | 1 | 0 | 1 | 3.00 | 9.00 | 3.00 |"
    assert len(lines) == 1  # settings without inputs get no row
