"""Collection datasets from a folder of meshes (issue 16: ``litege train geodesic --meshes``).

:func:`folder_spec` turns a directory of mesh files into a :class:`DatasetSpec` of kind
``collection`` (files split train/val/test by file, seeded; each file a family) and
:func:`build_collection_dataset` builds it with a :class:`FolderFactory`, resumably.
"""

from __future__ import annotations

from pathlib import Path

from litege_core.datasets.build import build_dataset
from litege_core.datasets.factories import FolderFactory
from litege_core.datasets.spec import DatasetSpec
from litege_core.errors import InputError


def folder_spec(
    meshes_dir: str | Path,
    *,
    shapes_per_mesh: int = 10,
    eval_shapes_per_mesh: int = 2,
    seed: int = 0,
    n_sources: int = 48,
    n_extra_sources: int = 16,
    shard_size: int = 16,
    name: str | None = None,
    poses: bool = False,
) -> DatasetSpec:
    """The collection spec of a folder: ``shapes_per_mesh`` training shapes per training file
    and ``eval_shapes_per_mesh`` per validation / test file (40 files → 32 train files → 320
    training shapes by default). With ``poses`` (the shapes are poses of rigged files) fewer
    than three files are shared by every split
    (:func:`~litege_core.synth.folder.pose_splits`).

    Raises:
        InputError: no mesh files, or non-positive counts.
    """
    from litege_core.synth.folder import list_meshes, pose_splits, split_files

    if shapes_per_mesh < 1 or eval_shapes_per_mesh < 0:
        raise InputError("need shapes_per_mesh ≥ 1 and eval_shapes_per_mesh ≥ 0")
    files = list_meshes(meshes_dir)
    splits = pose_splits(files, seed) if poses else split_files(files, seed)
    counts = {
        "train": len(splits["train"]) * shapes_per_mesh,
        "val": len(splits["val"]) * eval_shapes_per_mesh,
        "test": len(splits["test"]) * eval_shapes_per_mesh,
    }
    return DatasetSpec(
        name=name or f"folder-{Path(meshes_dir).resolve().name}",
        category="folder",
        families=files,
        n_shapes=counts,
        n_shared_sources=n_sources,
        n_extra_sources=n_extra_sources,
        shard_size=shard_size,
        kind="collection",
        split_families=splits,
    )


def folder_factory(meshes_dir: str | Path, spec: DatasetSpec, settings=None) -> FolderFactory:
    """The factory of a folder spec (its version carries a digest of the files)."""
    from litege_core.synth.folder import folder_digest

    return FolderFactory(str(meshes_dir), folder_digest(meshes_dir, spec.families), settings)


def build_collection_dataset(
    meshes_dir: str | Path,
    out_dir: str | Path,
    *,
    shapes_per_mesh: int = 10,
    eval_shapes_per_mesh: int = 2,
    workers: int = 1,
    seed: int = 0,
    solver: str = "exact",
    n_sources: int = 48,
    n_extra_sources: int = 16,
    settings=None,
    progress: bool = True,
) -> dict:
    """Build (or resume) the collection dataset of every mesh under ``meshes_dir`` into
    ``out_dir``; returns the manifest.

    Args:
        meshes_dir: directory of mesh files (obj, ply, off, stl, glb, gltf; searched recursively).
        out_dir: dataset directory (resumable: rerun the same call to continue).
        shapes_per_mesh / eval_shapes_per_mesh: shapes per training / evaluation file.
        workers: processes computing shapes in parallel.
        seed: seed of the train/val/test split by file.
        solver: ``"exact"`` (MMP) or ``"heat"``.
        n_sources / n_extra_sources: farthest-point and random sources per shape.
        settings: :class:`~litege_core.synth.folder.FolderSettings` (augmentation ranges).

    Raises:
        InputError: files of the folder cannot be used (all named,
            :func:`~litege_core.synth.folder.check_files`, before any shape is built).
        ArtifactError: ``out_dir`` holds a dataset of other files, settings or solver.
    """
    from litege_core.synth.folder import FolderSettings, check_files

    spec = folder_spec(
        meshes_dir,
        shapes_per_mesh=shapes_per_mesh,
        eval_shapes_per_mesh=eval_shapes_per_mesh,
        seed=seed,
        n_sources=n_sources,
        n_extra_sources=n_extra_sources,
    )
    check_files(meshes_dir, spec.families, settings or FolderSettings())
    factory = folder_factory(meshes_dir, spec, settings)
    return build_dataset(spec, out_dir, factory, workers=workers, solver=solver, progress=progress)


__all__ = ["build_collection_dataset", "folder_factory", "folder_spec"]
