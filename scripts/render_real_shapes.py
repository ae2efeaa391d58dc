"""Render posed real training shapes (rigged animals, MakeHuman bodies) to PNG, print mesh
statistics and optionally time the exact ground truth of a dataset shape.

Usage::

    .venv/bin/python scripts/render_real_shapes.py --out out/rigged [--per-family 4]
        [--families Horse,Stag,makehuman] [--time 3] [--train-data ../shared/train-data]

Writes ``<family>.png`` (a row of ``--per-family`` shapes, three-quarter view, seeds 0, 1, …)
and prints one line per shape: vertices, faces, smallest angle, Euler characteristic, clip or
body parameters, generation seconds. With ``--time N`` it also computes the exact (MMP) rows of
the first ``N`` shapes of each family from the sources a dataset uses (48 farthest-point + 16
random) and reports seconds per shape.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from litege_core.datasets.build import exact_distance_rows, shape_sources
from litege_core.datasets.factories import train_data_root
from litege_core.synth import makehuman, meshops, rigged


def _generate(root: Path, family: str, seed: int) -> tuple[np.ndarray, np.ndarray, str]:
    if family == "makehuman":
        model = makehuman.cached_makehuman(str(root / "makehuman"))
        vertices, faces, draw = makehuman.posed_human(model, seed)
        label = f"g{draw.gender:.1f} m{draw.muscle:.1f} w{draw.weight:.1f}"
        return vertices, faces, label
    animal = rigged.cached_model(str(rigged.animal_path(root, family)), family)
    vertices, faces, pose = rigged.posed_animal(animal, seed)
    body = "x".join(f"{b:.2f}" for b in pose.body_scale)
    return vertices, faces, f"{pose.clip} t={pose.time:.2f} body {body}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="out/rigged")
    parser.add_argument("--train-data", default=None)
    parser.add_argument("--families", default=",".join((*rigged.ANIMALS, "makehuman")))
    parser.add_argument("--per-family", type=int, default=4)
    parser.add_argument("--time", type=int, default=0, help="shapes per family to time")
    args = parser.parse_args()

    from litege_core.render.figures import render_surface, side_by_side, titled

    root = train_data_root(args.train_data)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    timings: list[float] = []
    for family in args.families.split(","):
        images = []
        for seed in range(args.per_family):
            start = time.perf_counter()
            vertices, faces, label = _generate(root, family, seed)
            seconds = time.perf_counter() - start
            report = meshops.manifold_report(vertices, faces)
            print(
                f"{family:12s} seed {seed}: V={len(vertices)} F={len(faces)} "
                f"min angle {report.min_angle:.1f}° euler {report.euler} ok={report.ok} "
                f"{label} ({seconds:.1f} s)"
            )
            size = (300, 360) if family == "makehuman" else (360, 280)
            image = render_surface(vertices, faces, size=size, view="three_quarter", up_axis=1)
            images.append(titled(image, f"{family} #{seed}", label))
            if seed < args.time:
                sources = shape_sources(vertices, 48, 16, seed)
                start = time.perf_counter()
                rows = exact_distance_rows(vertices, faces, sources)
                timings.append(time.perf_counter() - start)
                assert np.isfinite(rows).all()
                print(f"    exact rows (64 sources): {timings[-1]:.1f} s")
        side_by_side(images).save(out / f"{family}.png")
    if timings:
        print(f"exact ground truth: {np.mean(timings):.1f} s/shape over {len(timings)} shapes")


if __name__ == "__main__":
    main()
