"""``scripts/build_folder_cal.py --primitives``: the solids of no training family that choose the
fusion veto's OOD limit are each one closed surface (exact geodesics join every pair)."""

from __future__ import annotations

import pytest

from tests.scripts.conftest import load_script


@pytest.mark.parametrize("name", sorted(load_script("build_folder_cal").PRIMITIVES))
def test_each_primitive_is_one_closed_surface(name: str) -> None:
    solid = load_script("build_folder_cal").PRIMITIVES[name]()
    assert solid.is_watertight and solid.body_count == 1
    assert len(solid.split(only_watertight=False)) == 1
