"""Where the time and the memory of the learned predictor go (issue 17): a stage breakdown of
four workloads, side by side for several predictor configurations, printed as markdown.

Usage::

    python scripts/profile_predictor.py [--runs 7] [--config float32/full --config auto/stride2]
        [--flamegraph out/profile]

Workloads (shipped ``quadrupeds`` model, held-out procedural quadrupeds, one torch thread,
preprocessing included):

* ``1 pair``: one 2000-point cloud registered, one (source, target) pair;
* ``distance field``: the same cloud, one source to every point;
* ``64 × 1 query``: 64 clouds of 2000 points (8 distinct shapes, each sent 8 times; nothing
  cached between them), one pair each, in one ``register_many`` + ``distances_many``;
* ``1K × 1K``: a 5000-vertex mesh (procedural dog, isotropic remesh), 1000 × 1000 vertices.

Stages, run one after the other exactly as :meth:`Predictor.register_many` and
:meth:`Predictor.distances_many` run them (the script checks that its result equals the
public API's):

* ``sampling``: :func:`shape_samples` (2000 area-weighted points on a mesh; nothing on a cloud);
* ``canonicalize``: :func:`canonicalize_bbox_many` (the frames and the canonical samples);
* ``UDF``: the unsigned distance field at the informative voxels (k-d tree per cloud on a
  CPU, one batched kernel on a GPU);
* ``PCA``: ``(udf − μ)Pᵀ`` and the reconstruction residual;
* ``shape MLP``: :meth:`Predictor.restore_many` (shape MLP, per-shape bias, the states);
* ``point features``: :meth:`Predictor.resolve` of sources and targets (the point MLP of the
  queried points, or the whole feature table when a query needs most points);
* ``head``: the pair evaluation (the predictor's grouped / dense blocks).

Time: median over ``--runs`` runs (after one warm-up) of the process CPU time of each stage
(on this shared machine CPU time is steadier than wall time; the end-to-end row gives both).
Memory: allocator-exact peaks (numpy by tracemalloc, torch's CPU allocator by the profiler's
memory events; :mod:`litege_core.evaluation.speed`), per stage above what was allocated when
the stage started, and for the whole workload.

Configurations ``PRECISION/LATTICE``: the :class:`Predictor` ``precision`` (``float32``,
``bfloat16``, ``int8``, ``auto``) and ``descriptor_lattice`` (``full``, ``bcc``, ``stride2``).

``--flamegraph DIR`` also records a py-spy flame graph (SVG) of each workload (baseline
configuration) into ``DIR`` (needs ``pip install py-spy``; keep DIR out of git, e.g. out/).
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse
import shutil
import statistics
import subprocess
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from datetime import date
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
import torch

from litege_core import __version__
from litege_core.arrays import frozen
from litege_core.canonical import canonicalize_bbox_many
from litege_core.evaluation.speed import (
    cpu_name,
    device_sync,
    numpy_peak,
    peak_memory,
    time_call,
    torch_cpu_peak,
)
from litege_core.learned import Predictor, load_shipped
from litege_core.learned.describe import shape_samples
from litege_core.learned.state import ShapeRecord
from litege_core.shape import Shape
from litege_core.synth import families, generate_shape
from litege_core.variants import isotropic_remesh, point_cloud

STAGES = (
    "sampling",
    "canonicalize",
    "UDF",
    "PCA",
    "shape MLP",
    "point features",
    "head",
)
WORKLOADS = ("1 pair", "distance field", "64 × 1 query", "1K × 1K")
SLUG = {"1 pair": "pair", "distance field": "field", "64 × 1 query": "batch64", "1K × 1K": "matrix"}


@dataclass
class Workload:
    name: str
    shapes: list[Shape]
    sources: list[Any]
    targets: list[Any]
    note: str


def make_workloads(wanted: Sequence[str] = WORKLOADS) -> dict[str, Workload]:
    """The ``wanted`` workloads (the 1K × 1K mesh needs pymeshlab to remesh: built only when
    asked for)."""
    names = families("quadruped")
    generated = [
        generate_shape("quadruped", names[i % len(names)], 2_000_000 + i) for i in range(8)
    ]
    clouds = [
        Shape.from_arrays(point_cloud(g.vertices, g.faces, 2000, i).points)
        for i, g in enumerate(generated)
    ]
    batch = [clouds[i % 8] for i in range(64)]
    workloads = {
        "1 pair": Workload("1 pair", [clouds[1]], [[0]], [[1]], "2000-point cloud"),
        "distance field": Workload(
            "distance field", [clouds[1]], [[0]], [None], "2000-point cloud, 1 → 2000"
        ),
        "64 × 1 query": Workload(
            "64 × 1 query", batch, [[0]] * 64, [[1]] * 64, "64 clouds of 2000 points"
        ),
    }
    if "1K × 1K" in wanted:
        dog = generate_shape("quadruped", "dog", 2_000_000)
        remeshed = isotropic_remesh(dog.vertices, dog.faces, 5000)
        mesh = Shape.from_arrays(remeshed.vertices, remeshed.faces)
        rng = np.random.default_rng(0)
        src = rng.choice(mesh.n_points, 1000, replace=False)
        dst = rng.choice(mesh.n_points, 1000, replace=False)
        workloads["1K × 1K"] = Workload(
            "1K × 1K", [mesh], [src], [dst], f"{mesh.n_points}-vertex mesh, 1000 × 1000"
        )
    return {name: workloads[name] for name in WORKLOADS if name in wanted}


# --------------------------------------------------------------------------- the stages


def stage_functions(predictor: Predictor, work: Workload) -> list[tuple[str, Callable]]:
    """The stages of one end-to-end run, as ``(name, fn(context) -> None)`` in order; each
    reads what earlier stages left in the shared ``context`` dict."""
    engine = predictor.engine

    def sampling(c: dict) -> None:
        c["samples"] = [shape_samples(s, predictor.n_mesh_samples, 0) for s in work.shapes]

    def canonicalize(c: dict) -> None:
        batch = canonicalize_bbox_many(c["samples"], predictor.device)
        c["transforms"], c["clouds"] = batch.transforms, batch.clouds

    def udf(c: dict) -> None:
        c["udf"] = engine.udf(c["clouds"])

    def pca(c: dict) -> None:
        with torch.no_grad():
            centred = c["udf"] - engine.mean
            codes = centred @ engine._components_t
            residual = engine._residual(centred, codes)
        c["descriptors"] = codes.cpu().numpy().astype(np.float32)
        c["residuals"] = residual.cpu().numpy().astype(np.float64)

    def shape_mlp(c: dict) -> None:
        records = [
            ShapeRecord(
                shape_id=shape.content_hash,
                bundle_hash=predictor.bundle.content_hash,
                transform=c["transforms"][b],
                descriptor=frozen(c["descriptors"][b]),
                residual=float(c["residuals"][b]),
                seed=0,
            )
            for b, shape in enumerate(work.shapes)
        ]
        c["states"] = predictor.restore_many(work.shapes, records)

    def features(c: dict) -> None:
        count = len(c["states"])
        resolved = predictor._resolve_many(
            c["states"] * 2,
            list(work.sources) + list(work.targets),
            ["source"] * count + ["target"] * count,
        )
        c["blocks"] = list(zip(resolved[:count], resolved[count:], strict=True))

    def head(c: dict) -> None:
        c["out"] = predictor.evaluate_blocks(c["blocks"])

    return [
        ("sampling", sampling),
        ("canonicalize", canonicalize),
        ("UDF", udf),
        ("PCA", pca),
        ("shape MLP", shape_mlp),
        ("point features", features),
        ("head", head),
    ]


def end_to_end(predictor: Predictor, work: Workload) -> list:
    states = predictor.register_many(work.shapes)
    return predictor.distances_many(states, work.sources, work.targets)


def check_against_api(predictor: Predictor, work: Workload) -> None:
    context: dict = {}
    for _, fn in stage_functions(predictor, work):
        fn(context)
    api = end_to_end(predictor, work)
    for state, mine, theirs in zip(context["states"], context["out"], api, strict=True):
        mine = (np.asarray(mine, np.float64) / state.transform.scale).astype(np.float32)
        np.testing.assert_allclose(mine, theirs, rtol=1e-5, atol=1e-6)


def profile_stages(predictor: Predictor, work: Workload, runs: int) -> dict[str, Any]:
    """Median CPU ms per stage, per-stage allocator peaks and the end-to-end figures."""
    stages = stage_functions(predictor, work)
    cpu: dict[str, list[float]] = {name: [] for name, _ in stages}
    sync = device_sync(predictor.device)
    clock = time.process_time if sync is None else time.perf_counter  # GPU: wall, synced
    for run in range(runs + 1):
        context: dict = {}
        for name, fn in stages:
            start = clock()
            fn(context)
            if sync is not None:
                sync()
            if run:  # run 0 warms up
                cpu[name].append(1000.0 * (clock() - start))
    numpy_mb: dict[str, float] = {}
    torch_mb: dict[str, float] = {}
    context = {}
    for name, fn in stages:  # numpy peaks, stage by stage
        _, numpy_mb[name] = numpy_peak(partial(fn, context))
    context = {}
    for name, fn in stages:  # torch allocator peaks (a separate run: see speed.py)
        _, torch_mb[name] = torch_cpu_peak(partial(fn, context))
    timing = time_call(lambda: end_to_end(predictor, work), runs=runs, warmup=1, sync=sync)
    total = peak_memory(lambda: end_to_end(predictor, work), predictor.device)
    return {
        "cpu_ms": {name: statistics.median(v) for name, v in cpu.items()},
        "numpy_mb": {k: v / 2**20 for k, v in numpy_mb.items()},
        "torch_mb": {k: v / 2**20 for k, v in torch_mb.items()},
        "e2e_cpu_ms": timing.cpu_ms,
        "e2e_wall_ms": timing.wall_ms,
        "peak_numpy_mb": total.numpy_mb,
        "peak_torch_mb": total.torch_mb,
        "peak_cuda_mb": total.cuda_mb,
    }


# --------------------------------------------------------------------------- flame graphs


def flamegraphs(directory: Path, loops: int) -> list[str]:
    """One py-spy SVG per workload (baseline configuration); returns the written paths."""
    py_spy = shutil.which("py-spy") or str(Path(sys.executable).with_name("py-spy"))
    if not Path(py_spy).exists():
        print("py-spy not found (pip install py-spy): no flame graphs", file=sys.stderr)
        return []
    directory.mkdir(parents=True, exist_ok=True)
    written = []
    for name in WORKLOADS:
        target = directory / f"{SLUG[name]}.svg"
        command = [
            py_spy,
            "record",
            "--rate",
            "400",
            "--nonblocking",
            "--output",
            str(target),
            "--",
            sys.executable,
            __file__,
            "--loop",
            SLUG[name],
            "--loops",
            str(loops),
        ]
        subprocess.run(command, check=True, capture_output=True)
        written.append(str(target))
    return written


def loop_workload(slug: str, loops: int) -> None:
    """Child process of :func:`flamegraphs`: one workload end to end, ``loops`` times."""
    torch.set_num_threads(1)
    name = next(k for k, v in SLUG.items() if v == slug)
    work = make_workloads([name])[name]
    predictor = Predictor(load_shipped("quadrupeds"), fusion="none")
    for _ in range(loops):
        end_to_end(predictor, work)


# --------------------------------------------------------------------------- report


def report(
    results: dict[str, dict[str, dict[str, Any]]],
    configs: Sequence[str],
    workloads: dict[str, Workload],
    runs: int,
    command: str,
    svgs: Sequence[str],
    device: str = "cpu",
) -> str:
    lines = ["### Where the time and the memory go: predictor stage profile\n"]
    gpu = f", GPU {torch.cuda.get_device_name(0)}" if device.startswith("cuda") else ""
    lines.append(
        f"- date {date.today()}; {cpu_name()}, {os.cpu_count()} logical CPUs (shared with "
        f"other jobs){gpu}, torch {torch.__version__} with 1 thread, numpy {np.__version__}, "
        f"litege {__version__}; model `quadrupeds` on `{device}`; command `{command}`"
    )
    lines.append(
        "- workloads (preprocessing included): "
        + "; ".join(f"**{w.name}**: {w.note}" for w in workloads.values())
    )
    lines.append(
        f"- time: median process CPU ms of each stage over {runs} runs after a warm-up (stages "
        "run as `register_many` + `distances_many` run them; the script checks it gets the "
        "same distances); end to end: the public calls, CPU and wall ms"
    )
    lines.append(
        "- memory: allocator-exact peak MB above the stage's start, numpy (tracemalloc) + "
        "torch CPU allocator (profiler memory events); not RSS"
    )
    if device != "cpu":
        lines.append(
            "- on the GPU a stage's ms is wall time up to a `torch.cuda.synchronize()` after it "
            "(the kernels it queued included); whole workload: CUDA allocator peak as well"
        )
    if svgs:
        lines.append(f"- flame graphs (py-spy, baseline configuration): {', '.join(svgs)}")
    for config in configs:
        per = results[config]
        lines.append(f"\n**configuration `{config}`** (precision / descriptor lattice)\n")
        lines.append("| stage | " + " | ".join(f"{w} ms" for w in per) + " |")
        lines.append("|---|" + "---:|" * len(per))
        for stage in STAGES:
            cells = []
            for w in per:
                ms = per[w]["cpu_ms"][stage]
                share = 100.0 * ms / max(sum(per[w]["cpu_ms"].values()), 1e-9)
                cells.append(f"{ms:.2f} ({share:.0f} %)")
            lines.append(f"| {stage} | " + " | ".join(cells) + " |")
        lines.append(
            "| **sum of stages** | "
            + " | ".join(f"**{sum(per[w]['cpu_ms'].values()):.2f}**" for w in per)
            + " |"
        )
        lines.append(
            "| end to end, CPU / wall | "
            + " | ".join(f"{per[w]['e2e_cpu_ms']:.2f} / {per[w]['e2e_wall_ms']:.2f}" for w in per)
            + " |"
        )
        lines.append("")
        lines.append("| stage | " + " | ".join(f"{w} MB numpy + torch" for w in per) + " |")
        lines.append("|---|" + "---:|" * len(per))
        for stage in STAGES:
            lines.append(
                f"| {stage} | "
                + " | ".join(
                    f"{per[w]['numpy_mb'][stage]:.2f} + {per[w]['torch_mb'][stage]:.2f}"
                    for w in per
                )
                + " |"
            )
        lines.append(
            "| **whole workload** | "
            + " | ".join(
                f"**{per[w]['peak_numpy_mb']:.1f} + {per[w]['peak_torch_mb']:.1f}**"
                + (
                    ""
                    if per[w]["peak_cuda_mb"] is None
                    else f" (CUDA {per[w]['peak_cuda_mb']:.1f})"
                )
                for w in per
            )
            + " |"
        )
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=7)
    parser.add_argument(
        "--config",
        action="append",
        help="PRECISION/LATTICE, repeatable (default: float32/full, auto/full, auto/stride2)",
    )
    parser.add_argument("--workload", action="append", choices=list(SLUG.values()))
    parser.add_argument("--device", default="cpu", help="cpu or cuda (stages timed by wall)")
    parser.add_argument("--flamegraph", metavar="DIR", help="write py-spy SVGs into DIR")
    parser.add_argument("--flamegraph-loops", type=int, default=20)
    parser.add_argument("--loop", choices=list(SLUG.values()), help=argparse.SUPPRESS)
    parser.add_argument("--loops", type=int, default=20, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.loop:
        loop_workload(args.loop, args.loops)
        return
    torch.set_num_threads(1)
    configs = args.config or ["float32/full", "auto/full", "auto/stride2"]
    wanted = [k for k in WORKLOADS if not args.workload or SLUG[k] in args.workload]
    workloads = make_workloads(wanted)
    bundle = load_shipped("quadrupeds", args.device)
    results: dict[str, dict[str, dict[str, Any]]] = {}
    for config in configs:
        precision, _, lattice = config.partition("/")
        predictor = Predictor(
            bundle,
            args.device,
            precision=precision,
            descriptor_lattice=lattice or "full",
            fusion="none",
        )
        label = f"{predictor.precision}/{predictor.descriptor_lattice}"
        if precision == "auto":
            label = f"auto → {label}"
        results[label] = {}
        for name, work in workloads.items():
            check_against_api(predictor, work)
            results[label][name] = profile_stages(predictor, work, args.runs)
            print(f"{label} {name}: done", file=sys.stderr, flush=True)
    svgs = flamegraphs(Path(args.flamegraph), args.flamegraph_loops) if args.flamegraph else []
    command = "python scripts/profile_predictor.py " + " ".join(sys.argv[1:])
    print(report(results, list(results), workloads, args.runs, command.strip(), svgs, args.device))


if __name__ == "__main__":
    main()
