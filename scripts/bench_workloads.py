"""Every workload a user has, LiteGE side by side with the classical methods in one run, as
ratios (issue 17), with the speed targets checked at the end. Prints markdown.

Usage::

    python scripts/bench_workloads.py [--runs 5] [--exact-sources 20] [--no-cli]
        [--only-methods "LiteGE,LiteGE full head"] [--only-workloads "1K × 1K,distance field"]
        [--warm 3]

``--only-methods`` / ``--only-workloads`` run a subset of the cases (comma-separated names;
a quick look at a few rows: the targets table and the memory check then cover what ran).

Inputs (held-out procedural quadrupeds, test seeds; nothing cached between runs, every timing
includes the preprocessing: registration, k-NN graph, factorisation, solver set-up):

* ``2K cloud``: 2000 area-weighted samples of a procedural dog (``point_cloud``);
* ``5K mesh``: the same dog isotropically remeshed to about 5000 vertices;
* 64 shapes: 8 distinct procedural quadrupeds (5 families), each sent 8 times, as 2K clouds
  or 5K meshes.

Workloads: **one pair**; a **distance field** (1 → every point); **64 shapes × 1 query**
(one pair each); a **1K × 1K** matrix (1000 × 1000 distinct vertices of the 5K mesh);
**1K correspondences** (5K dog → 5K cat, 1000 query vertices).

Methods: LiteGE (:class:`Predictor`, shipped ``quadrupeds``) in nine configurations: the
network alone with the default head and lattice (row ``LiteGE``: float32, ``head="auto"`` and
``descriptor_lattice="auto"``: for the shipped model the distilled small head and the UDF at the
1/8 of the voxels of the ``stride2`` lattice; ``fusion="none"``), the
trained head on that lattice (``head="full"``), the trained network as trained (``head="full"``,
``descriptor_lattice="full"``), the trained head with ``precision="auto"`` (bfloat16 head
product where the CPU has AMX / AVX512-BF16), and ``fusion="graph"`` (the calibrated graph
fusion: row ``LiteGE graph fusion`` is the library's, the CLI's and the service's default
configuration since 2026-11-29, ``fusion="auto"`` on a shipped model) with the default head and
lattice or the trained network; the network alone and the fusion each also with
``precision="int8", embed_precision="int8"`` (the point MLP's ``n × n`` products and the small
head's per-pair product in dynamic int8), and the network alone with
``precision="auto", embed_precision="auto"`` (row ``LiteGE auto precision``: bfloat16 products
where the CPU has AVX512-BF16 / AMX, else float32, the service's
``LITEGE_GEODESIC_PRECISION=auto``);
kNN-graph Dijkstra, point-cloud heat, mesh heat and exact (MMP) through
:class:`litege_core.engines.ClassicalSolver` (``graph``, ``heat``, ``exact``); for
correspondences the ``quadrupeds`` matching model (:class:`MatchingModel`), nearest neighbour
in its aligned frame, and ZoomOut (pyFM) as in ``litege eval matching``. The exact 1K × 1K is
extrapolated from ``--exact-sources`` sources (its build plus per-source time × 1000).

Time: median process CPU time over ``--runs`` rounds after a warm-up round; the rounds
interleave the methods, so load from other jobs hits them alike. With ``--warm N`` each round
also repeats each case N times right after its timed call (a "warm" column: the case with its
own data and weights in the caches; the interleaved figure has the other cases' there, which
costs LiteGE more than kNN Dijkstra). Wall-clock medians are shown
too. The ratio column divides by the kNN Dijkstra time of the same workload and input
(correspondences: by ZoomOut). One torch thread, ``OMP_NUM_THREADS=1``.
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")

import argparse
import platform
import statistics
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import date
from functools import partial
from typing import Any

import numpy as np
import torch

from litege_core import __version__
from litege_core.engines import ClassicalSolver
from litege_core.evaluation.speed import cpu_name, peak_memory
from litege_core.learned import Predictor, load_shipped
from litege_core.learned.numpy_predictor import NumpyPredictor
from litege_core.shape import Shape
from litege_core.synth import families, generate_shape
from litege_core.variants import isotropic_remesh, point_cloud

LITEGE = {
    "LiteGE": ("float32", "auto", "auto", "none", "float32"),
    "LiteGE int8": ("int8", "auto", "auto", "none", "int8"),
    "LiteGE auto precision": ("auto", "auto", "auto", "none", "auto"),
    "LiteGE full head": ("float32", "auto", "full", "none", "float32"),
    "LiteGE full head + full lattice": ("float32", "full", "full", "none", "float32"),
    "LiteGE full head + auto precision": ("auto", "auto", "full", "none", "float32"),
    "LiteGE graph fusion": ("float32", "auto", "auto", "graph", "float32"),
    "LiteGE graph fusion + int8": ("int8", "auto", "auto", "graph", "int8"),
    "LiteGE graph fusion + full head + full lattice": (
        "float32",
        "full",
        "full",
        "graph",
        "float32",
    ),
}
"""Name → (precision, descriptor lattice, head, fusion, embed precision) of each LiteGE
configuration."""
REFERENCE = "kNN Dijkstra"


@dataclass
class Case:
    workload: str
    data: str
    method: str
    fn: Callable[[], object]
    runs: int = 0  # 0: the --runs default
    note: str = ""
    scale: float = 1.0  # extrapolation factor
    offset: Callable[[], float] | None = None
    cpu: list[float] = field(default_factory=list)
    wall: list[float] = field(default_factory=list)
    warm: list[float] = field(default_factory=list)  # CPU ms of back-to-back repeats


def _inputs():
    names = families("quadruped")
    generated = [
        generate_shape("quadruped", names[i % len(names)], 2_000_000 + i) for i in range(8)
    ]
    clouds = [
        Shape.from_arrays(point_cloud(g.vertices, g.faces, 2000, i).points)
        for i, g in enumerate(generated)
    ]
    meshes = []
    for g in generated:
        remeshed = isotropic_remesh(g.vertices, g.faces, 5000)
        meshes.append(Shape.from_arrays(remeshed.vertices, remeshed.faces))
    dog = generate_shape("quadruped", "dog", 2_000_000)
    cat = generate_shape("quadruped", "cat", 2_000_001)
    dog_mesh = isotropic_remesh(dog.vertices, dog.faces, 5000)
    cat_mesh = isotropic_remesh(cat.vertices, cat.faces, 5000)
    return {
        "cloud": Shape.from_arrays(point_cloud(dog.vertices, dog.faces, 2000, 0).points),
        "mesh": Shape.from_arrays(dog_mesh.vertices, dog_mesh.faces),
        "clouds64": [clouds[i % 8] for i in range(64)],
        "meshes64": [meshes[i % 8] for i in range(64)],
        "cat": Shape.from_arrays(cat_mesh.vertices, cat_mesh.faces),
    }


def _classical(shape: Shape, method: str, sources, targets=None):
    return ClassicalSolver(shape, method).distances(sources, targets)


def _classical_batch(shapes: list[Shape], method: str) -> list:
    return [_classical(s, method, [0], [1]) for s in shapes]


def _litege(predictor: Any, shape: Shape, sources, targets=None):
    """A :class:`Predictor` or :class:`NumpyPredictor` (same register / distances calls)."""
    return predictor.distances(predictor.register(shape), sources, targets)


def _litege_batch(predictor: Predictor, shapes: list[Shape]) -> list:
    count = len(shapes)
    return predictor.distances_many(predictor.register_many(shapes), [[0]] * count, [[1]] * count)


def _match(method, x: Shape, y: Shape, queries):
    return method.match(method.prepare(x), method.prepare(y), queries)


def litege_predictors(bundle) -> dict[str, Predictor]:
    """The LiteGE configurations the bundle supports (``small head`` and ``graph fusion``
    need their sidecars)."""
    from litege_core.learned.fusion_calibration import FUSION_CONFIG
    from litege_core.learned.small_head import small_head_config

    has_fusion = bundle.path is not None and (bundle.path / FUSION_CONFIG).is_file()
    return {
        name: Predictor(
            bundle,
            precision=p,
            embed_precision=embed,
            descriptor_lattice=lattice,
            head=head,
            fusion=fusion,
        )
        for name, (p, lattice, head, fusion, embed) in LITEGE.items()
        if (head == "full" or small_head_config(bundle) is not None)
        and (fusion == "none" or has_fusion)
    }


NUMPY_RUNTIMES = {
    "LiteGE numpy": ("auto", "auto"),
    "LiteGE numpy full head + full lattice": ("full", "full"),
}
"""The torch-free runtime (:class:`~litege_core.learned.numpy_predictor.NumpyPredictor`, what
``litege geodesic`` runs on a CPU): one shape at a time, so no ``64 shapes`` rows."""


def numpy_runtimes() -> dict[str, NumpyPredictor]:
    return {
        name: NumpyPredictor.shipped("quadrupeds", head=head, lattice=lattice)
        for name, (head, lattice) in NUMPY_RUNTIMES.items()
    }


def build_cases(args, data) -> list[Case]:
    bundle = load_shipped("quadrupeds")
    predictors = litege_predictors(bundle)
    single: dict[str, Predictor | NumpyPredictor] = {**predictors, **numpy_runtimes()}
    cloud, mesh = data["cloud"], data["mesh"]
    rng = np.random.default_rng(0)
    src = rng.choice(mesh.n_points, 1000, replace=False)
    dst = rng.choice(mesh.n_points, 1000, replace=False)
    far_c = int(np.argmax(np.linalg.norm(cloud.vertices - cloud.vertices[0], axis=1)))
    far_m = int(np.argmax(np.linalg.norm(mesh.vertices - mesh.vertices[0], axis=1)))
    cases: list[Case] = []

    for data_name, shape, far, classical in (
        ("2K cloud", cloud, far_c, {REFERENCE: "graph", "point-cloud heat": "heat"}),
        ("5K mesh", mesh, far_m, {REFERENCE: "graph", "mesh heat": "heat", "exact": "exact"}),
    ):
        for name, predictor in single.items():
            cases.append(
                Case(
                    "one pair",
                    data_name,
                    name,
                    partial(_litege, predictor, shape, [0], [far]),
                )
            )
            cases.append(
                Case(
                    "distance field",
                    data_name,
                    name,
                    partial(_litege, predictor, shape, [0]),
                )
            )
        for label, method in classical.items():
            cases.append(
                Case(
                    "one pair",
                    data_name,
                    label,
                    partial(_classical, shape, method, [0], [far]),
                )
            )
            cases.append(
                Case(
                    "distance field",
                    data_name,
                    label,
                    partial(_classical, shape, method, [0]),
                )
            )

    for data_name, shapes, classical in (
        ("64 × 2K clouds", data["clouds64"], {REFERENCE: "graph", "point-cloud heat": "heat"}),
        (
            "64 × 5K meshes",
            data["meshes64"],
            {REFERENCE: "graph", "mesh heat": "heat", "exact": "exact"},
        ),
    ):
        for name, predictor in predictors.items():
            cases.append(
                Case(
                    "64 shapes × 1 query",
                    data_name,
                    name,
                    partial(_litege_batch, predictor, shapes),
                )
            )
        for label, method in classical.items():
            cases.append(
                Case(
                    "64 shapes × 1 query",
                    data_name,
                    label,
                    partial(_classical_batch, shapes, method),
                    runs=1 if method == "exact" else 0,
                )
            )

    for name, predictor in single.items():
        cases.append(
            Case(
                "1K × 1K",
                "5K mesh",
                name,
                partial(_litege, predictor, mesh, src, dst),
            )
        )
    cases.append(Case("1K × 1K", "5K mesh", REFERENCE, lambda: _classical(mesh, "graph", src, dst)))
    cases.append(
        Case("1K × 1K", "5K mesh", "mesh heat", lambda: _classical(mesh, "heat", src, dst))
    )
    k = max(1, int(args.exact_sources))
    cases.append(
        Case(
            "1K × 1K",
            "5K mesh",
            "exact",
            lambda: _classical(mesh, "exact", src[:k], dst),
            runs=1,
            note=f"extrapolated from {k} sources",
            scale=1000.0 / k,
        )
    )

    if not args.no_matching:
        cases.extend(_matching_cases(data))
    methods = [m.strip() for m in (args.only_methods or "").split(",") if m.strip()]
    workloads = [w.strip() for w in (args.only_workloads or "").split(",") if w.strip()]
    unknown = set(methods) - {c.method for c in cases} | set(workloads) - {
        c.workload for c in cases
    }
    if unknown:
        raise SystemExit(f"unknown methods or workloads: {sorted(unknown)}")
    return [
        case
        for case in cases
        if (not methods or case.method in methods) and (not workloads or case.workload in workloads)
    ]


def _matching_cases(data) -> list[Case]:
    from litege_core.evaluation.matching import (
        LiteGEMethod,
        NearestNeighbourMethod,
        ZoomOutMethod,
    )
    from litege_core.matching import MatchingModel

    model = MatchingModel.load("quadrupeds")
    x, y = data["mesh"], data["cat"]
    queries = np.random.default_rng(1).choice(x.n_points, 1000, replace=False)
    methods = {
        "LiteGE matching": LiteGEMethod(model),
        "NN (aligned)": NearestNeighbourMethod(model),
    }
    try:
        methods["ZoomOut (pyFM)"] = ZoomOutMethod()
    except Exception as exc:  # pyFM missing: the row says so
        print(f"ZoomOut unavailable: {exc}", file=sys.stderr)
    cases = []
    for label, method in methods.items():
        cases.append(
            Case(
                "1K correspondences",
                "5K mesh → 5K mesh",
                label,
                partial(_match, method, x, y, queries),
                runs=1 if label.startswith("ZoomOut") else 0,
            )
        )
    return cases


def run_cases(cases: list[Case], runs: int, warm: int = 0) -> None:
    """Time every case in ``runs`` interleaved rounds after a warm-up round; with ``warm``,
    each round also repeats a case ``warm`` times right after its timed call (the mean CPU
    time of the repeats: the case with its own data and weights in the caches, as a stream of
    queries of one kind meets it), except the one-round cases."""
    rounds = runs + 1
    for r in range(rounds):
        for case in cases:
            wanted = case.runs or runs
            if r > wanted:  # slow cases: fewer rounds (the warm-up round still runs)
                continue
            start_wall, start_cpu = time.perf_counter(), time.process_time()
            case.fn()
            cpu = 1000.0 * (time.process_time() - start_cpu) * case.scale
            wall = 1000.0 * (time.perf_counter() - start_wall) * case.scale
            if r:
                case.cpu.append(cpu)
                case.wall.append(wall)
            if r and warm and not case.runs:
                start_cpu = time.process_time()
                for _ in range(warm):
                    case.fn()
                case.warm.append(1000.0 * (time.process_time() - start_cpu) * case.scale / warm)
        print(f"round {r + 1}/{rounds} done", file=sys.stderr, flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--exact-sources", type=int, default=20)
    parser.add_argument("--no-matching", action="store_true")
    parser.add_argument("--no-cli", action="store_true")
    parser.add_argument("--only-methods", default="", help="comma-separated method names")
    parser.add_argument("--only-workloads", default="", help="comma-separated workload names")
    parser.add_argument(
        "--warm",
        type=int,
        default=0,
        help="also time N back-to-back repeats of each case per round (a 'warm' column)",
    )
    args = parser.parse_args()
    torch.set_num_threads(1)
    data = _inputs()
    cases = build_cases(args, data)
    run_cases(cases, args.runs, args.warm)

    bundle = load_shipped("quadrupeds")
    memory = {}
    ran = {case.method for case in cases}
    configurations = {n: p for n, p in litege_predictors(bundle).items() if n in ran}
    for name, predictor in configurations.items():
        batch = data["clouds64"]

        def query(p: Predictor = predictor, b: list = batch) -> object:
            return p.distances_many(p.register_many(b), [[0]] * len(b), [[1]] * len(b))

        query()  # one-time set-up (the descriptor engine) is not the workload's memory
        memory[name] = peak_memory(query)
    cli = None
    if not args.no_cli:
        from bench_cli import cli_wall_seconds, cloud_300  # scripts/ is sys.path[0]

        cli = cli_wall_seconds(cloud_300(), max(3, args.runs))

    med = {(c.workload, c.data, c.method): c for c in cases}

    def cpu(workload: str, data_name: str, method: str) -> float:
        return statistics.median(med[(workload, data_name, method)].cpu)

    auto = Predictor(bundle, precision="auto", fusion="none").precision
    subset = ""
    if args.only_methods or args.only_workloads:
        subset = f' --only-methods "{args.only_methods}" --only-workloads "{args.only_workloads}"'

    print("### Workloads side by side: LiteGE vs classical methods (issue 17)\n")
    print(
        f"- date {date.today()}; {cpu_name()}, {os.cpu_count()} logical CPUs shared with other "
        f"jobs; python {platform.python_version()}, torch {torch.__version__} (1 thread), "
        f"numpy {np.__version__}, litege {__version__}; OMP_NUM_THREADS=1; "
        f"`precision='auto'` resolves to `{auto}` here"
    )
    print(
        f"- median of {args.runs} interleaved rounds after a warm-up (exact on 64 meshes, the "
        "exact 1K × 1K and ZoomOut: 1 round), preprocessing included, nothing cached between "
        "runs; CPU = process CPU time (the steadier figure on this shared machine), wall in "
        f"brackets; command `python scripts/bench_workloads.py --runs {args.runs} "
        f"--exact-sources {args.exact_sources}{subset}"
        + (f" --warm {args.warm}`" if args.warm else "`")
    )
    if args.warm:
        print(
            f"- warm: the mean CPU time of {args.warm} back-to-back repeats right after each "
            "timed call (median over the rounds; the one-round cases have none): the case "
            "with its own data and weights in the caches, as a stream of queries of one kind "
            "meets it; the interleaved figure has the other cases' data there"
        )
    print(
        "- ratio: the method's CPU time over kNN Dijkstra's on the same workload and input "
        "(correspondences: over ZoomOut); < 1 is faster\n"
    )
    warm_head = " warm CPU ms | warm ratio |" if args.warm else ""
    print(f"| workload | input | method | CPU ms | (wall ms) | ratio |{warm_head} note |")
    print("|---|---|---|---:|---:|---:|" + ("---:|---:|" if args.warm else "") + "---|")
    for case in cases:
        ms = statistics.median(case.cpu)
        wall = statistics.median(case.wall)
        ref_name = "ZoomOut (pyFM)" if case.workload == "1K correspondences" else REFERENCE
        ref = med.get((case.workload, case.data, ref_name))
        ratio = f"{ms / statistics.median(ref.cpu):.2f}×" if ref is not None else "—"
        warm_cells = ""
        if args.warm:
            warm_ms = statistics.median(case.warm) if case.warm else None
            ref_warm = statistics.median(ref.warm) if ref is not None and ref.warm else None
            warm_cells = (
                " — | — |"
                if warm_ms is None
                else f" {warm_ms:.1f} | " + (f"{warm_ms / ref_warm:.2f}× |" if ref_warm else "— |")
            )
        print(
            f"| {case.workload} | {case.data} | {case.method} | {ms:.1f} | ({wall:.1f}) | "
            f"{ratio} |{warm_cells} {case.note} |"
        )

    print("\n**Targets** (2-core shared CPU, one thread, preprocessing included)\n")
    print("| target | configuration | measured | target | met |")
    print("|---|---|---:|---:|---|")
    ref_field = ("distance field", "2K cloud", REFERENCE)
    knn_field = cpu(*ref_field) if ref_field in med else float("nan")
    for name in [*configurations, *(n for n in NUMPY_RUNTIMES if n in ran)]:
        if all(key in med for key in (("one pair", "2K cloud", name), ref_field)):
            pair = cpu("one pair", "2K cloud", name) / knn_field
            print(
                f"| 2K cloud, 1 pair ÷ kNN Dijkstra field | {name} | {pair:.2f}× | ≤ 1.0× | "
                f"{_ok(pair <= 1.0)} |"
            )
        if all(key in med for key in (("distance field", "2K cloud", name), ref_field)):
            field_ratio = cpu("distance field", "2K cloud", name) / knn_field
            print(
                f"| 2K cloud, field ÷ kNN Dijkstra field | {name} | {field_ratio:.2f}× | "
                f"≤ 2.0× | {_ok(field_ratio <= 2.0)} |"
            )
            fields = med[("distance field", "2K cloud", name)].warm, med[ref_field].warm
            if all(fields):
                warm_ratio = statistics.median(fields[0]) / statistics.median(fields[1])
                print(
                    f"| 2K cloud, field ÷ kNN Dijkstra field, warm | {name} | "
                    f"{warm_ratio:.2f}× | ≤ 2.0× | {_ok(warm_ratio <= 2.0)} |"
                )
        if name in memory:
            mem = memory[name].cpu_mb
            print(
                f"| 64 clouds × 1 query, peak memory growth (numpy {memory[name].numpy_mb:.1f} "
                f"+ torch {memory[name].torch_mb:.1f} MB) | {name} | {mem:.1f} MB | ≤ 60 MB | "
                f"{_ok(mem <= 60)} |"
            )
        if ("1K × 1K", "5K mesh", name) in med:
            matrix = cpu("1K × 1K", "5K mesh", name) / 1000.0
            print(
                f"| 1K × 1K on a 5K mesh (CPU s) | {name} | {matrix:.2f} s | ≤ 0.5 s | "
                f"{_ok(matrix <= 0.5)} |"
            )
    if cli is not None:
        print(
            f"| `litege geodesic` on a 300-point cloud (wall s, fresh process) | defaults | "
            f"{cli:.2f} s | ≤ 1.5 s | {_ok(cli <= 1.5)} |"
        )


def _ok(flag: bool) -> str:
    return "yes" if flag else "**no**"


if __name__ == "__main__":
    main()
