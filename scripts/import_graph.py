"""The import graph of ``litege_core`` and ``service``: cycles and imports that climb a layer.

Usage: python scripts/import_graph.py [--edges]

Every ``import`` / ``from … import`` statement counts, also those inside functions and under
``TYPE_CHECKING``: a lazy import is still a dependency. Layers are those of
``docs/architecture.md``; a module may import modules of its own package, and modules of
packages in lower layers. Exits 1 when a cycle or an upward import exists.
"""

from __future__ import annotations

import argparse
import ast
import sys
from collections.abc import Iterable
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("litege_core", "service")

LAYERS: dict[str, int] = {
    # foundations
    "litege_core.errors": 0,
    "litege_core.arrays": 1,
    "litege_core.files": 1,
    "litege_core.enums": 1,
    "litege_core.device": 1,
    "litege_core.shape": 2,
    "litege_core.validate": 2,
    "litege_core.query": 2,
    "litege_core.io": 3,
    "litege_core.projection": 3,
    "litege_core.sampling": 3,
    "litege_core.seams": 3,
    "litege_core.canonical": 3,
    "litege_core.metrics": 3,
    "litege_core": 3,  # the package root: __version__ and re-exported foundations
    "litege_core.models": 0,  # data only
    # method parts
    "litege_core.descriptor": 4,
    "litege_core.nets": 4,
    "litege_core.engines": 4,
    "litege_core.synth": 4,
    "litege_core.variants": 4,
    # models and their data
    "litege_core.learned": 5,
    "litege_core.matching": 5,
    "litege_core.datasets": 5,
    # workflows
    "litege_core.train": 6,
    "litege_core.evaluation": 6,
    "litege_core.render": 6,
    # entry points
    "litege_core.cli": 7,
    "service": 8,
}


def module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def group(module: str) -> str:
    """The layer key of a module: its longest prefix in :data:`LAYERS`."""
    parts = module.split(".")
    for end in range(len(parts), 0, -1):
        key = ".".join(parts[:end])
        if key in LAYERS:
            return key
    raise KeyError(f"{module} has no layer in scripts/import_graph.py LAYERS")


def imports_of(path: Path, module: str, known: set[str]) -> set[str]:
    """Project modules imported by ``path`` (resolved to the longest known module name)."""
    tree = ast.parse(path.read_text(), str(path))
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    found: set[str] = set()
    for node in ast.walk(tree):
        names: Iterable[str] = ()
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")
                anchor = anchor[: len(anchor) - node.level + 1]
                base = ".".join([*anchor, base] if base else anchor)
            names = [f"{base}.{alias.name}" for alias in node.names] + [base]
        for name in names:
            parts = name.split(".")
            for end in range(len(parts), 0, -1):
                candidate = ".".join(parts[:end])
                if candidate in known:
                    # a module's own ancestor packages are initialized before it anyway
                    if candidate != module and not module.startswith(candidate + "."):
                        found.add(candidate)
                    break
    return found


def build_graph() -> dict[str, set[str]]:
    files = {
        module_name(p): p
        for package in PACKAGES
        for p in (ROOT / package).rglob("*.py")
        if "_generated" not in p.parts
    }
    known = set(files)
    return {module: imports_of(path, module, known) for module, path in files.items()}


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []
    counter = 0

    def visit(node: str) -> None:
        nonlocal counter
        index[node] = low[node] = counter
        counter += 1
        stack.append(node)
        on_stack.add(node)
        for nxt in sorted(graph.get(node, ())):
            if nxt not in index:
                visit(nxt)
                low[node] = min(low[node], low[nxt])
            elif nxt in on_stack:
                low[node] = min(low[node], index[nxt])
        if low[node] == index[node]:
            component = []
            while True:
                item = stack.pop()
                on_stack.discard(item)
                component.append(item)
                if item == node:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    sys.setrecursionlimit(10_000)
    for node in sorted(graph):
        if node not in index:
            visit(node)
    return found


def upward_imports(graph: dict[str, set[str]]) -> list[tuple[str, str]]:
    """``(importer, imported)`` pairs where the imported module's layer is above the
    importer's, or a different package of the same layer (siblings stay independent)."""
    bad = []
    for module, targets in graph.items():
        mine = group(module)
        for target in targets:
            theirs = group(target)
            if theirs == mine:
                continue
            if LAYERS[theirs] > LAYERS[mine] or (
                LAYERS[theirs] == LAYERS[mine] and not _sibling_allowed(mine, theirs)
            ):
                bad.append((module, target))
    return sorted(bad)


SIBLINGS_ALLOWED = {
    ("litege_core", "litege_core.io"),  # the package root re-exports load_shape
    ("litege_core.shape", "litege_core.validate"),  # a Shape is validated on construction
    ("litege_core.canonical", "litege_core.sampling"),  # frames from farthest-point samples
    ("litege_core.seams", "litege_core.sampling"),  # seams are repeated positions on a rim
    ("litege_core.variants", "litege_core.synth"),
    ("litege_core.matching", "litege_core.learned"),  # the matching bundle reuses bundle I/O
    ("litege_core.train", "litege_core.evaluation"),  # a run ends with a side-by-side evaluation
}
"""Same-layer imports that are part of the design (one direction each; a cycle is still an
error)."""


def _sibling_allowed(mine: str, theirs: str) -> bool:
    return (mine, theirs) in SIBLINGS_ALLOWED


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--edges", action="store_true", help="print every package-level edge")
    args = parser.parse_args()
    graph = build_graph()
    found_cycles = cycles(graph)
    upward = upward_imports(graph)
    edges = {(group(a), group(b)) for a, targets in graph.items() for b in targets}
    edges = {(a, b) for a, b in edges if a != b}
    print(
        f"{len(graph)} modules, {sum(len(t) for t in graph.values())} imports, "
        f"{len(edges)} package-level edges"
    )
    if args.edges:
        for a, b in sorted(edges):
            print(f"  {a} (layer {LAYERS[a]}) -> {b} (layer {LAYERS[b]})")
    for component in found_cycles:
        print("cycle:", " <-> ".join(component))
    for importer, imported in upward:
        print(
            f"upward: {importer} ({LAYERS[group(importer)]}) imports "
            f"{imported} ({LAYERS[group(imported)]})"
        )
    if not found_cycles and not upward:
        print("no import cycle, no upward import")
        return 0
    return 1


if __name__ == "__main__":
    raise SystemExit(main())
