"""The paper's Table 1 on this machine: B point clouds (2000 points), one query each,
preprocessing included (canonicalization, UDF-PCA, embeddings), for B = 1, 4, 8, 32, 64, 96;
time and allocator-exact peak memory, on the CPU always and on CUDA whenever it is available.

Usage: python scripts/bench_batch_table.py [--model quadrupeds] [--runs 5] [--threads 1]
           [--precision float32] [--lattice auto] [--no-cuda] [--cuda-udf auto,torch]
Clouds: area-weighted samples of 8 distinct procedural quadrupeds (test seeds), reused
cyclically; nothing is cached between runs. Memory: numpy peak by tracemalloc + torch
CPU-allocator peak by torch.profiler memory events (+ CUDA allocator peak on a GPU), above what
was allocated before the batch: see litege_core.evaluation.speed (not RSS).
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")  # pykdtree's OpenMP and BLAS: one thread

import argparse
import platform
from datetime import date

import torch

from litege_core.evaluation.speed import batch_query_table
from litege_core.learned import Predictor, load_shipped
from litege_core.shape import Shape
from litege_core.synth import families, generate_shape
from litege_core.variants import point_cloud

PAPER_MS = {1: 1.9, 4: 2.0, 8: 2.6, 32: 7.3, 64: 13.4, 96: 19.1}  # RTX A4000, reference only


def _table(predictor: Predictor, clouds: list[Shape], runs: int) -> list[str]:
    rows = batch_query_table(predictor, clouds, runs=runs)
    cuda = predictor.device.type == "cuda"
    head = "| shapes | median ms | ms per shape | CPU ms | numpy peak MB | torch peak MB |"
    rule = "|---:|---:|---:|---:|---:|---:|"
    if cuda:
        head += " CUDA peak MB |"
        rule += "---:|"
    lines = [head + " paper GPU ms |", rule + "---:|"]
    for row in rows:
        line = (
            f"| {row['shapes']} | {row['median_ms']:.1f} | {row['ms_per_shape']:.2f} | "
            f"{row['cpu_ms']:.1f} | {row['numpy_peak_mb']:.1f} | {row['torch_peak_mb']:.1f} |"
        )
        if cuda:
            line += f" {row.get('cuda_peak_mb', 0.0):.1f} |"
        lines.append(line + f" {PAPER_MS[int(row['shapes'])]} |")
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", default="quadrupeds")
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--precision", default="float32", help="Predictor precision")
    parser.add_argument("--lattice", default="auto", help="Predictor descriptor_lattice")
    parser.add_argument("--no-cuda", action="store_true", help="skip the CUDA rows")
    parser.add_argument(
        "--cuda-udf",
        default="auto",
        help="comma-separated UDF backends of the CUDA rows (auto = triton where installed)",
    )
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    names = families("quadruped")
    clouds = []
    for i in range(8):
        shape = generate_shape("quadruped", names[i % len(names)], 2_000_000 + i)
        clouds.append(Shape.from_arrays(point_cloud(shape.vertices, shape.faces, 2000, i).points))
    devices = ["cpu"] + (["cuda"] if torch.cuda.is_available() and not args.no_cuda else [])
    command = (
        f"python scripts/bench_batch_table.py --runs {args.runs} --threads {args.threads}"
        + (f" --precision {args.precision}" if args.precision != "float32" else "")
        + (f" --lattice {args.lattice}" if args.lattice != "auto" else "")
    )
    print(f"### B shapes × 1 query, preprocessing included (paper Table 1 setting), {devices}\n")
    gpu = f", GPU {torch.cuda.get_device_name(0)}" if "cuda" in devices else ", no GPU"
    print(
        f"- date {date.today()}; {os.cpu_count()} logical CPUs {platform.machine()}{gpu}; "
        f"torch {torch.__version__}, {args.threads} thread(s); model `{args.model}`, "
        f"precision `{args.precision}`, descriptor lattice `{args.lattice}`; 2000-point "
        f"clouds; median of {args.runs} runs after 1 warm-up; command `{command}`"
    )
    print(
        "- memory is allocator-exact, above what was allocated before the batch: numpy peak "
        "(tracemalloc) and torch CPU-allocator peak (torch.profiler memory events) from two "
        "runs, their sum bounds the joint peak; CUDA: `max_memory_allocated` "
        "(litege_core.evaluation.speed). CPU ms: process CPU time (steadier than wall time on "
        "this shared machine)"
    )
    print(
        "- the paper's GPU figures (RTX A4000) are shown for reference only: different "
        "hardware, not a like-for-like comparison"
    )
    runs = [("cpu", "auto")] + [("cuda", b) for b in args.cuda_udf.split(",") if "cuda" in devices]
    for device, udf_backend in runs:
        predictor = Predictor(
            load_shipped(args.model, device),
            device,
            precision=args.precision,
            descriptor_lattice=args.lattice,
            fusion="none",
            udf_backend=udf_backend,
        )
        print(
            f"\n**{device}** ({predictor.precision}, lattice {predictor.descriptor_lattice}, "
            f"head {predictor.head}, UDF {predictor.engine.udf.backend.value})\n"
        )
        print("\n".join(_table(predictor, clouds, args.runs)))


if __name__ == "__main__":
    main()
