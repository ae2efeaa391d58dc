"""The architecture's import rules hold: no import cycle, no import that climbs a layer
(``scripts/import_graph.py``, layers as in ``docs/architecture.md``)."""

from __future__ import annotations


def test_no_import_cycle(import_graph):
    assert import_graph.cycles(import_graph.build_graph()) == []


def test_no_module_imports_a_layer_above_it(import_graph):
    assert import_graph.upward_imports(import_graph.build_graph()) == []


def test_every_module_has_a_layer(import_graph):
    for module in import_graph.build_graph():
        import_graph.group(module)  # raises KeyError for a package missing from LAYERS


def test_the_checker_sees_a_cycle_and_an_upward_import(import_graph):
    graph = {"litege_core.query": {"litege_core.io"}, "litege_core.io": {"litege_core.query"}}
    assert import_graph.cycles(graph) == [["litege_core.io", "litege_core.query"]]
    assert ("litege_core.query", "litege_core.io") in import_graph.upward_imports(graph)
