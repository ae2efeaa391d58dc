"""Build a fusion-calibration set from a few mesh files outside every training family.

Usage: python scripts/build_folder_cal.py [--train-data ../shared/train-data] [--shapes 8]
    [--out data/folder-cal]
       python scripts/build_folder_cal.py --primitives [--shapes 3] [--out data/primitives-cal]

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
network (its veto's OOD limit). ~1 min on one core with ``--shapes 3``.
"""

from __future__ import annotations

import argparse
import dataclasses
import tempfile
from pathlib import Path

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


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--train-data", default="../shared/train-data")
    parser.add_argument("--primitives", action="store_true", help="the generated solids instead")
    parser.add_argument("--shapes", type=int, default=None, help="remeshed shapes per file")
    parser.add_argument("--sources", type=int, default=24)
    parser.add_argument("--out", default=None)
    args = parser.parse_args()
    name, category = (
        ("primitives-cal", PRIMITIVES_CATEGORY)
        if args.primitives
        else (
            "folder-cal",
            CATEGORY,
        )
    )
    args.shapes = args.shapes or (3 if args.primitives else 8)
    args.out = args.out or f"data/{name}"
    with tempfile.TemporaryDirectory() as meshes:
        if args.primitives:
            for solid, make in PRIMITIVES.items():
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
