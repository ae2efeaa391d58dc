"""The scripts under test are files, not modules: load them by path."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

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


@pytest.fixture(scope="module")
def update_benchmarks() -> ModuleType:
    return load_script("update_benchmarks")


@pytest.fixture(scope="module")
def bench_rig_poses() -> ModuleType:
    return load_script("bench_rig_poses")


@pytest.fixture(scope="module")
def bench_rig_matching() -> ModuleType:
    return load_script("bench_rig_matching")
