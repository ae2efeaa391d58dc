"""Shared fixtures: small deterministic shapes, and the optional real evaluation data."""

import os
from pathlib import Path

import numpy as np
import pytest
import trimesh
from hypothesis import settings

EVAL_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "eval-data"


@pytest.fixture(scope="session")
def sphere_mesh() -> tuple[np.ndarray, np.ndarray]:
    """A 642-vertex unit icosphere ``(vertices, faces)``."""
    mesh = trimesh.creation.icosphere(subdivisions=3)
    return np.asarray(mesh.vertices), np.asarray(mesh.faces)


@pytest.fixture(scope="session")
def eval_data() -> Path:
    """Path of ../shared/eval-data; tests using it skip when it is absent."""
    if not EVAL_DATA.is_dir():
        pytest.skip("../shared/eval-data not available")
    return EVAL_DATA


# CI runs must be reproducible: hypothesis draws the same examples every time there.
settings.register_profile("ci", derandomize=True, print_blob=True)
if os.environ.get("CI"):
    settings.load_profile("ci")
