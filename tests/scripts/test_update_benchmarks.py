"""scripts/update_benchmarks.py: its contents table (GitHub anchors, titles, kept current)."""

from __future__ import annotations

from types import ModuleType

DOC = """# Benchmarks

Intro paragraph.

<!-- BEGIN first -->
## Graph fusion: chords cut (issue 14, step 6; 2026-11-29) — shipped

```
# a shell comment, not a heading
```

### Real-shape ablation: TOSCA animals (real)
<!-- END first -->

<!-- BEGIN second -->
### Real-shape ablation: TOSCA animals (real)
text
<!-- END second -->

<!-- BEGIN third -->
## Speed at the end of the session (issues 14 and 17; 2026-12-01): not shipped
<!-- END third -->

<!-- BEGIN plain -->
- no heading here
<!-- END plain -->
"""


def test_slug_follows_githubs_rules(update_benchmarks: ModuleType) -> None:
    assert update_benchmarks.slug("B shapes × 1 query, ['cpu']") == "b-shapes--1-query-cpu"
    shipped = update_benchmarks.slug("Shipped `humans` model — shipped")
    assert shipped == "shipped-humans-model--shipped"
    assert update_benchmarks.slug("A fused pair 26.7 → 10.5 ms") == "a-fused-pair-267--105-ms"


def test_repeated_headings_are_numbered_and_fences_skipped(update_benchmarks: ModuleType) -> None:
    found = update_benchmarks.anchors(DOC)
    assert found.count("real-shape-ablation-tosca-animals-real") == 1
    assert "real-shape-ablation-tosca-animals-real-1" in found
    assert not any("shell-comment" in anchor for anchor in found)


def test_sections_read_title_issues_and_outcome(update_benchmarks: ModuleType) -> None:
    first, second, third, plain = update_benchmarks.sections(DOC)
    assert (first.name, first.issues, first.outcome) == ("first", [14], "shipped")
    assert first.anchor.startswith("graph-fusion-chords-cut-issue-14")
    # the first block's subheading took the unnumbered anchor
    assert second.anchor == "real-shape-ablation-tosca-animals-real-1"
    assert (third.issues, third.outcome) == ([14, 17], "not shipped")
    assert (plain.title, plain.anchor) == ("", "")


def test_contents_placed_once_then_replaced(update_benchmarks: ModuleType) -> None:
    once = update_benchmarks.with_contents(DOC)
    assert once.index("<!-- BEGIN contents -->") < once.index("<!-- BEGIN first -->")
    assert once.index("Intro paragraph.") < once.index("<!-- BEGIN contents -->")
    assert update_benchmarks.with_contents(once) == once
    assert "- the dev sets" not in once  # no snapshot of that kind in DOC
    assert "- speed, every workload: [Speed at the end of the session" in once
    # the contents heading is reserved: a later heading of the same name would be numbered
    assert update_benchmarks.anchors(once)[1] == "contents"


def test_the_repositorys_contents_are_current(update_benchmarks: ModuleType) -> None:
    text = update_benchmarks.BENCHMARKS.read_text()
    current = update_benchmarks.with_contents(text)
    assert current == text, "run python scripts/update_benchmarks.py --contents"
