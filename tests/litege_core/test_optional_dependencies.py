"""Optional dependencies: the reference engines (pygeodesic, tvb-gdist, potpourri3d) and the
renderer (Pillow) are extras, not requirements of the core; without them every module still
imports (or refuses with MissingDependencyError), and using them says what to install."""

from __future__ import annotations

import subprocess
import sys
import textwrap
import tomllib
from pathlib import Path

from litege_core.errors import MissingDependencyError

REPO = Path(__file__).resolve().parents[2]
PROJECT = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]
OPTIONAL = {"pygeodesic": "engines", "tvb-gdist": "engines", "potpourri3d": "engines"}
OPTIONAL["pillow"] = "render"
# import names of the optional distributions, and of the other extras' packages
BLOCKED = ("pygeodesic", "gdist", "potpourri3d", "PIL", "pymeshlab", "pyFM")


def _names(requirements: list[str]) -> set[str]:
    return {r.split(">")[0].split("<")[0].split("=")[0].split("[")[0].strip() for r in requirements}


def test_engines_and_pillow_are_extras_that_dev_and_data_install():
    extras = PROJECT["optional-dependencies"]
    assert not _names(PROJECT["dependencies"]) & set(OPTIONAL)
    for name, extra in OPTIONAL.items():
        assert name in _names(extras[extra]), (name, extra)
    assert "litege[engines,render]" in extras["dev"]  # `make` installs .[service,data,dev]
    assert "litege[engines]" in extras["data"]
    assert "litege[engines]" in extras["eval"]
    assert "litege[engines]" in extras["service"]  # served paths are refined with potpourri3d


def _without_optional(code: str) -> subprocess.CompletedProcess:
    """Run ``code`` in a fresh interpreter where the optional packages cannot be imported."""
    prelude = textwrap.dedent(
        f"""
        import importlib.abc, sys

        class Block(importlib.abc.MetaPathFinder):
            def find_spec(self, name, path=None, target=None):
                if name.split(".")[0] in {BLOCKED!r}:
                    raise ModuleNotFoundError(f"No module named {{name!r}} (blocked)", name=name)
                return None

        sys.meta_path.insert(0, Block())
        """
    )
    return subprocess.run(
        [sys.executable, "-c", prelude + textwrap.dedent(code)],
        capture_output=True,
        text=True,
        timeout=300,
        cwd=REPO,
    )


def test_every_module_imports_without_the_optional_packages():
    result = _without_optional(
        """
        import importlib, pkgutil
        import litege_core
        from litege_core.errors import MissingDependencyError

        refused, broken = [], []
        for info in pkgutil.walk_packages(litege_core.__path__, "litege_core."):
            if info.name.endswith("__main__"):
                continue
            try:
                importlib.import_module(info.name)
            except MissingDependencyError as exc:
                refused.append(f"{info.name}: {exc}")
            except ImportError as exc:
                broken.append(f"{info.name}: {exc!r}")
        print("REFUSED", refused)
        print("BROKEN", broken)
        """
    )
    assert result.returncode == 0, result.stderr
    assert "BROKEN []" in result.stdout, result.stdout
    assert "litege[render]" in result.stdout  # render.figures names its extra


def test_using_a_missing_optional_package_names_the_extra(tmp_path):
    result = _without_optional(
        """
        import numpy as np
        from litege_core.cli import main
        from litege_core.engines import compute_distances
        from litege_core.errors import MissingDependencyError
        from litege_core.shape import Shape
        import trimesh

        mesh = trimesh.creation.icosphere(subdivisions=1)
        shape = Shape.from_arrays(np.asarray(mesh.vertices), np.asarray(mesh.faces))
        for method in ("exact", "heat"):
            try:
                compute_distances(shape, [0], method=method)
            except MissingDependencyError as exc:
                print("MISSING", method, exc)
        print("EXIT", main(["render", "nothing.obj", "-o", "x.png"]))
        """
    )
    assert result.returncode == 0, result.stderr
    assert "MISSING exact" in result.stdout and "MISSING heat" in result.stdout, result.stdout
    assert "EXIT 2" in result.stdout
    assert "[missing-dependency]" in result.stderr and "litege[render]" in result.stderr


def test_missing_dependency_error_is_an_import_error():
    error = MissingDependencyError("x needs y: pip install 'litege[engines]'")
    assert isinstance(error, ImportError) and error.code == "missing-dependency"
