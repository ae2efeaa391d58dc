"""The "done when" run of issue 16 ("Train on your own collection"): 40 real-looking meshes the
code never trained on → ``litege train geodesic --meshes DIR --out BUNDLE --init quadrupeds
--time-budget 30`` → the bundle served by ``litege geodesic --model BUNDLE``, compared with the
shipped model on the held-out files of the collection.

The collection is made under ``--out`` (never in the repository) from the licence-clean
meshes of the train-data directory (``$LITEGE_TRAIN_DATA`` or ``../shared/train-data``, see
its README): posed, remeshed rigged animals (:func:`litege_core.synth.rigged.posed_animal`:
the 11 Quaternius animals and the Khronos fox, at seeds ``--seed-offset + k``, far from any
dataset preset's seeds; written as OBJ, PLY and OFF) plus the static cat, koala and Spot
meshes, with a ``CREDITS.md`` that the model card quotes. The shipped models were trained on
procedural shapes only.

Prints a markdown section (machine, date, timings, the held-out comparison) on stdout;
``--benchmarks`` also writes it into BENCHMARKS.md (section ``train-folder``). The command's
progress goes to stderr.

Usage:
    nice -n 5 .venv/bin/python scripts/bench_train_folder.py --benchmarks \
        > out/bench-train-folder/section.md 2> out/bench-train-folder/log.txt
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import subprocess
import sys
import time
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
STATIC = {
    "cat.obj": "odedstein-meshes/cat-low-resolution.obj",
    "koala.obj": "odedstein-meshes/koala_low_resolution.obj",
    "spot.obj": "odedstein-meshes/spot.obj",
}
CREDITS = """\
- Quaternius "Ultimate Animated Animals" (Alpaca, Bull, Cow, Deer, Donkey, Fox, Horse, Husky,
  ShibaInu, Stag, Wolf): CC0, by Quaternius (posed and remeshed here).
- Fox: model by PixelMannen (CC0); rigging and animation by @tomkranis (CC BY 4.0); glTF
  conversion by @AsoboStudio and @scurest (CC BY 4.0) (posed and remeshed here).
- "Cat" by billyd (thingiverse.com/thing:1565405), CC BY 4.0; remeshed by Oded Stein
  (odedstein-meshes), CC BY 4.0.
- "Koala" by YahooJAPAN (thingiverse.com/thing:182225), CC BY 3.0; remeshed by Oded Stein
  (odedstein-meshes), CC BY 3.0.
- Spot by Keenan Crane, public domain.
"""


def train_data_root(path: str | None) -> Path:
    return Path(path or os.environ.get("LITEGE_TRAIN_DATA") or ROOT.parent / "shared/train-data")


def make_collection(folder: Path, data: Path, n_meshes: int, seed_offset: int) -> list[str]:
    """Write the collection (skipping files already there); returns the file names."""
    import trimesh

    from litege_core.synth.rigged import ANIMALS, animal_path, cached_model, posed_animal

    folder.mkdir(parents=True, exist_ok=True)
    (folder / "CREDITS.md").write_text(CREDITS)
    names = []
    for name, source in STATIC.items():
        if not (folder / name).exists():
            shutil.copyfile(data / source, folder / name)
        names.append(name)
    suffixes = ("obj", "ply", "off")
    for k in range(n_meshes - len(STATIC)):
        animal = ANIMALS[k % len(ANIMALS)]
        seed = seed_offset + k
        name = f"{animal.lower()}-{seed}.{suffixes[k % 3]}"
        names.append(name)
        if (folder / name).exists():
            continue
        model = cached_model(str(animal_path(data, animal)), animal)
        vertices, faces, _ = posed_animal(model, seed)
        trimesh.Trimesh(vertices, faces, process=False).export(folder / name)
        print(f"posed {name}: {len(vertices)} vertices", file=sys.stderr)
    return names


def machine() -> str:
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    load = ", ".join(f"{x:.1f}" for x in os.getloadavg())
    return f"{cpu}, {os.cpu_count()} cores (load average {load} at the start)"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="out/bench-train-folder")
    parser.add_argument("--train-data", default=None)
    parser.add_argument("--meshes", type=int, default=40)
    parser.add_argument("--seed-offset", type=int, default=7_000_000)
    parser.add_argument("--init", default="quadrupeds")
    parser.add_argument("--budget", type=float, default=30.0, help="minutes")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--keep", action="store_true", help="resume the data of an earlier run")
    parser.add_argument("--benchmarks", action="store_true", help="write into BENCHMARKS.md")
    args = parser.parse_args()

    out = Path(args.out)
    folder, bundle = out / "meshes", out / "bundle"
    start = time.perf_counter()
    names = make_collection(folder, train_data_root(args.train_data), args.meshes, args.seed_offset)
    collection_seconds = time.perf_counter() - start
    if bundle.exists() and not args.keep:
        shutil.rmtree(bundle)
    where = machine()
    date = datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC")
    command = [
        "litege",
        "train",
        "geodesic",
        "--meshes",
        str(folder),
        "--out",
        str(bundle),
        "--init",
        args.init,
        "--time-budget",
        f"{args.budget:g}",
        "--workers",
        str(args.workers),
    ]
    start = time.perf_counter()
    result = subprocess.run(
        [sys.executable, "-m", "litege_core.cli", *command[1:]],
        stdout=subprocess.PIPE,
        text=True,
        check=True,
    )
    wall = time.perf_counter() - start
    summary = json.loads(result.stdout)

    test_file = next(n for n in names if n.endswith(".ply"))
    start = time.perf_counter()
    served = subprocess.run(
        [
            sys.executable,
            "-m",
            "litege_core.cli",
            "geodesic",
            str(folder / test_file),
            "--sources",
            "0,1,2",
            "--model",
            str(bundle),
            "-o",
            str(out / "served.npy"),
        ],
        stdout=subprocess.PIPE,
        text=True,
        check=True,
    )
    serve_seconds = time.perf_counter() - start
    served_report = json.loads(served.stdout)
    distances = np.load(out / "served.npy")

    seconds = summary["seconds"]
    data, training, held = summary["data"], summary["training"], summary["held_out"]
    evaluation = (bundle / "evaluation.md").read_text().strip()
    means = held["mean_over_settings"]
    new = next(k for k in means if k.endswith("(this bundle)"))
    verdict = "beats" if held["beats_reference"] else "does NOT beat"
    lines = [
        "### Train on your own collection: 40 unseen real-looking meshes, one command",
        "",
        f"`scripts/bench_train_folder.py`, {date}, {where}; other jobs shared the CPU.",
        "",
        f"- Collection: {len(names)} meshes ({len(names) - len(STATIC)} posed, remeshed "
        f"Quaternius / Khronos animals at seeds {args.seed_offset}+, cat, koala, Spot; made in "
        f"{collection_seconds:.0f} s, not timed below), split by file "
        f"{data['files']['train']} train / {data['files']['val']} val / "
        f"{data['files']['test']} test.",
        f"- Command: `{' '.join(command)}`: **{wall / 60:.1f} min** wall clock "
        f"(budget {args.budget:g} min; limit 45 min).",
        "- Phases (s): "
        + ", ".join(f"{k} {v:.0f}" for k, v in seconds.items() if k != "total")
        + f"; total {seconds['total']:.0f}.",
        f"- Data: {data['shapes']['train']} of {data['planned_shapes']['train']} planned "
        f"training shapes built within the data share of the budget, "
        f"{data['shapes']['val']} val, {data['shapes']['test']} test shapes "
        f"({data['augmentation']}), exact ground truth.",
        f"- Training: fine-tuned from `{training['init']}`, {training['steps']} steps in "
        f"{training['epochs']} epochs (best {training['best_epoch']}), stopped by budget: "
        f"{training['stopped_by_budget']}; validation mean {training['val_mean_error']:.2f}.",
        f"- Served: `litege geodesic {test_file} --sources 0,1,2 --model BUNDLE` → "
        f"{served_report['shape']} distances (finite: {bool(np.isfinite(distances).all())}), "
        f"{serve_seconds:.1f} s including start-up.",
        f"- Held-out ({held['n_shapes']} shapes of the test files, mean over settings): "
        f"this bundle **{means[new]:.2f}** vs {held['reference']} "
        f"**{means[held['reference']]:.2f}**: the new bundle {verdict} the shipped model.",
        "",
        evaluation,
    ]
    section = "\n".join(lines) + "\n"
    print(section)
    (out / "section.md").write_text(section)
    if args.benchmarks:
        sys.path.insert(0, str(ROOT / "scripts"))
        from update_benchmarks import write_section

        write_section("train-folder", section)


if __name__ == "__main__":
    main()
