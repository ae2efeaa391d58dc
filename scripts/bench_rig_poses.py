"""Does posing a collection's rigged files help the model trained on it? (``litege train
geodesic --meshes``, its rigged glTF files as stored, or posed by their own clips with
``--poses``)

The 12 rigged, animated animals of the train-data directory (``$LITEGE_TRAIN_DATA`` or
``../shared/train-data``: the 11 Quaternius ``.gltf`` files and the Khronos ``Fox.glb``) are
linked into ``OUT/rigs``. Two bundles are trained from scratch on that folder, side by side
(one process each, the same budget, seed and file split, so both hold out the same animals):
``OUT/posed`` (``--poses``: each shape a pose drawn in one of its file's clips) and
``OUT/static`` (the default: every file as stored). From scratch, so that what the shipped
models already know of these animals does not decide. Both are then evaluated side by side with
``scripts/eval_real_ablation.py``, the network alone:

* on the posed run's held-out test shapes (poses of the held-out animals: unseen poses of
  unseen files, the case the option is for);
* on TOSCA (real animals of the dev set: ``--no-tosca`` leaves it out).

Prints a markdown subsection (``###``) and keeps it as ``OUT/section.md``. The BENCHMARKS.md
section ``rig-poses`` holds the prose (title, what it found) and one such subsection per seed,
written with ``scripts/update_benchmarks.py``'s ``write_section`` (as on 2026-12-02, seeds 0
and 1). Progress goes to stderr.

Usage:
    nice .venv/bin/python scripts/bench_rig_poses.py [--budget 20] [--seed 0] \\
        2> out/bench-rig-poses/log.txt
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import time
from datetime import UTC, datetime
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def train_data_root(path: str | None) -> Path:
    return Path(path or os.environ.get("LITEGE_TRAIN_DATA") or ROOT.parent / "shared/train-data")


def link_rigs(folder: Path, data: Path) -> list[str]:
    """Link the rigged animals of ``data`` into ``folder``; returns the file names."""
    from litege_core.synth.rigged import ANIMALS, animal_path

    folder.mkdir(parents=True, exist_ok=True)
    names = []
    for animal in ANIMALS:
        source = animal_path(data, animal).resolve()
        name = f"{animal}{source.suffix}"
        if not (folder / name).exists():
            (folder / name).symlink_to(source)
        names.append(name)
    return names


def train(
    folder: Path, out: Path, budget: float, seed: int, extra: list[str]
) -> subprocess.Popen[str]:
    """Start one ``litege train geodesic --meshes`` run (its summary JSON on stdout)."""
    build = out.with_name(f"{out.name}-build")  # the run's dataset and checkpoints
    for path in (out, build):
        if path.exists():
            shutil.rmtree(path)
    command = [sys.executable, "-m", "litege_core.cli", "train", "geodesic"]
    command += ["--meshes", str(folder), "--out", str(out), "--work", str(build)]
    command += ["--time-budget", f"{budget:g}"]
    command += ["--workers", "1", "--eval-shapes-per-mesh", "8", "--seed", str(seed), *extra]
    return subprocess.Popen(command, stdout=subprocess.PIPE, text=True)


def evaluate(args: list[str]) -> str:
    """``scripts/eval_real_ablation.py ARGS``'s markdown."""
    command = [sys.executable, str(ROOT / "scripts" / "eval_real_ablation.py"), *args]
    return subprocess.run(command, stdout=subprocess.PIPE, text=True, check=True).stdout.strip()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="out/bench-rig-poses")
    parser.add_argument("--train-data", default=None)
    parser.add_argument("--budget", type=float, default=20.0, help="minutes per run")
    parser.add_argument("--seed", type=int, default=0, help="file split and training seed")
    parser.add_argument("--cache", default="out/exact-cache", help="TOSCA's exact rows")
    parser.add_argument("--no-tosca", action="store_true")
    args = parser.parse_args()

    out = Path(args.out)
    rigs = out / "rigs"
    names = link_rigs(rigs, train_data_root(args.train_data))
    date = datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC")
    cpu = os.cpu_count()
    start = time.perf_counter()
    runs = {
        "posed": train(rigs, out / "posed", args.budget, args.seed, ["--poses"]),
        "static": train(rigs, out / "static", args.budget, args.seed, []),
    }
    summaries = {}
    for label, process in runs.items():
        stdout, _ = process.communicate()
        if process.returncode != 0:
            raise SystemExit(f"the {label} run failed ({process.returncode})")
        summaries[label] = json.loads(stdout)
    wall = time.perf_counter() - start
    models = [f"{out / label}=trained {label}" for label in runs]
    model_args = [arg for model in models for arg in ("--model", model)]
    common = ["--sources", "12", "--settings", "mesh,cloud_2000,cloud_300", "--no-baselines"]
    held_out = evaluate(
        [
            *model_args,
            "--dataset",
            str(out / "posed-build" / "data"),
            *common,
            "--synthetic",
            "0",
        ]
    )
    tosca = (
        ""
        if args.no_tosca
        else evaluate(
            [*model_args, "--set", "tosca", *common, "--synthetic", "0", "--cache", args.cache]
        )
    )
    posed = summaries["posed"]
    files = posed["data"]["files"]
    lines = [
        f"### Rigged files posed by their own clips, or as stored ({date[:10]})",
        "",
        f"`scripts/bench_rig_poses.py --budget {args.budget:g} --seed {args.seed}`, {date}, "
        f"{cpu} logical CPUs "
        "(the two runs side by side, one process each).",
        "",
        f"- Folder: the {len(names)} rigged, animated train-data animals ({', '.join(names)}), "
        f"split by file {files['train']} train / {files['val']} val / {files['test']} test "
        "(the same split in both runs).",
        "- Both from scratch (no `--init`), the same budget and seed; `posed`: `--poses`, each "
        "shape at a time drawn in one of its file's clips; `static`: every file as stored. "
        f"Wall clock for both: {wall / 60:.1f} min.",
    ]
    for label, summary in summaries.items():
        data, training = summary["data"], summary["training"]
        lines.append(
            f"- `{label}`: {data['shapes']['train']} training shapes, {training['steps']} steps "
            f"({training['epochs']} epochs, best {training['best_epoch']}), validation mean "
            f"{training['val_mean_error']:.2f} (on its own validation shapes)."
        )
    lines += [
        "",
        "Held out: poses of the test-split animals (the `posed` run's test shapes), network "
        "alone, exact ground truth:",
        "",
        held_out,
    ]
    if tosca:
        lines += ["", "TOSCA (real animals, dev set), network alone:", "", tosca]
    section = "\n".join(lines) + "\n"
    print(section)
    (out / "section.md").write_text(section)


if __name__ == "__main__":
    main()
