"""Render the README's figures with the ``litege render`` commands into ``docs/images/``.

Usage::

    .venv/bin/python scripts/render_docs.py [--out docs/images] [--matching-model quadrupeds]

Writes ``heatmap.png`` (``litege render``: predicted geodesic distances on a procedural dog
from its nose, isolines, and the geodesic path from the nose to a front paw) and
``match.png`` (``litege render-match``: a procedural dog's colours carried to a procedural
cat through the predicted matches). The shapes are generated (``litege_core.synth``, fixed
seeds), so the figures are reproducible; each PNG stays under 200 KB. The match figure
needs a matching model; without one it is skipped with a message.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np
import trimesh

from litege_core.cli import main as litege
from litege_core.synth import generate_shape

MAX_BYTES = 200 * 1024


def _export(directory: Path, family: str, seed: int) -> tuple[Path, np.ndarray]:
    shape = generate_shape("quadruped", family, seed)
    path = directory / f"{family}.obj"
    trimesh.Trimesh(shape.vertices, shape.faces, process=False).export(path)
    return path, np.asarray(shape.vertices)


def _check(path: Path) -> None:
    size = path.stat().st_size
    print(f"{path}: {size / 1024:.0f} KB")
    if size > MAX_BYTES:
        raise SystemExit(f"{path} is larger than {MAX_BYTES // 1024} KB")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("docs/images"))
    parser.add_argument("--matching-model", default="quadrupeds")
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)

    with tempfile.TemporaryDirectory() as tmp:
        directory = Path(tmp)
        dog, vertices = _export(directory, "dog", 11)
        cat, _ = _export(directory, "cat", 11)
        # nose: the frontmost vertex along the body axis (+z); paw: the lowest front vertex
        nose = int(np.argmax(vertices[:, 2]))
        front = vertices[:, 2] > np.quantile(vertices[:, 2], 0.6)
        paw = int(np.flatnonzero(front)[np.argmin(vertices[front, 1])])

        heatmap = args.out / "heatmap.png"
        render = ["render", str(dog), "--source", str(nose), "--path", f"{nose},{paw}"]
        code = litege([*render, "--size", "560x400", "-o", str(heatmap)])
        if code:
            return code
        _check(heatmap)

        match = args.out / "match.png"
        render_match = ["render-match", str(dog), str(cat), "--model", args.matching_model]
        code = litege([*render_match, "--size", "400x320", "-o", str(match)])
        if code:
            print(
                f"match.png skipped: matching model {args.matching_model!r} unavailable",
                file=sys.stderr,
            )
            return code
        _check(match)
    return 0


if __name__ == "__main__":
    sys.exit(main())
