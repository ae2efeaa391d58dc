"""Wall time of a fresh `litege geodesic` process on a 300-point cloud (issue 17 target ≤ 1.5 s).

    python scripts/bench_cli.py [--runs 7]

One procedural dog (seed 2,000,000, outside every training seed range), 300 surface points,
saved as NPY, binary PLY and XYZ; each file × runtime (``numpy``: the torch-free default, with
the shipped model's graph fusion (the default) and without it; ``torch``) and the kNN-graph Dijkstra
(``--method graph``) as the classical reference, run in interleaved rounds, a fresh interpreter
each time (imports, model loading and the query included). Prints a markdown section for
BENCHMARKS.md.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from datetime import date
from pathlib import Path

import numpy as np

from litege_core import __version__
from litege_core.evaluation.speed import cpu_name
from litege_core.io import save_shape
from litege_core.shape import Shape
from litege_core.synth import generate_shape
from litege_core.variants import point_cloud

FORMATS = ("npy", "ply", "xyz")
CONFIGURATIONS = {
    "LiteGE, numpy runtime (default: graph fusion)": ["--runtime", "numpy"],
    "LiteGE, numpy runtime, network alone": ["--runtime", "numpy", "--fusion", "none"],
    "LiteGE, torch runtime (graph fusion)": ["--runtime", "torch"],
    "kNN-graph Dijkstra": ["--method", "graph"],
}


def cloud_300() -> Shape:
    """The benchmark cloud: 300 surface points of a held-out procedural dog."""
    dog = generate_shape("quadruped", "dog", 2_000_000)
    return Shape.from_arrays(point_cloud(dog.vertices, dog.faces, 300, 0).points)


def cli_command(path: Path, output: Path, extra: list[str]) -> list[str]:
    """``litege geodesic PATH --sources 0 -o OUTPUT EXTRA`` in a fresh interpreter."""
    command = [sys.executable, "-m", "litege_core.cli", "geodesic", str(path)]
    return [*command, "--sources", "0", "-o", str(output), *extra]


def wall_seconds(command: list[str]) -> float:
    start = time.perf_counter()
    subprocess.run(command, check=True, capture_output=True)
    return time.perf_counter() - start


def cli_wall_seconds(cloud: Shape, runs: int, extra: list[str] | None = None) -> float:
    """Median wall time of ``litege geodesic`` (defaults, or ``extra`` options) on ``cloud``
    saved as NPY, a fresh process each run."""
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "cloud300.npy"
        np.save(path, np.asarray(cloud.vertices, dtype=np.float64))
        command = cli_command(path, Path(folder) / "out.npy", extra or [])
        return statistics.median(wall_seconds(command) for _ in range(runs))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=7)
    args = parser.parse_args()
    load = os.getloadavg()[0]
    cloud = cloud_300()
    times: dict[tuple[str, str], list[float]] = {}
    with tempfile.TemporaryDirectory() as folder:
        files = {fmt: Path(folder) / f"cloud300.{fmt}" for fmt in FORMATS}
        for path in files.values():
            save_shape(cloud, path)
        output = Path(folder) / "out.npy"
        for extra in CONFIGURATIONS.values():  # warm-up: file caches, .pyc files
            wall_seconds(cli_command(files["npy"], output, extra))
        for _ in range(args.runs):
            for fmt, path in files.items():
                for name, extra in CONFIGURATIONS.items():
                    times.setdefault((fmt, name), []).append(
                        wall_seconds(cli_command(path, output, extra))
                    )
    print("### `litege geodesic` start-up: a 300-point cloud, a fresh process (issue 17)\n")
    print(
        f"- date {date.today()}; {cpu_name()}, {os.cpu_count()} logical CPUs shared with other "
        f"jobs (load average {load:.1f} at the start); python {platform.python_version()}, "
        f"numpy {np.__version__}, litege {__version__}"
    )
    print(
        f"- median of {args.runs} interleaved rounds after a warm-up; wall seconds of "
        "`litege geodesic FILE --sources 0 -o OUT` (imports, model loading, registration, one "
        "distance field); one procedural dog (seed 2,000,000), 300 surface points; command "
        f"`python scripts/bench_cli.py --runs {args.runs}`; ratio over kNN-graph Dijkstra on "
        "the same file\n"
    )
    print("| file | configuration | wall s | ratio | target ≤ 1.5 s |")
    print("|---|---|---:|---:|---|")
    for fmt in FORMATS:
        reference = statistics.median(times[(fmt, "kNN-graph Dijkstra")])
        for name in CONFIGURATIONS:
            wall = statistics.median(times[(fmt, name)])
            met = "" if name.startswith("kNN") else ("yes" if wall <= 1.5 else "**no**")
            print(f"| {fmt} | {name} | {wall:.2f} | {wall / reference:.2f}× | {met} |")


if __name__ == "__main__":
    main()
