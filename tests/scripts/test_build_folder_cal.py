"""``scripts/build_folder_cal.py --primitives``: the solids of no training family that choose the
fusion veto's OOD limit, and the held-out ones to evaluate it on, are each one closed surface
(exact geodesics join every pair)."""

from __future__ import annotations

import numpy as np
import pytest

from tests.scripts.conftest import load_script

SCRIPT = load_script("build_folder_cal")


@pytest.mark.parametrize("name", sorted({**SCRIPT.PRIMITIVES, **SCRIPT.HELD_OUT_SOLIDS}))
def test_each_solid_is_one_closed_surface(name: str) -> None:
    solid = {**SCRIPT.PRIMITIVES, **SCRIPT.HELD_OUT_SOLIDS}[name]()
    assert solid.is_watertight and solid.body_count == 1 and solid.volume > 0
    assert len(solid.split(only_watertight=False)) == 1


def test_the_held_out_solids_are_other_kinds() -> None:
    assert not set(SCRIPT.PRIMITIVES) & set(SCRIPT.HELD_OUT_SOLIDS)


def test_the_u_tube_arms_are_parallel_and_apart() -> None:
    """Its two straight arms run along x at z = ±0.5 (0.7 apart at their surfaces)."""
    tube = SCRIPT.HELD_OUT_SOLIDS["u-tube"]()
    arms = tube.vertices[tube.vertices[:, 0] < -0.3]
    assert set(np.round(np.sign(arms[:, 2]))) == {-1.0, 1.0}
    assert np.abs(arms[:, 2]).min() == pytest.approx(0.35, abs=1e-6)
    assert np.abs(arms[:, 2]).max() == pytest.approx(0.65, abs=1e-6)
