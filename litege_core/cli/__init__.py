"""The ``litege`` command line.

Sub-commands:
    litege info FILE          load and validate a shape; print kind, counts, area, content hash
    litege geodesic FILE      predicted geodesic distances (sources × targets) to a .npy file
    litege path FILE          predicted geodesic path (polyline) to a .npy file
    litege match X Y          for each query point of X, the matched point of Y (.npy, int64)
    litege data build ...     build (or resume) a ground-truth geodesic dataset
    litege data verify DIR    check a dataset's shard hashes and arrays
    litege train geodesic     train a geodesic model from a TOML config
    litege train tnet         train the T-Net (shape orientation for matching)
    litege train matching     train the matching network and export a matching bundle
    litege eval geodesic      evaluate a model against the classical baselines
    litege eval matching      evaluate a matching model against NN and ZoomOut baselines
    litege render FILE        PNG heatmap of predicted distances (isolines, path), offscreen
    litege render-match X Y   PNG of a correspondence X → Y (colour transfer), offscreen
    litege sample FAMILY      write a procedural animal or human (licence-clean sample shape)

Other distributions add commands through the ``litege.commands`` entry-point group: each entry
point is a function ``register(subparsers)`` that adds its parser(s) with ``handler`` defaults.
The service registers ``litege serve`` this way (``service.server:add_serve_command``), so the
core never imports the service. Entry points are loaded only when their command is run (or
when :func:`build_parser` is asked for them), so ``litege --help`` and ``litege geodesic``
never import a web framework.

Each command lives in one module of this package (:mod:`~litege_core.cli.shapes`,
:mod:`~litege_core.cli.data`, :mod:`~litege_core.cli.train`, :mod:`~litege_core.cli.evaluate`,
:mod:`~litege_core.cli.match`, :mod:`~litege_core.cli.render`), with the shared argument groups
and helpers in :mod:`~litege_core.cli.common`; the heavy imports happen inside the handlers.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Collection, Sequence
from importlib import import_module
from typing import TYPE_CHECKING

from litege_core import __version__
from litege_core.errors import LiteGEError, MissingDependencyError

if TYPE_CHECKING:
    from importlib.metadata import EntryPoint

COMMAND_GROUP = "litege.commands"
"""Entry-point group of the commands that other distributions add to ``litege``."""

_MODULES = ("shapes", "data", "evaluate", "match", "train", "render", "sample")
"""The core's command modules, in ``--help`` order; each has ``register(subparsers)``."""


def plugin_commands(builtin: Collection[str] = ()) -> list[EntryPoint]:
    """The ``litege.commands`` entry points, by name, except those named in ``builtin``
    (a plugin cannot replace a built-in command)."""
    from importlib.metadata import entry_points

    found = {ep.name: ep for ep in entry_points(group=COMMAND_GROUP)}
    return [found[name] for name in sorted(found) if name not in builtin]


def _missing(entry_point: EntryPoint, error: ImportError) -> Callable[[argparse.Namespace], int]:
    """The handler of a plugin command whose module cannot be imported."""
    dist = entry_point.dist
    package = dist.name if dist is not None else entry_point.module.split(".")[0]
    extras = ",".join(entry_point.extras)
    hint = f"pip install '{package}[{extras}]'" if extras else f"pip install {package}"

    def handler(args: argparse.Namespace) -> int:
        raise MissingDependencyError(
            f"'litege {entry_point.name}' is unavailable ({error}); install with: {hint}"
        ) from error

    return handler


def _add_plugins(commands: argparse._SubParsersAction, load: bool | Collection[str]) -> None:
    """Add the plugin commands: imported and registered when ``load`` is ``True`` or names
    them, otherwise only listed (in ``--help`` and "invalid choice" errors)."""
    for entry_point in plugin_commands(builtin=set(commands.choices)):
        if load is True or (not isinstance(load, bool) and entry_point.name in load):
            try:
                register = entry_point.load()
            except ImportError as exc:
                parser = commands.add_parser(entry_point.name, help=f"(unavailable: {exc})")
                parser.set_defaults(handler=_missing(entry_point, exc))
                continue
            register(commands)
        else:
            module = entry_point.value.split(":")[0]
            commands.add_parser(
                entry_point.name, help=f"provided by {module}; see: litege {entry_point.name} -h"
            )


def _core_parser() -> tuple[argparse.ArgumentParser, argparse._SubParsersAction]:
    parser = argparse.ArgumentParser(prog="litege", description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--version", action="version", version=f"litege {__version__}")
    commands = parser.add_subparsers(dest="command", required=True)
    for name in _MODULES:
        import_module(f"litege_core.cli.{name}").register(commands)
    return parser, commands


def build_parser(plugins: bool | Collection[str] = True) -> argparse.ArgumentParser:
    """The ``litege`` argument parser.

    Args:
        plugins: which ``litege.commands`` entry points to import and register: all
            (``True``), none (``False``: no entry-point lookup at all), or those of the given
            command names (the others are listed by name only).
    """
    parser, commands = _core_parser()
    if plugins is not False:
        _add_plugins(commands, plugins)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``litege`` with ``argv`` (default ``sys.argv[1:]``); returns the exit status."""
    argv = list(sys.argv[1:] if argv is None else argv)
    parser, commands = _core_parser()
    # The command is the first non-option word. A built-in one needs no entry-point lookup;
    # anything else (a plugin, --help, a typo) lists the plugins, importing only the one run.
    command = next((word for word in argv if not word.startswith("-")), None)
    if command not in commands.choices:
        _add_plugins(commands, {command} if command else False)
    args = parser.parse_args(argv)
    try:
        return int(args.handler(args))
    except LiteGEError as exc:
        print(f"litege: error [{exc.code}]: {exc}", file=sys.stderr)
        return 2


__all__ = ["COMMAND_GROUP", "build_parser", "main", "plugin_commands"]
