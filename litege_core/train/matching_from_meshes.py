"""A matching model from a folder of meshes that share one topology (issue 16): the library
side of ``litege train matching --meshes DIR --out BUNDLE``.

Every file must have the same vertex count and faces, vertex ``i`` the same point on every
shape (:func:`~litege_core.train.from_meshes.shared_topology`; a clear InputError otherwise).

1. **Data.** A *template*-kind dataset (:class:`FolderTemplateFactory`): each file turned
   onto the first (files may be stored in different orientations); the template is the
   first file's faces with the mean vertices of all files; the files are split train/val/test
   by file (seeded, :func:`~litege_core.synth.folder.split_files`) and each split's families
   are its files; shape ``(file, seed)`` is the file's vertices (centred, unit area) under a
   smooth random non-rigid stretch (:func:`~litege_core.synth.meshops.smooth_stretch`, none
   for seed 0 of a file's evaluation shapes). Ground truth by the heat method, shared sources
   only (as the ``matching`` preset), built resumably under ``WORK/data``.

   **Poses** (``poses=True``, ``--poses``): every file is a rigged, animated glTF whose skinned
   bodies share one topology (:func:`~litege_core.train.from_meshes.rig_topology`; one file is
   enough), and a shape is a pose of the file's rig (a clip drawn among its animations and a
   time in it, linear blend skinning: :data:`~litege_core.synth.folder.RIG_POSES`) before the
   stretch; a file stands in its rest pose for the template and the first evaluation shape.
   With fewer than three files every split draws from every file: the splits hold different
   poses (seeds) of the same characters.
2. **T-Net.** The T-Net of the ``init`` matching bundle (default ``quadrupeds``), fine-tuned
   on the training shapes in the frame it already agrees on
   (:func:`~litege_core.train.tnet.collection.tune_tnet_on_collection`; ``tnet_steps=0``
   keeps it as it is): a user's characters can lie outside the families it was trained on.
3. **Training** with a generated :class:`~litege_core.train.matching.MatchingTrainConfig`
   (:func:`folder_matching_config`): that T-Net, a basis fitted on the training shapes, small
   widths and a number of steps sized to the time budget; a TOML config may override any key.
4. **Bundle.** The exported matching bundle is copied to ``OUT`` with a short model card
   (``MODEL_CARD.md``) and ``summary.json``. Serve it with ``litege match X Y --bundle OUT``.
"""

from __future__ import annotations

import functools
import json
import logging
import math
import shutil
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from litege_core.errors import InputError

LOG = logging.getLogger("litege.train")

DATA_DIR = "data"
RUN_DIR = "run"
WORK_DIR = "work"
TNET_FILE = "tnet.safetensors"
CARD = "MODEL_CARD.md"
SUMMARY = "summary.json"
DEFAULT_INIT = "quadrupeds"
STEPS_PER_SECOND = 8.0
"""Rough CPU step rate of the generated network (width 128, 1536 pairs a step) on one core,
used to size the schedule to a time budget: about half the 17 steps/s of an AMD EPYC core
(2026-12-02, ``scripts/bench_rig_matching.py``), for a core shared with other work."""
TRAIN_SHARE = 0.6
"""Fraction of the time left after the data build that the planned schedule spans (basis
fit, tables, validation and export take the rest)."""
DEFAULT_STEPS = 2000
DEFAULT_SHAPES_PER_MESH = (20, 2)
"""Training and evaluation shapes per file of a folder run that names none."""
TNET_SHARE = 0.3
"""Share of the time left after the data build that the T-Net's fine-tune may take."""
DEFAULT_TNET_STEPS = 600
"""T-Net fine-tuning steps without a time budget (the most with one)."""


@dataclass(frozen=True)
class FolderTemplateFactory:
    """The template factory of a folder of meshes sharing one topology (picklable: the
    build's worker processes reload the files).

    ``generate(file, seed)`` is the file's vertices, centred and scaled to unit area, under a
    smooth non-rigid stretch seeded by ``(seed, file)``; the first validation and test shape
    of each split (seeds 1,000,000 and 2,000,000) is the file itself, unstretched."""

    meshes: str
    files: tuple[str, ...]
    digest: str
    category: str = "folder-template"
    stretch_amplitude: float = 0.04
    axis_range: tuple[float, float] = (0.9, 1.1)
    poses: bool = False

    @property
    def version(self) -> str:
        return f"folder-template-2-{self.digest}" + ("-poses" if self.poses else "")

    def _rig(self, name: str) -> Any:
        from litege_core.synth.folder import rigged_model

        rig = rigged_model(str(Path(self.meshes) / name))
        if rig is None:
            raise InputError(f"{name} is not a rigged, animated glTF file")
        return rig

    def load(self, name: str) -> tuple[NDArray, NDArray]:
        """The file's vertices, centred at unit area (a rig: its rest pose), and faces; a file
        other than the first is turned onto the first (the proper rotation that best fits
        its vertices to theirs, :func:`~litege_core.matching.intrinsic.robust_rotation`), so
        files stored in different orientations make one collection."""
        if self.poses:
            rig = self._rig(name)
            faces = np.asarray(rig.mesh.faces, dtype=np.int64)
            return _unit_area(rig.rest_vertices(), faces), faces
        from litege_core.matching.intrinsic import robust_rotation

        vertices, faces = _unit_area_mesh(str(Path(self.meshes) / name))
        if name == self.files[0]:
            return vertices.copy(), faces
        first = _unit_area_mesh(str(Path(self.meshes) / self.files[0]))[0]
        rotation, _ = robust_rotation(vertices, first)
        return vertices @ rotation.T, faces

    def template(self) -> tuple[NDArray, NDArray]:
        first, faces = self.load(self.files[0])
        total = first.copy()
        for name in self.files[1:]:
            total += self.load(name)[0]
        return total / len(self.files), faces

    def generate(self, family: str, seed: int) -> NDArray:
        from litege_core.datasets.spec import SPLIT_SEED_OFFSETS
        from litege_core.synth.meshops import smooth_stretch

        vertices, faces = self.load(family)
        if seed in (SPLIT_SEED_OFFSETS["val"], SPLIT_SEED_OFFSETS["test"]):
            return vertices  # the first evaluation shape is the file itself
        digest = int.from_bytes(family.encode()[:8].ljust(8, b"\0"), "little")
        rng = np.random.default_rng([seed, digest, 0x5EED])
        if self.poses:
            from litege_core.synth.folder import RIG_POSES
            from litege_core.synth.rigged import pose_model

            vertices = pose_model(self._rig(family), rng, RIG_POSES)[0]
        stretched = smooth_stretch(
            vertices, rng, axis_range=self.axis_range, amplitude=self.stretch_amplitude
        )
        return _unit_area(stretched, faces)


@functools.lru_cache(maxsize=64)
def _unit_area_mesh(path: str) -> tuple[NDArray, NDArray]:
    """A mesh file's vertices (read-only), centred at unit area, and faces (memoized)."""
    from litege_core.arrays import frozen
    from litege_core.io import load_shape
    from litege_core.synth.folder import FOLDER_LIMITS

    shape = load_shape(path, kind="mesh", limits=FOLDER_LIMITS)
    assert shape.faces is not None  # kind="mesh"
    faces = frozen(shape.faces, np.int64)
    return frozen(_unit_area(np.asarray(shape.vertices, np.float64), faces)), faces


def _unit_area(vertices: NDArray, faces: NDArray) -> NDArray:
    from litege_core.synth.meshops import triangle_area_total

    area = triangle_area_total(vertices, faces)
    if not area > 0:
        raise InputError("a mesh of the folder has zero area")
    centred: NDArray = (vertices - vertices.mean(axis=0)) / math.sqrt(area)
    return centred


@dataclass(frozen=True)
class MatchingFolderOptions:
    """What :func:`train_matching_from_meshes` does.

    Attributes:
        meshes: the folder (files sharing one topology).
        poses: the files are rigs and their shapes poses of them (see the module docstring).
        out: the bundle directory written at the end.
        work: dataset and run directory (default ``OUT/work``).
        init: the matching bundle (shipped name or directory) whose T-Net is reused.
        time_budget_s: wall-clock budget (``None``: :data:`DEFAULT_STEPS` steps).
        workers: ground-truth processes.
        seed: seed of the file split, the stretches and training.
        shapes_per_mesh / eval_shapes_per_mesh: shapes per train / val-test file (``None``:
            :data:`DEFAULT_SHAPES_PER_MESH`, or for ``poses`` of fewer than three files
            :func:`~litege_core.synth.folder.shapes_per_file`'s).
        n_sources: shared ground-truth sources (farthest points of the template).
        config: a TOML config whose tables override the generated one.
        name: the bundle name (default: the folder's name).
        tnet_steps: T-Net fine-tuning steps (``None``: :data:`DEFAULT_TNET_STEPS`, fewer when
            :data:`TNET_SHARE` of the budget left after the data does not fit them; ``0``: the
            ``init`` T-Net as it is).
        distance_fn: a custom ground-truth row function (tests), replacing the heat method.
        progress: progress bars of the data build.
    """

    meshes: Path
    out: Path
    work: Path | None = None
    init: str = DEFAULT_INIT
    time_budget_s: float | None = None
    workers: int = 1
    seed: int = 0
    shapes_per_mesh: int | None = None
    eval_shapes_per_mesh: int | None = None
    n_sources: int = 48
    config: str | Path | None = None
    name: str | None = None
    distance_fn: Any = None
    progress: bool = True
    poses: bool = False
    tnet_steps: int | None = None

    def __post_init__(self) -> None:
        if self.time_budget_s is not None and not self.time_budget_s > 0:
            raise InputError("the time budget must be positive")
        if self.workers < 1:
            raise InputError("--workers must be at least 1")
        if self.tnet_steps is not None and self.tnet_steps < 0:
            raise InputError("--tnet-steps must be 0 (keep the T-Net) or more")
        if (self.shapes_per_mesh is not None and self.shapes_per_mesh < 1) or (
            self.eval_shapes_per_mesh is not None and self.eval_shapes_per_mesh < 2
        ):
            raise InputError(
                "need at least one shape per training file and two per evaluation file "
                "(validation matches pairs of different shapes)"
            )

    @property
    def work_dir(self) -> Path:
        return Path(self.work) if self.work is not None else Path(self.out) / WORK_DIR


def folder_template_spec(
    files: tuple[str, ...],
    *,
    name: str,
    seed: int = 0,
    shapes_per_mesh: int = 20,
    eval_shapes_per_mesh: int = 2,
    n_sources: int = 48,
) -> Any:
    """The template-kind :class:`~litege_core.datasets.spec.DatasetSpec` of a folder: files
    split by file (fewer than three: every split holds every file, and differs by its seeds),
    shared sources only (``n_extra_sources = 0``, as the matching preset)."""
    from litege_core.datasets.spec import DatasetSpec
    from litege_core.synth.folder import pose_splits

    splits = pose_splits(files, seed)
    counts = {
        "train": len(splits["train"]) * shapes_per_mesh,
        "val": len(splits["val"]) * eval_shapes_per_mesh,
        "test": len(splits["test"]) * eval_shapes_per_mesh,
    }
    return DatasetSpec(
        name=name,
        category="folder-template",
        families=files,
        n_shapes=counts,
        n_shared_sources=n_sources,
        n_extra_sources=0,
        shard_size=8,
        split_families=splits,
    )


def export_tnet(init: str, path: Path) -> str:
    """Write the T-Net of the matching bundle ``init`` to ``path`` (a T-Net weights file, as
    the matching config names it); returns the bundle directory."""
    from litege_core.matching.bundle import load_matching_bundle, resolve_matching_bundle
    from litege_core.train.tnet import save_tnet

    directory = resolve_matching_bundle(init)
    bundle = load_matching_bundle(directory)
    path.parent.mkdir(parents=True, exist_ok=True)
    save_tnet(bundle.tnet.cpu().eval(), path)
    return str(directory)


def planned_steps(seconds: float | None) -> tuple[int, int]:
    """``(first_pass_steps, steps)`` of a run with ``seconds`` left for training (``None``:
    the unbudgeted default): 2 first passes of 10 % each, the rest the continuation."""
    total = DEFAULT_STEPS if seconds is None else int(TRAIN_SHARE * seconds * STEPS_PER_SECOND)
    total = max(total, 20)
    first = max(5, total // 10)
    return first, max(10, total - 2 * first)


def folder_matching_config(
    data_dir: str | Path,
    run_dir: str | Path,
    tnet: str | Path,
    *,
    name: str,
    seed: int = 0,
    train_seconds: float | None = None,
    overrides: dict[str, Any] | None = None,
) -> Any:
    """The matching config of a folder run: the T-Net filter measured from the frame the
    T-Net agrees on (``data.frame = "consensus"``: a user's files keep their own convention),
    width 128, 64 PCA components (fewer with few
    training shapes), 8 view pairs × 12 rows × 16 targets a step, steps sized to
    ``train_seconds``; ``overrides`` (parsed TOML tables) replace any key except
    ``data.dataset``, ``data.tnet`` and ``output.dir``."""
    from litege_core.train.matching import MatchingTrainConfig

    first, steps = planned_steps(train_seconds)
    tables: dict[str, dict[str, Any]] = {
        "data": {"views_per_shape": 4, "val_view_pairs": 24, "frame": "consensus"},
        "basis": {"path": str(Path(run_dir) / "basis.safetensors"), "n_components": 64},
        "network": {"width": 128, "output": "abs"},
        "train": {
            "view_pairs": 8,
            "rows_per_pair": 12,
            "targets_per_pair": 16,
            "first_passes": 2,
            "first_pass_steps": first,
            "steps": steps,
            "validate_every": max(10, steps // 5),
            "seed": seed,
            "threads": 1,
        },
        "output": {"name": name, "category": "folder", "weights_dtype": "float16"},
    }
    for table, values in (overrides or {}).items():
        if not isinstance(values, dict):
            raise InputError(f"[{table}] of the config must be a table")
        tables[table] = {**tables.get(table, {}), **values}
    tables["data"] = {**tables["data"], "dataset": str(data_dir), "tnet": str(tnet)}
    tables["output"] = {**tables["output"], "dir": str(run_dir)}
    return MatchingTrainConfig.from_dict(tables)


def train_matching_from_meshes(options: MatchingFolderOptions) -> dict[str, Any]:
    """Folder of meshes sharing one topology → matching bundle in ``options.out`` (see the
    module docstring); returns the JSON-safe summary (also ``OUT/summary.json``)."""
    from litege_core.datasets import build_dataset
    from litege_core.matching.bundle import load_matching_bundle
    from litege_core.synth.folder import folder_digest, shapes_per_file
    from litege_core.train.config import read_toml
    from litege_core.train.from_meshes import rig_topology, shared_topology
    from litege_core.train.matching import train_matching

    start = time.monotonic()
    out, work = Path(options.out), options.work_dir
    name = options.name or Path(options.meshes).resolve().name
    topology = rig_topology if options.poses else shared_topology
    files, n_vertices, faces = topology(options.meshes)
    overrides = read_toml(options.config) if options.config is not None else {}
    run_dir = work / RUN_DIR
    tnet_path = work / TNET_FILE
    init_dir = export_tnet(options.init, tnet_path)  # fails early on a bad --init

    # 1. data
    files = tuple(files)
    shapes, eval_shapes = shapes_per_file(
        len(files),
        options.poses,
        DEFAULT_SHAPES_PER_MESH,
        (options.shapes_per_mesh, options.eval_shapes_per_mesh),
    )
    spec = folder_template_spec(
        files,
        name=f"folder-matching-{Path(options.meshes).resolve().name}",
        seed=options.seed,
        shapes_per_mesh=shapes,
        eval_shapes_per_mesh=eval_shapes,
        n_sources=min(options.n_sources, n_vertices),
    )
    factory: Any = FolderTemplateFactory(  # a ShapeFactory (read-only category / version)
        str(options.meshes), files, folder_digest(options.meshes, files), poses=options.poses
    )
    splits = spec.split_families or {}
    LOG.info(
        "data: %d meshes sharing one topology (%d vertices, %d faces) → %d train / %d val / "
        "%d test files; %s shapes, heat ground truth from %d shared sources, in %s",
        len(files),
        n_vertices,
        faces.shape[0],
        len(splits.get("train", ())),
        len(splits.get("val", ())),
        len(splits.get("test", ())),
        spec.n_shapes,
        spec.n_shared_sources,
        work / DATA_DIR,
    )
    build_dataset(
        spec,
        work / DATA_DIR,
        factory,
        workers=options.workers,
        distance_fn=options.distance_fn,
        solver="heat",
        progress=options.progress,
    )
    data_seconds = time.monotonic() - start

    # 2. T-Net
    tnet_summary = tune_folder_tnet(options, work / DATA_DIR, tnet_path, start)

    # 3. training
    train_seconds = None
    if options.time_budget_s is not None:
        train_seconds = max(options.time_budget_s - (time.monotonic() - start), 10.0)
    for stale in ("bundle", "basis.safetensors"):
        target = run_dir / stale
        if target.is_dir():
            shutil.rmtree(target)
        else:
            target.unlink(missing_ok=True)
    config = folder_matching_config(
        work / DATA_DIR,
        run_dir,
        tnet_path,
        name=name,
        seed=options.seed,
        train_seconds=train_seconds,
        overrides=overrides,
    )
    LOG.info(
        "training: T-Net of %s%s, width %d, %d × %d first-pass steps then %d steps",
        init_dir,
        "" if tnet_summary is None else " tuned on the collection",
        config.network.width,
        config.train.first_passes,
        config.train.first_pass_steps,
        config.train.steps,
    )
    manifest = train_matching(config)

    # 4. the bundle in OUT
    bundle_dir = run_dir / "bundle"
    out.mkdir(parents=True, exist_ok=True)
    for filename in [*manifest["files"], "manifest.json"]:
        shutil.copy2(bundle_dir / filename, out / filename)
    load_matching_bundle(out)  # what is served loads
    collection = {
        "meshes": str(options.meshes),
        "n_vertices": n_vertices,
        "n_faces": int(faces.shape[0]),
        "files": {split: list(names) for split, names in splits.items()},
        "shapes": dict(spec.n_shapes),
        "init": options.init,
        "seed": options.seed,
        "poses": options.poses,
        "tnet": tnet_summary,
    }
    (out / CARD).write_text(_model_card(manifest, collection))
    summary = {
        "bundle": str(out),
        "name": manifest["name"],
        "kind": "matching",
        "serve": f"litege match X Y --bundle {out}",
        "time_budget_s": options.time_budget_s,
        "seconds": {"data": data_seconds, "total": time.monotonic() - start},
        "data": {"dir": str(work / DATA_DIR), **collection},
        "training": {
            "steps": config.train.steps,
            "first_pass_steps": config.train.first_pass_steps,
            "chosen_first_pass": manifest["training"].get("chosen_first_pass"),
            "run_dir": str(run_dir),
        },
        "metrics": manifest["metrics"],
    }
    (out / SUMMARY).write_text(json.dumps(summary, indent=2, default=str) + "\n")
    LOG.info("matching bundle %s written to %s", name, out)
    return summary


def tune_folder_tnet(
    options: MatchingFolderOptions, data_dir: Path, tnet_path: Path, start: float
) -> dict[str, Any] | None:
    """Fine-tune the T-Net at ``tnet_path`` (the ``init`` bundle's) on the training shapes of
    the built dataset; ``None`` when ``options.tnet_steps`` is 0."""
    from litege_core.datasets import GeodesicDataset
    from litege_core.train.data import load_split_arrays
    from litege_core.train.tnet.collection import tune_tnet_on_collection

    steps = DEFAULT_TNET_STEPS if options.tnet_steps is None else options.tnet_steps
    if steps == 0:
        return None
    minutes = 0.0
    if options.time_budget_s is not None:
        minutes = max(TNET_SHARE * (options.time_budget_s - (time.monotonic() - start)), 30.0)
        minutes /= 60.0
    dataset = GeodesicDataset(data_dir)
    LOG.info("T-Net: fine-tuning the %s T-Net on the collection", options.init)
    return tune_tnet_on_collection(
        options.init,
        load_split_arrays(dataset, "train", 0),
        load_split_arrays(dataset, "val", 0),
        np.asarray(dataset.faces),
        tnet_path,
        steps=steps,
        minutes=minutes,
        seed=options.seed,
    )


def _model_card(manifest: dict[str, Any], collection: dict[str, Any]) -> str:
    from litege_core.synth.folder import splits_share_files

    metrics = manifest.get("metrics", {})
    lines = [
        f"# {manifest['name']} (matching)",
        "",
        f"Matching model trained with `litege train matching --meshes {collection['meshes']}` "
        f"on {sum(len(v) for v in collection['files'].values())} meshes sharing one topology "
        f"({collection['n_vertices']} vertices, {collection['n_faces']} faces; vertex i "
        "corresponds on every shape).",
        "",
        "- files ("
        + (
            f"split by file, seed {collection['seed']}"
            if not splits_share_files(collection["files"])
            else "every file in every split: the splits hold different poses"
        )
        + "): "
        + "; ".join(f"{split}: {len(names)}" for split, names in collection["files"].items()),
        (
            f"- shapes (poses drawn from each rig's animation clips, then smooth random "
            f"stretches): {collection['shapes']}"
            if collection["poses"]
            else f"- shapes (smooth random stretches of the files): {collection['shapes']}"
        ),
        "- ground truth: heat method from the template's shared farthest-point sources",
        (
            f"- T-Net: the `{collection['init']}` matching bundle's, fine-tuned on the "
            f"collection ({collection['tnet']['steps']} steps; randomly turned training shapes "
            f"brought to one frame: {100 * collection['tnet']['agreement_before']:.0f} % → "
            f"{100 * collection['tnet']['agreement_after']:.0f} %)"
            if collection["tnet"]
            else f"- T-Net: reused from the `{collection['init']}` matching bundle"
        ),
        "",
        "## Validation",
        "",
        "| metric | value |",
        "|---|---|",
        *(
            f"| {key} | {value:.4g} |"
            for key, value in sorted(metrics.items())
            if isinstance(value, int | float)
        ),
        "",
        "Use: `litege match X Y --bundle DIR`. The T-Net orients inputs as it learned on its own "
        "training shapes: collections far from that category may match poorly.",
        "",
    ]
    return "\n".join(lines)


__all__ = [
    "FolderTemplateFactory",
    "MatchingFolderOptions",
    "export_tnet",
    "folder_matching_config",
    "folder_template_spec",
    "planned_steps",
    "train_matching_from_meshes",
    "tune_folder_tnet",
]
