"""The scripts under test are files, not modules: load them by path."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest

SCRIPTS = Path(__file__).resolve().parents[2] / "scripts"


def load_script(name: str) -> ModuleType:
    """``scripts/NAME.py`` as a module (registered as ``litege_script_NAME``)."""
    spec = importlib.util.spec_from_file_location(f"litege_script_{name}", SCRIPTS / f"{name}.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def ship_model() -> ModuleType:
    return load_script("ship_model")


@pytest.fixture(scope="module")
def eval_real_ablation() -> ModuleType:
    return load_script("eval_real_ablation")


@pytest.fixture(scope="module")
def import_graph() -> ModuleType:
    return load_script("import_graph")


@pytest.fixture(scope="module")
def compose_matching() -> ModuleType:
    return load_script("compose_matching")


@pytest.fixture(scope="module")
def swap_tnet() -> ModuleType:
    return load_script("swap_tnet")


@pytest.fixture(scope="module")
def frame_report() -> ModuleType:
    return load_script("frame_report")


@pytest.fixture(scope="module")
def contact_error() -> ModuleType:
    return load_script("contact_error")


@pytest.fixture(scope="module")
def signed_error() -> ModuleType:
    return load_script("signed_error")


@pytest.fixture(scope="module")
def bench_workloads() -> ModuleType:
    return load_script("bench_workloads")


@pytest.fixture
def toy_fusion(toy_bundle_dir_with_ood, blob):
    """The toy bundle with a fusion calibration of its own (no veto bias, gate 0) and the toy
    blob as an evaluation shape (any positive rows: Euclidean distances from two sources):
    ``(bundle, predictor, shape)`` for the fusion diagnoses."""
    from litege_core.evaluation.geodesic import EvalShape
    from litege_core.learned import Predictor, load_bundle
    from litege_core.learned.fusion_calibration import FusionCalibration

    bundle = load_bundle(toy_bundle_dir_with_ood)
    calibration = FusionCalibration(
        k=8,
        prune_ratio=1.6,
        bias_log10_points=(2.0, 3.0),
        bias=(1.0, 1.0),
        gate=(0.0, 0.0, 0.0, 0.0),
        mesh_bias=1.0,
        bundle_hash=bundle.content_hash,
    )
    mesh = blob(2)
    vertices, faces = np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces)
    sources = np.array([0, 5])
    gt = np.linalg.norm(vertices[sources][:, None] - vertices[None], axis=-1)
    shape = EvalShape("blob", "test", vertices, faces, sources, gt)
    return bundle, Predictor(bundle, fusion=calibration), shape
