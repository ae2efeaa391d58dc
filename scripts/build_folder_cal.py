"""Build a fusion-calibration set from a few mesh files outside every training family.

Usage: python scripts/build_folder_cal.py [--train-data ../shared/train-data] [--shapes 8]
    [--out data/folder-cal]
       python scripts/build_folder_cal.py --primitives [cal|test] [--shapes 3]

The graph fusion of a bundle (``scripts/calibrate_fusion.py``) must be fitted on shapes the
network was not trained on, or its gate learns to trust the network more than it should on real
shapes. A bundle fine-tuned on the rigged animals cannot be calibrated on ``data/rigged-cal``;
this set takes the three static train-data meshes that no factory trains on (the cat sculpt,
the koala scan and Spot, in ``odedstein-meshes``), each remeshed ``--shapes`` times with the
folder augmentation (3,000–6,000 vertices, smooth stretches), every shape in the test split,
exact MMP rows from 24 FPS sources. ~2.5 min on one core.

``--primitives`` builds the same kind of set from eight generated solids of no training family
(two tori, a capsule, a sphere, a rod, a thick ring, a box and a cone: :data:`PRIMITIVES`):
shapes the networks do not know, on which the calibration learns when to stop trusting the
network (its veto's OOD limit), in ``data/primitives-cal``. ~1.5 min on one core with
``--shapes 3``. ``--primitives test`` builds ``data/primitives-test`` from six other solids
(:data:`HELD_OUT_SOLIDS`: a vase, an hourglass, a U-bent tube, a twisted bar, an ellipsoid, a
spindle) to evaluate on: never calibrate on it.
"""

from __future__ import annotations

import argparse
import dataclasses
import tempfile
from pathlib import Path

import numpy as np
import trimesh

from litege_core.datasets import build_dataset, folder_spec
from litege_core.datasets.collection import folder_factory
from litege_core.synth.folder import list_meshes

CATEGORY = "static-meshes"
"""The set's category in its manifest: the model card credits its authors by it
(``litege_core.learned.cards.COLLECTION_CREDITS``)."""

CALIBRATION_MESHES = (
    "odedstein-meshes/cat-low-resolution.obj",
    "odedstein-meshes/koala_low_resolution.obj",
    "odedstein-meshes/spot.obj",
)


PRIMITIVES_CATEGORY = "primitives"
PRIMITIVES = {
    "torus": lambda: trimesh.creation.torus(1.0, 0.35, major_sections=64, minor_sections=32),
    "thin-torus": lambda: trimesh.creation.torus(1.0, 0.15, major_sections=96, minor_sections=24),
    "capsule": lambda: trimesh.creation.capsule(height=2.0, radius=0.4, count=[32, 32]),
    "sphere": lambda: trimesh.creation.icosphere(4),
    "rod": lambda: trimesh.creation.cylinder(0.3, 2.5, sections=48),
    "thick-ring": lambda: trimesh.creation.annulus(0.5, 1.0, 0.4, sections=64),
    "box": lambda: trimesh.creation.box((1.0, 0.6, 0.3)),
    "cone": lambda: trimesh.creation.cone(0.6, 1.5, sections=64),
}
"""Name → generated watertight solid of the ``--primitives`` set (remeshed by the folder
augmentation like any mesh file)."""


def _revolved(profile: list[tuple[float, float]]) -> trimesh.Trimesh:
    """The solid of revolution of a ``(radius, height)`` profile about the z axis."""
    return trimesh.creation.revolve(np.asarray(profile, dtype=np.float64), sections=64)


def _bent_tube() -> trimesh.Trimesh:
    """A tube of radius 0.15 bent into a U: a half circle of radius 0.5, two parallel arms 0.7
    apart at their surfaces."""
    tube = trimesh.creation.cylinder(0.15, 4.0, sections=32)  # along z in [-2, 2]
    vertices, faces = trimesh.remesh.subdivide_to_size(tube.vertices, tube.faces, 0.08)
    radius, half = 0.5, np.pi * 0.5 / 2
    bent_z = np.clip(vertices[:, 2], -half, half)
    angle, beyond = bent_z / radius, vertices[:, 2] - bent_z  # arms: along the end tangents
    tangent = np.column_stack([-np.sin(angle), np.zeros_like(angle), np.cos(angle)])
    normal = np.column_stack([np.cos(angle), np.zeros_like(angle), np.sin(angle)])
    axis = radius * normal + beyond[:, None] * tangent
    bent = axis + vertices[:, :1] * normal + vertices[:, 1:2] * np.array([0.0, 1.0, 0.0])
    return trimesh.Trimesh(bent, faces, process=True)


def _twisted_bar() -> trimesh.Trimesh:
    """A 2 × 0.4 × 0.15 bar twisted half a turn about its long axis."""
    bar = trimesh.creation.box((2.0, 0.4, 0.15))
    vertices, faces = trimesh.remesh.subdivide_to_size(bar.vertices, bar.faces, 0.05)
    angle = vertices[:, 0] / 2.0 * np.pi
    cos, sin = np.cos(angle), np.sin(angle)
    y, z = vertices[:, 1], vertices[:, 2]
    return trimesh.Trimesh(
        np.column_stack([vertices[:, 0], cos * y - sin * z, sin * y + cos * z]), faces, process=True
    )


HELD_OUT_SOLIDS = {
    "vase": lambda: _revolved(
        [(0, -1), (0.5, -1), (0.7, -0.5), (0.3, 0.2), (0.35, 0.6), (0.6, 1), (0, 1)]
    ),
    "hourglass": lambda: _revolved([(0, -1), (0.8, -1), (0.2, 0), (0.8, 1), (0, 1)]),
    "spindle": lambda: _revolved([(0, -1.5), (0.3, -1.0), (0.4, 0), (0.3, 1.0), (0, 1.5)]),
    "u-tube": _bent_tube,
    "twisted-bar": _twisted_bar,
    "ellipsoid": lambda: trimesh.creation.icosphere(4).apply_scale((1.5, 0.8, 0.5)),
}
"""Name → solid of the ``--primitives test`` set: none of :data:`PRIMITIVES`' kinds."""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--train-data", default="../shared/train-data")
    parser.add_argument(
        "--primitives",
        nargs="?",
        const="cal",
        choices=("cal", "test"),
        help="generated solids instead: the calibration ones (cal) or the held-out ones (test)",
    )
    parser.add_argument("--shapes", type=int, default=None, help="remeshed shapes per file")
    parser.add_argument("--sources", type=int, default=24)
    parser.add_argument("--out", default=None)
    args = parser.parse_args()
    name = f"primitives-{args.primitives}" if args.primitives else "folder-cal"
    category = PRIMITIVES_CATEGORY if args.primitives else CATEGORY
    args.shapes = args.shapes or (3 if args.primitives else 8)
    args.out = args.out or f"data/{name}"
    with tempfile.TemporaryDirectory() as meshes:
        if args.primitives:
            solids = PRIMITIVES if args.primitives == "cal" else HELD_OUT_SOLIDS
            for solid, make in solids.items():
                make().export(Path(meshes) / f"{solid}.obj")
        for mesh in () if args.primitives else CALIBRATION_MESHES:
            source = (Path(args.train_data) / mesh).resolve()
            (Path(meshes) / source.name).symlink_to(source)
        files = list_meshes(meshes)
        spec = folder_spec(
            meshes,
            shapes_per_mesh=1,
            eval_shapes_per_mesh=args.shapes,
            n_sources=args.sources,
            n_extra_sources=0,
            shard_size=8,
            name=name,
        )
        spec = dataclasses.replace(
            spec,
            category=category,
            split_families={"train": (), "val": (), "test": files},
            n_shapes={"train": 0, "val": 0, "test": args.shapes * len(files)},
        )
        factory = dataclasses.replace(folder_factory(meshes, spec), category=category)
        build_dataset(spec, args.out, factory, workers=1, solver="exact")
    print(f"built {args.out}: {args.shapes * len(files)} test shapes of {', '.join(files)}")


if __name__ == "__main__":
    main()
