"""Write BENCHMARKS.md: a benchmark command's output into a section, and the contents table.

Sections are delimited by ``<!-- BEGIN name -->`` / ``<!-- END name -->`` markers; a section
is created at the end of the file if missing. Numbers in BENCHMARKS.md are therefore always the
verbatim output of a script in this repository, never typed by hand.

Every write also rewrites the ``contents`` section at the top of the file (after its opening
paragraph): first the newest section of each recurring snapshot (the dev sets, the speed
workloads), then one row per section in document order: its title linked to its heading, the
issues its title names, and the outcome its title states ("shipped", "not shipped", ...). It
reads titles only.

Usage:
    python scripts/update_benchmarks.py SECTION -- python scripts/bench_descriptor.py --runs 30
    python scripts/update_benchmarks.py --contents [--check]
"""

from __future__ import annotations

import bisect
import re
import subprocess
import sys
import unicodedata
from dataclasses import dataclass
from pathlib import Path

BENCHMARKS = Path(__file__).resolve().parents[1] / "BENCHMARKS.md"


def replace_section(text: str, name: str, body: str) -> str:
    begin, end = f"<!-- BEGIN {name} -->", f"<!-- END {name} -->"
    block = f"{begin}\n{body.rstrip()}\n{end}"
    pattern = re.compile(re.escape(begin) + r".*?" + re.escape(end), re.DOTALL)
    if pattern.search(text):
        return pattern.sub(lambda _: block, text)
    return text.rstrip() + "\n\n" + block + "\n"


def write_section(name: str, body: str) -> None:
    """Write ``body`` into section ``name`` of BENCHMARKS.md and refresh its contents."""
    text = BENCHMARKS.read_text() if BENCHMARKS.exists() else "# Benchmarks\n"
    BENCHMARKS.write_text(with_contents(replace_section(text, name, body)))


CONTENTS = "contents"
TITLE = "Contents"
_BLOCK = re.compile(r"<!-- BEGIN (\S+) -->\n(.*?)<!-- END \1 -->", re.DOTALL)
_HEADING = re.compile(r"^(#{1,6}) +(.+?) *$", re.MULTILINE)
_FENCE = re.compile(r"^```.*?^```", re.MULTILINE | re.DOTALL)
_ISSUES = re.compile(r"\bissues? ([0-9][0-9, and]*)")
_OUTCOME = re.compile(r"\)\s*(?:—|:)\s*([^()]+)$")
"""A title's outcome: what follows its closing parenthesis after a dash or a colon, e.g.
``… (issue 14; 2026-11-29) — shipped`` or ``… (issue 14, step 2; 2026-12-02): not shipped``."""
SNAPSHOTS = (
    ("the dev sets, all defaults", r"^The dev sets at the end"),
    ("speed, every workload", r"^Speed at the end"),
    ("the GPU path", r"CUDA"),
)
"""(label, title pattern): the newest section whose title matches is listed first."""


@dataclass(frozen=True)
class Section:
    """One ``BEGIN``/``END`` block: its marker name, first heading (``""`` if none) and the
    anchor GitHub gives that heading (``""`` if none)."""

    name: str
    title: str
    anchor: str

    @property
    def issues(self) -> list[int]:
        """The issue numbers the title names (``(issue 14, step 3; …)``, ``(issues 14 and 17)``)."""
        found: list[int] = []
        for group in _ISSUES.findall(self.title):
            numbers = [int(n) for n in re.findall(r"[0-9]+", group)]
            found += [n for n in numbers if n < 1000 and n not in found]  # not a year
        return found

    @property
    def outcome(self) -> str:
        """What the title says became of the work (``"shipped"``, ``"not adopted"``, …), or
        ``""`` where it says nothing."""
        match = _OUTCOME.search(self.title)
        return match.group(1).strip() if match else ""


def slug(heading: str) -> str:
    """The anchor GitHub derives from a heading's text: lower case, inline markup and
    punctuation dropped (letters, marks, digits, ``_``, ``-`` and spaces kept), spaces as ``-``."""
    text = re.sub(r"<[^>]+>", "", heading).lower()
    kept = "".join(ch for ch in text if ch in " -_" or unicodedata.category(ch)[0] in "LMN")
    return kept.replace(" ", "-")


def headings(text: str) -> list[re.Match[str]]:
    """The Markdown headings of ``text``, those inside fenced code blocks left out."""
    fences = [(m.start(), m.end()) for m in _FENCE.finditer(text)]
    return [m for m in _HEADING.finditer(text) if not any(a <= m.start() < b for a, b in fences)]


def anchors(text: str, reserved: tuple[str, ...] = ()) -> list[str]:
    """The anchors of every heading of ``text`` in order, repeats numbered ``-1``, ``-2`` … as
    GitHub numbers them (``reserved``: slugs of headings placed before ``text``)."""
    seen: dict[str, int] = {}
    for name in reserved:
        seen[name] = seen.get(name, -1) + 1
    out = []
    for match in headings(text):
        base = slug(match.group(2))
        count = seen.get(base, -1) + 1
        seen[base] = count
        out.append(base if count == 0 else f"{base}-{count}")
    return out


def sections(text: str) -> list[Section]:
    """Every block of ``text`` but ``contents``, in document order, anchored as they will be
    once the contents section (whose only heading is :data:`TITLE`) stands before them."""
    body = _BLOCK.sub(lambda m: "" if m.group(1) == CONTENTS else m.group(0), text)
    found = headings(body)
    starts = [m.start() for m in found]
    labelled = list(zip(found, anchors(body, reserved=(slug(TITLE),)), strict=True))
    out = []
    for block in _BLOCK.finditer(body):
        first = bisect.bisect_left(starts, block.start(2))  # the block's first heading, if any
        if first < len(starts) and starts[first] < block.end(2):
            heading, anchor = labelled[first]
            out.append(Section(block.group(1), heading.group(2), anchor))
        else:
            out.append(Section(block.group(1), "", ""))
    return out


def _link(section: Section) -> str:
    if not section.anchor:
        return f"`{section.name}`"
    title = section.title.replace("|", "\\|")
    return f"[{title}](#{section.anchor})"


def contents(found: list[Section]) -> str:
    """The ``contents`` section's Markdown."""
    lines = [
        f"## {TITLE}",
        "",
        "Written by `scripts/update_benchmarks.py` from the section titles. Sections are in "
        "the order they were measured; a later one can supersede an earlier one, and a title "
        "says when its change was not shipped.",
        "",
        "**Newest snapshots**",
        "",
    ]
    for label, pattern in SNAPSHOTS:
        newest = [s for s in found if s.title and re.search(pattern, s.title)]
        if newest:
            lines.append(f"- {label}: {_link(newest[-1])} (`{newest[-1].name}`)")
    lines += ["", "| section | marker | issues | outcome |", "|---|---|---|---|"]
    for section in found:
        issues = ", ".join(str(n) for n in section.issues)
        lines.append(f"| {_link(section)} | `{section.name}` | {issues} | {section.outcome} |")
    return "\n".join(lines) + "\n"


def with_contents(text: str) -> str:
    """``text`` with its ``contents`` section written: replaced in place, or placed before the
    first section (after the opening paragraph) the first time."""
    body = contents(sections(text))
    if f"<!-- BEGIN {CONTENTS} -->" in text:
        return replace_section(text, CONTENTS, body)
    first = text.find("<!-- BEGIN ")
    block = f"<!-- BEGIN {CONTENTS} -->\n{body.rstrip()}\n<!-- END {CONTENTS} -->\n\n"
    if first < 0:
        return text.rstrip() + "\n\n" + block
    return text[:first] + block + text[first:]


def main() -> None:
    if sys.argv[1:2] == ["--contents"] and sys.argv[2:] in ([], ["--check"]):
        text = BENCHMARKS.read_text()
        updated = with_contents(text)
        if sys.argv[2:] == ["--check"]:
            sys.exit(0 if updated == text else "BENCHMARKS.md contents are out of date")
        BENCHMARKS.write_text(updated)
        print(f"{len(sections(updated))} sections listed")
        return
    if len(sys.argv) < 4 or sys.argv[2] != "--":
        sys.exit(__doc__)
    name, command = sys.argv[1], sys.argv[3:]
    result = subprocess.run(command, capture_output=True, text=True, check=False)
    if result.returncode != 0:  # nothing is written; show why
        sys.stderr.write(result.stdout + result.stderr)
        sys.exit(f"{command[0]} exited with status {result.returncode}; {name} left unchanged")
    write_section(name, result.stdout)
    print(result.stdout)


if __name__ == "__main__":
    main()
