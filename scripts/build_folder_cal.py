"""Build a fusion-calibration set from a few mesh files outside every training family.

Usage: python scripts/build_folder_cal.py [--train-data ../shared/train-data] [--shapes 8]
    [--out data/folder-cal]

The graph fusion of a bundle (``scripts/calibrate_fusion.py``) must be fitted on shapes the
network was not trained on, or its gate learns to trust the network more than it should on real
shapes. A bundle fine-tuned on the rigged animals cannot be calibrated on ``data/rigged-cal``;
this set takes the three static train-data meshes that no factory trains on (the cat sculpt,
the koala scan and Spot, in ``odedstein-meshes``), each remeshed ``--shapes`` times with the
folder augmentation (3,000–6,000 vertices, smooth stretches), every shape in the test split,
exact MMP rows from 24 FPS sources. ~2.5 min on one core.
"""

from __future__ import annotations

import argparse
import dataclasses
import tempfile
from pathlib import Path

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


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--train-data", default="../shared/train-data")
    parser.add_argument("--shapes", type=int, default=8, help="remeshed shapes per file")
    parser.add_argument("--sources", type=int, default=24)
    parser.add_argument("--out", default="data/folder-cal")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as meshes:
        for name in CALIBRATION_MESHES:
            source = (Path(args.train_data) / name).resolve()
            (Path(meshes) / source.name).symlink_to(source)
        files = list_meshes(meshes)
        spec = folder_spec(
            meshes,
            shapes_per_mesh=1,
            eval_shapes_per_mesh=args.shapes,
            n_sources=args.sources,
            n_extra_sources=0,
            shard_size=8,
            name="folder-cal",
        )
        spec = dataclasses.replace(
            spec,
            category=CATEGORY,
            split_families={"train": (), "val": (), "test": files},
            n_shapes={"train": 0, "val": 0, "test": args.shapes * len(files)},
        )
        factory = dataclasses.replace(folder_factory(meshes, spec), category=CATEGORY)
        build_dataset(spec, args.out, factory, workers=1, solver="exact")
    print(f"built {args.out}: {args.shapes * len(files)} test shapes of {', '.join(files)}")


if __name__ == "__main__":
    main()
