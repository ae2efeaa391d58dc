"""Guards on the shape of the package: the core never imports the service or its frameworks,
and every public module declares its public names."""

from __future__ import annotations

import importlib
import pkgutil
import subprocess
import sys

import pytest

import litege_core

SERVICE_SIDE = ("fastapi", "starlette", "grpc", "redis", "uvicorn", "service")


def _modules() -> list[str]:
    """Every module of litege_core except ``__main__`` (importing it runs the CLI)."""
    return sorted(
        info.name
        for info in pkgutil.walk_packages(litege_core.__path__, "litege_core.")
        if not info.name.endswith(".__main__")
    )


def _public(name: str) -> bool:
    return not any(part.startswith("_") for part in name.split(".")[1:])


def test_the_core_never_imports_the_service_or_its_frameworks():
    code = (
        "import importlib, pkgutil, sys\n"
        "import litege_core\n"
        "for info in pkgutil.walk_packages(litege_core.__path__, 'litege_core.'):\n"
        "    if not info.name.endswith('.__main__'):\n"
        "        importlib.import_module(info.name)\n"
        f"found = sorted(m for m in sys.modules if m.split('.')[0] in {SERVICE_SIDE!r})\n"
        "print('FOUND', found)\n"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
    assert "FOUND []" in result.stdout, result.stdout


@pytest.mark.parametrize("name", [m for m in _modules() if _public(m)])
def test_public_modules_declare_all_and_every_name_exists(name):
    module = importlib.import_module(name)
    names = getattr(module, "__all__", None)
    assert names is not None, f"{name} does not define __all__"
    assert len(set(names)) == len(names), f"{name}.__all__ lists a name twice"
    missing = [n for n in names if not hasattr(module, n)]
    assert not missing, f"{name}.__all__ names what it does not define: {missing}"
