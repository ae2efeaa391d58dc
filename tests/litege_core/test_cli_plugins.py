"""Commands added through the ``litege.commands`` entry-point group: ``serve`` comes from the
service this way, plugins load only when run, and a broken plugin fails with an install hint."""

from __future__ import annotations

import importlib.metadata
import subprocess
import sys
import textwrap

import pytest

from litege_core.cli import COMMAND_GROUP, build_parser, main, plugin_commands
from litege_core.io import save_shape
from litege_core.shape import Shape


def _fake_entry_points(monkeypatch, *plugins):
    def entry_points(**params):
        assert params == {"group": COMMAND_GROUP}
        return importlib.metadata.EntryPoints(plugins)

    monkeypatch.setattr(importlib.metadata, "entry_points", entry_points)


@pytest.fixture
def hello_plugin(tmp_path, monkeypatch):
    """A plugin module ``litege_hello_plugin`` adding ``litege hello --name N``."""
    (tmp_path / "litege_hello_plugin.py").write_text(
        textwrap.dedent(
            """
            def register(commands):
                hello = commands.add_parser("hello", help="say hello")
                hello.add_argument("--name", default="world")
                hello.set_defaults(handler=lambda args: print(f"hello {args.name}") or 0)
            """
        )
    )
    monkeypatch.syspath_prepend(str(tmp_path))
    sys.modules.pop("litege_hello_plugin", None)
    yield importlib.metadata.EntryPoint("hello", "litege_hello_plugin:register", COMMAND_GROUP)
    sys.modules.pop("litege_hello_plugin", None)


def test_serve_is_registered_by_the_service_entry_point():
    assert "serve" in [ep.name for ep in plugin_commands()]
    args = build_parser().parse_args(["serve", "--port", "8123", "--no-grpc"])
    assert (args.port, args.grpc_port, args.no_grpc, args.no_rest) == (8123, None, True, False)
    assert callable(args.handler)


def test_a_plugin_runs_and_is_imported_only_when_run(hello_plugin, monkeypatch, capsys):
    _fake_entry_points(monkeypatch, hello_plugin)
    with pytest.raises(SystemExit):
        main(["--help"])
    assert "hello" in capsys.readouterr().out
    assert "litege_hello_plugin" not in sys.modules  # listed, not imported
    assert main(["hello", "--name", "cli"]) == 0
    assert capsys.readouterr().out == "hello cli\n"


def test_builtin_commands_never_look_up_entry_points(tmp_path, sphere_mesh, monkeypatch, capsys):
    def refuse(**params):
        raise AssertionError("entry points looked up for a built-in command")

    monkeypatch.setattr(importlib.metadata, "entry_points", refuse)
    save_shape(Shape.from_arrays(*sphere_mesh), tmp_path / "s.obj")
    assert main(["info", str(tmp_path / "s.obj")]) == 0


def test_a_plugin_cannot_replace_a_builtin_command(monkeypatch):
    info = importlib.metadata.EntryPoint("info", "no_such_module:register", COMMAND_GROUP)
    _fake_entry_points(monkeypatch, info)
    assert plugin_commands(builtin={"info"}) == []
    assert build_parser().parse_args(["info", "x.obj"]).command == "info"


def test_a_plugin_that_cannot_be_imported_fails_with_an_install_hint(monkeypatch, capsys):
    broken = importlib.metadata.EntryPoint(
        "broken", "litege_no_such_module:register [extra1]", COMMAND_GROUP
    )
    _fake_entry_points(monkeypatch, broken)
    assert main(["broken"]) == 2
    err = capsys.readouterr().err
    assert "[missing-dependency]" in err
    assert "pip install 'litege_no_such_module[extra1]'" in err


def test_help_imports_neither_the_service_nor_torch():
    code = (
        "import sys\n"
        "from litege_core.cli import main\n"
        "try:\n    main(['--help'])\nexcept SystemExit:\n    pass\n"
        "heavy = sorted(m for m in ('service', 'service.server', 'torch', 'uvicorn') "
        "if m in sys.modules)\n"
        "print('HEAVY', heavy)\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True
    ).stdout
    assert "serve" in out and "HEAVY []" in out
