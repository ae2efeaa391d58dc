"""Run a benchmark command and write its stdout into a section of BENCHMARKS.md.

Sections are delimited by ``<!-- BEGIN name -->`` / ``<!-- END name -->`` markers; the section
is created at the end of the file if missing, and the contents table at the top is rewritten
(``scripts/benchmarks_contents.py``). Numbers in BENCHMARKS.md are therefore always the
verbatim output of a script in this repository, never typed by hand.

Usage: python scripts/update_benchmarks.py SECTION -- python scripts/bench_descriptor.py --runs 30
"""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

BENCHMARKS = Path(__file__).resolve().parents[1] / "BENCHMARKS.md"


def replace_section(text: str, name: str, body: str) -> str:
    begin, end = f"<!-- BEGIN {name} -->", f"<!-- END {name} -->"
    block = f"{begin}\n{body.rstrip()}\n{end}"
    pattern = re.compile(re.escape(begin) + r".*?" + re.escape(end), re.DOTALL)
    if pattern.search(text):
        return pattern.sub(lambda _: block, text)
    return text.rstrip() + "\n\n" + block + "\n"


def main() -> None:
    if len(sys.argv) < 4 or sys.argv[2] != "--":
        sys.exit(__doc__)
    name, command = sys.argv[1], sys.argv[3:]
    result = subprocess.run(command, capture_output=True, text=True, check=False)
    if result.returncode != 0:  # nothing is written; show why
        sys.stderr.write(result.stdout + result.stderr)
        sys.exit(f"{command[0]} exited with status {result.returncode}; {name} left unchanged")
    text = BENCHMARKS.read_text() if BENCHMARKS.exists() else "# Benchmarks\n"
    from benchmarks_contents import with_contents  # its table lists the new section too

    BENCHMARKS.write_text(with_contents(replace_section(text, name, result.stdout)))
    print(result.stdout)


if __name__ == "__main__":
    main()
