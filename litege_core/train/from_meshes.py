"""A geodesic model from a folder of meshes in one call (issue 16, "Train on your own
collection"): the library side of ``litege train geodesic --meshes DIR --out BUNDLE``.

:func:`train_from_meshes` runs four phases, logged on stderr (``litege.train``) and timed in
the summary it returns:

1. **Data.** The folder's mesh files (any format :func:`litege_core.io.load_shape` reads) are
   split train/val/test by file (seeded, :func:`~litege_core.synth.folder.split_files`); each
   file gives ``shapes_per_mesh`` (train) or ``eval_shapes_per_mesh`` (val, test) augmented
   remeshes (smooth non-rigid stretches, isotropic remeshing to a random vertex count) with
   exact ground truth, built resumably under ``WORK/data`` (progress bars; rerun the same
   command to continue). Training views add random rotations, resampling (300–8K points),
   noise and cuts, so a few dozen files give a useful model. Under a time budget the train
   split stops growing at :data:`DATA_SHARE` of the budget (its first shard is always built,
   val and test always completely): training uses the shards built so far, and a rerun with
   the same ``--out`` builds more.
2. **References.** The held-out test files are evaluated side by side
   (:func:`~litege_core.evaluation.geodesic.evaluate_methods`) with the reference model(s)
   (the ``init`` model, else every shipped geodesic model), the heat method and kNN-graph
   Dijkstra, before training, so the time left for training is known.
3. **Training** with a generated :class:`~litege_core.train.config.TrainConfig`
   (:func:`folder_config`): with ``init`` a fine-tune (the init bundle's basis and network,
   lr 1e-3 → 1e-5), otherwise from scratch (a basis fitted on the training files, lr
   1e-2 → 1e-4); a TOML config may override any key. Under a budget the schedule is sized to
   the time left (a short probe measures the step rate) and the trainer's deadline stops it at
   the latest; the best validation checkpoint is exported (a warm start counts the init model
   as epoch 0, so the result is never worse than it on the validation files).
4. **Bundle.** The exported bundle is evaluated on the test files like the references and
   written to ``OUT`` (``manifest.json`` with the held-out numbers under
   ``metrics.held_out``, ``MODEL_CARD.md`` with the comparison table (written by
   :mod:`litege_core.learned.cards`), ``evaluation.md``, ``summary.json``). Serve it with
   ``litege geodesic FILE --model OUT``.

:func:`shared_topology` is the check of ``litege train matching --meshes``: every file must
have the same vertex count and faces (vertex ``i`` corresponds on all shapes).
"""

from __future__ import annotations

import copy
import json
import logging
import math
import shutil
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from litege_core.errors import InputError
from litege_core.files import make_directory
from litege_core.train.config import TrainConfig, check_time_budget, read_toml

LOG = logging.getLogger("litege.train")

DATA_DIR = "data"
RUN_DIR = "run"
WORK_DIR = "work"
CARD = "MODEL_CARD.md"
EVALUATION = "evaluation.md"
SUMMARY = "summary.json"
CREDIT_FILES = ("CREDITS.md", "ATTRIBUTION.md")
"""A file of these names at the top of the meshes folder goes into the model card."""

DATA_SHARE = 0.4
"""Fraction of the time budget after which the train split stops growing."""
MIN_EVAL_RESERVE_S = 20.0
"""Seconds kept after training for export, the bundle's evaluation and the card, on top of
1.5 × the measured evaluation time of one reference model."""
PROBE_STEPS = 12
SCHEDULE_SAFETY = 0.85
"""Fraction of the measured step rate × time left that the planned schedule spans (other
processes, validation and checkpoints take the rest; the deadline cuts any overrun)."""
DEFAULT_VERTEX_RANGE = (2000, 4000)
DEFAULT_SHAPES_PER_MESH = (10, 2)
"""Training and evaluation shapes per file of a folder run that names none."""
FINE_TUNE_TRAIN = {"lr": 1e-3, "eta_min": 1e-5, "epochs": 8, "steps_per_epoch": 500}
SCRATCH_TRAIN = {"lr": 1e-2, "eta_min": 1e-4, "epochs": 12, "steps_per_epoch": 1000}
MAX_COMPONENTS = 240


class DataBudgetReached(Exception):  # noqa: N818 - a signal, not an error
    """Raised by :class:`BudgetedFactory` once the data deadline has passed."""


@dataclass(frozen=True)
class BudgetedFactory:
    """A collection factory that refuses new *training* shapes after ``deadline`` (a
    :func:`time.time` instant, shared by the build's worker processes), except the first
    ``always`` of them; validation and test shapes are always made. Same category and
    version as ``inner``, so a build resumes across calls."""

    inner: Any
    deadline: float
    always: int

    @property
    def category(self) -> str:
        return str(self.inner.category)

    @property
    def version(self) -> str:
        return str(self.inner.version)

    def generate_mesh(self, family: str, seed: int) -> tuple[NDArray, NDArray]:
        from litege_core.datasets.spec import SPLIT_SEED_OFFSETS

        is_train = seed < SPLIT_SEED_OFFSETS["val"]
        if is_train and seed >= self.always and time.time() >= self.deadline:
            raise DataBudgetReached(f"data budget reached before training shape {seed}")
        result: tuple[NDArray, NDArray] = self.inner.generate_mesh(family, seed)
        return result


@dataclass(frozen=True)
class FolderTrainOptions:
    """What :func:`train_from_meshes` does.

    Attributes:
        meshes: the folder of mesh files (searched recursively).
        out: the bundle directory written at the end.
        work: where the dataset (``data/``) and the run (``run/``) go (default ``OUT/work``).
        init: warm start from a shipped model name or a bundle directory (``None``: scratch).
        time_budget_s: wall-clock budget of the whole call (``None``: none).
        workers: processes computing the ground truth.
        seed: seed of the file split and of training.
        shapes_per_mesh / eval_shapes_per_mesh: augmented shapes per train / val-test file
            (``None``: :data:`DEFAULT_SHAPES_PER_MESH`, or for ``poses`` of fewer than three
            files :func:`~litege_core.synth.folder.shapes_per_file`'s).
        vertex_range: vertex counts of the remeshed shapes (log-uniform).
        poses: pose each rigged, animated glTF by its own clips (``FolderSettings.poses``);
            ``False`` (default): every file in its stored pose.
        n_sources / n_extra_sources: farthest-point and random ground-truth sources per shape.
        solver: ``"exact"`` (MMP), ``"heat"`` or ``"heat-fine"`` (see
            :data:`~litege_core.datasets.build.SOLVERS`).
        config: a TOML config whose tables override the generated one (``data.dataset`` and
            ``output.dir`` are always the command's).
        name: the bundle name (default: the folder's name).
        references: models compared on the test files (default: ``init``, else the shipped
            geodesic models).
        settings: evaluation settings (:data:`~litege_core.evaluation.geodesic.SETTINGS`).
        distance_fn: a custom ground-truth row function (tests), replacing ``solver``.
        progress: progress bars of the data build.
    """

    meshes: Path
    out: Path
    work: Path | None = None
    init: str | None = None
    time_budget_s: float | None = None
    workers: int = 1
    seed: int = 0
    shapes_per_mesh: int | None = None
    eval_shapes_per_mesh: int | None = None
    vertex_range: tuple[int, int] = DEFAULT_VERTEX_RANGE
    poses: bool = False
    n_sources: int = 48
    n_extra_sources: int = 16
    solver: str = "exact"
    config: str | Path | None = None
    name: str | None = None
    references: tuple[str, ...] | None = None
    settings: tuple[str, ...] = ()
    distance_fn: Callable[[NDArray, NDArray, NDArray], NDArray] | None = None
    progress: bool = True

    def __post_init__(self) -> None:
        check_time_budget(self.time_budget_s)
        if self.workers < 1:
            raise InputError("--workers must be at least 1")
        counts = (self.shapes_per_mesh, self.eval_shapes_per_mesh)
        if any(count is not None and count < 1 for count in counts):
            raise InputError("need at least one shape per training and per evaluation file")

    @property
    def work_dir(self) -> Path:
        return Path(self.work) if self.work is not None else Path(self.out) / WORK_DIR


@dataclass
class _Clock:
    """Phase timings and the deadlines of a budgeted call."""

    budget_s: float | None
    start: float = field(default_factory=time.monotonic)
    seconds: dict[str, float] = field(default_factory=dict)

    def elapsed(self) -> float:
        return time.monotonic() - self.start

    def left(self) -> float:
        return math.inf if self.budget_s is None else self.budget_s - self.elapsed()

    def phase(self, name: str, since: float) -> None:
        self.seconds[name] = self.seconds.get(name, 0.0) + time.monotonic() - since


# --------------------------------------------------------------------------- data


def build_folder_data(options: FolderTrainOptions, clock: _Clock) -> dict[str, Any]:
    """Build (or resume) the collection dataset of ``options.meshes`` under ``WORK/data``,
    the train split bounded by the data share of the budget; returns what was built."""
    from litege_core.datasets import build_dataset, folder_spec
    from litege_core.datasets.collection import folder_factory
    from litege_core.synth.folder import (
        FolderSettings,
        check_files,
        shapes_per_file,
        splits_share_files,
    )

    files = check_folder(options.meshes, poses=options.poses)
    settings = FolderSettings(vertex_range=options.vertex_range, poses=options.poses)
    check_files(options.meshes, files, settings)
    shapes, eval_shapes = shapes_per_file(
        len(files),
        options.poses,
        DEFAULT_SHAPES_PER_MESH,
        (options.shapes_per_mesh, options.eval_shapes_per_mesh),
    )
    spec = folder_spec(
        options.meshes,
        shapes_per_mesh=shapes,
        eval_shapes_per_mesh=eval_shapes,
        seed=options.seed,
        n_sources=options.n_sources,
        n_extra_sources=options.n_extra_sources,
        shard_size=8,
        name=options.name or f"folder-{Path(options.meshes).resolve().name}",
        poses=options.poses,
    )
    factory: Any = folder_factory(options.meshes, spec, settings)
    if options.time_budget_s is not None:
        data_deadline = time.time() + DATA_SHARE * options.time_budget_s - clock.elapsed()
        factory = BudgetedFactory(factory, data_deadline, always=spec.shard_size)
    splits = spec.split_families or {}
    LOG.info(
        "data: %d mesh files → %d train / %d val / %d test files; %s shapes, %s ground truth, "
        "%d–%d vertices, in %s",
        len(files),
        len(splits.get("train", ())),
        len(splits.get("val", ())),
        len(splits.get("test", ())),
        spec.n_shapes,
        options.solver if options.distance_fn is None else "custom",
        *options.vertex_range,
        options.work_dir / DATA_DIR,
    )
    complete = True
    try:
        build_dataset(
            spec,
            options.work_dir / DATA_DIR,
            factory,
            workers=options.workers,
            distance_fn=options.distance_fn,
            solver=options.solver,
            progress=options.progress,
        )
    except DataBudgetReached:
        complete = False
    from litege_core.datasets import GeodesicDataset

    counts = dict(GeodesicDataset(options.work_dir / DATA_DIR).manifest["counts"])
    if not complete:
        LOG.info(
            "data budget reached: %d of %d training shapes built (rerun the command with the "
            "same --out to build more)",
            counts["train"],
            spec.n_shapes["train"],
        )
    return {
        "dir": str(options.work_dir / DATA_DIR),
        "held_out": "held-out test poses" if splits_share_files(splits) else "held-out test files",
        "files": {split: len(names) for split, names in splits.items()},
        "shapes": counts,
        "planned_shapes": dict(spec.n_shapes),
        "complete": complete,
        "augmentation": settings.describe(),
    }


def check_folder(meshes: str | Path, poses: bool = False) -> tuple[str, ...]:
    """The mesh files of a folder; InputError when there are fewer than three (one train,
    one validation and one test file at least), unless the shapes are ``poses`` of rigged
    files and every file is one (one file is enough:
    :func:`~litege_core.synth.folder.pose_splits`)."""
    from litege_core.synth.folder import list_meshes, not_rigs

    files = list_meshes(meshes)
    if len(files) < 3 and not poses:
        raise InputError(
            f"{meshes} holds {len(files)} mesh file(s): training needs at least 3 (files are "
            "split train/val/test by file; 20–50 are better), or --poses for rigged, animated "
            "glTF files (one is enough)"
        )
    others = not_rigs(meshes, files) if len(files) < 3 else []
    if others:
        raise InputError(
            "with fewer than 3 files every file must be a rigged, animated glTF (--poses: its "
            f"poses are the held-out shapes); not one: {', '.join(others)}"
        )
    return files


# --------------------------------------------------------------------------- config


def folder_config(
    data_dir: str | Path,
    run_dir: str | Path,
    *,
    fine_tune: bool,
    n_train_shapes: int,
    name: str,
    category: str,
    seed: int = 0,
    budgeted: bool = False,
    overrides: dict[str, Any] | None = None,
) -> TrainConfig:
    """The training config of a folder run: fine-tune defaults (``fine_tune``: lr 1e-3 →
    1e-5, 8 × 500 steps) or from-scratch defaults (lr 1e-2 → 1e-4, 12 × 1000 steps, a basis
    of ``min(240, n_train_shapes)`` components fitted on the training files); no early stopping
    under a budget (``budgeted``: the deadline ends the run), patience 4 otherwise.
    ``overrides`` (parsed TOML tables) replace any key, except ``data.dataset`` and
    ``output.dir``."""
    tables: dict[str, dict[str, Any]] = {
        "data": {"views_per_shape": 6, "val_augmented_views": 1},
        "basis": {"n_components": min(MAX_COMPONENTS, max(1, n_train_shapes))},
        "train": {
            **(FINE_TUNE_TRAIN if fine_tune else SCRATCH_TRAIN),
            "patience": 0 if budgeted else 4,
            "seed": seed,
            "threads": 1,
        },
        "output": {"name": name, "category": category},
    }
    for table, values in (overrides or {}).items():
        if not isinstance(values, dict):
            raise InputError(f"[{table}] of the config must be a table")
        tables[table] = {**tables.get(table, {}), **values}
    tables["data"]["dataset"] = str(data_dir)
    tables["output"] = {**tables["output"], "dir": str(run_dir)}
    return TrainConfig.from_dict(tables)


def plan_schedule(config: TrainConfig, seconds: float, steps_per_second: float) -> TrainConfig:
    """``config`` with ``epochs × steps_per_epoch`` ≈ :data:`SCHEDULE_SAFETY` × ``seconds`` ×
    ``steps_per_second`` steps, in about ten epochs (20 to 1000 steps each)."""
    total = max(1, int(SCHEDULE_SAFETY * seconds * steps_per_second))
    per_epoch = min(1000, max(20, math.ceil(total / 10)))
    epochs = max(1, round(total / per_epoch))
    return config.replace(train={"epochs": epochs, "steps_per_epoch": per_epoch})


def measure_step_rate(prepared: Any, steps: int = PROBE_STEPS) -> float:
    """Training steps per second of ``prepared`` (on a copy of the network; the batch
    sampler's state is restored, so the run itself is unchanged)."""
    import torch

    from litege_core.train.trainer import training_loss

    network = copy.deepcopy(prepared.network).train()
    optimizer = torch.optim.Adam(network.parameters(), lr=1e-6)
    sampler = prepared.trainer.sampler
    state = sampler.get_state().clone()
    try:

        def step() -> None:
            loss = training_loss(network, sampler.sample())
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            optimizer.step()

        step()  # warm-up
        start = time.perf_counter()
        for _ in range(steps):
            step()
        return steps / max(time.perf_counter() - start, 1e-9)
    finally:
        sampler.set_state(state)


# --------------------------------------------------------------------------- evaluation


def _predictor(reference: str | Path, device: Any) -> Any:
    from litege_core.learned import Predictor, load_model

    return Predictor(load_model(reference, device), device, fusion="none")


def _reference_names(options: FolderTrainOptions) -> list[str]:
    from litege_core.learned import shipped_bundles

    if options.references is not None:
        return list(options.references)
    return [options.init] if options.init is not None else shipped_bundles()


def _label(reference: str, init: str | None) -> str:
    name = Path(reference).name if Path(reference).is_dir() else reference
    return f"{name} (init)" if reference == init else f"{name} (shipped)"


# --------------------------------------------------------------------------- the run


def train_from_meshes(options: FolderTrainOptions) -> dict[str, Any]:
    """Folder of meshes → bundle in ``options.out`` (see the module docstring); returns the
    JSON-safe summary (also written to ``OUT/summary.json``)."""
    from litege_core.evaluation.geodesic import (
        HEAT,
        KNN,
        SETTINGS,
        collection_eval_shapes,
        comparison_methods,
        comparison_table,
        evaluate_methods,
        mean_by_method,
    )
    from litege_core.learned import load_bundle
    from litege_core.train.pipeline import (
        BUNDLE_DIR,
        CHECKPOINT_DIR,
        LOG_FILE,
        export,
        load_init_bundle,
        prepare_run,
    )
    from litege_core.train.trainer import Trainer

    clock = _Clock(options.time_budget_s)
    out, work = Path(options.out), options.work_dir
    name = options.name or Path(options.meshes).resolve().name
    settings = tuple(options.settings) or SETTINGS
    if options.init is not None:
        load_init_bundle(options.init)  # fail before any work on a bad --init
    references = _reference_names(options)
    overrides = read_toml(options.config) if options.config is not None else {}

    # 1. data
    start = time.monotonic()
    data = build_folder_data(options, clock)
    clock.phase("data", start)
    if data["shapes"]["train"] == 0:
        raise InputError("no training shape was built")

    run_dir = work / RUN_DIR
    make_directory(run_dir)
    handler = logging.FileHandler(run_dir / LOG_FILE)
    handler.setFormatter(logging.Formatter("%(asctime)s %(message)s", "%Y-%m-%dT%H:%M:%S"))
    LOG.addHandler(handler)
    try:
        for stale in (CHECKPOINT_DIR, BUNDLE_DIR):  # training starts over; the data resumes
            shutil.rmtree(run_dir / stale, ignore_errors=True)
        (run_dir / "basis.safetensors").unlink(missing_ok=True)
        init_category = (
            load_init_bundle(options.init).category if options.init is not None else "folder"
        )
        config = folder_config(
            data["dir"],
            run_dir,
            fine_tune=options.init is not None,
            n_train_shapes=data["shapes"]["train"],
            name=name,
            category=init_category,
            seed=options.seed,
            budgeted=options.time_budget_s is not None,
            overrides=overrides,
        )
        device = config.resolve_device()

        # 2. references on the held-out files
        start = time.monotonic()
        shapes = collection_eval_shapes(data["dir"], "test", group=data["held_out"])
        labels = {_label(ref, options.init): ref for ref in references}
        LOG.info(
            "evaluating %s, heat and kNN on %d held-out shapes (%s)",
            ", ".join(labels),
            len(shapes),
            ", ".join(settings),
        )
        predictors = {label: _predictor(ref, device) for label, ref in labels.items()}
        reference_results = evaluate_methods(
            shapes, comparison_methods(predictors), settings, seed=options.seed
        )
        clock.phase("reference_evaluation", start)
        model_seconds = max(
            (
                sum(r.seconds for r in reference_results if r.method == label)
                for label in predictors
            ),
            default=30.0,
        )
        reserve = MIN_EVAL_RESERVE_S + 1.5 * model_seconds

        # 3. training
        start = time.monotonic()
        prepared = prepare_run(config, options.init)
        if options.init is not None:
            prepared.trainer.start_from_baseline()
        clock.phase("tables", start)
        start = time.monotonic()
        deadline = None
        user_train = overrides.get("train", {})
        if options.time_budget_s is not None:
            deadline = time.monotonic() + clock.left() - reserve
            if "epochs" not in user_train and "steps_per_epoch" not in user_train:
                rate = measure_step_rate(prepared)
                seconds = max(deadline - time.monotonic(), 1.0)
                planned = plan_schedule(config, seconds, rate)
                LOG.info(
                    "schedule: %.0f s left for training at %.1f steps/s → %d epochs × %d steps",
                    seconds,
                    rate,
                    planned.train.epochs,
                    planned.train.steps_per_epoch,
                )
                old = prepared.trainer
                prepared.config = planned
                prepared.trainer = Trainer(
                    planned,
                    prepared.network,
                    old.sampler,
                    prepared.validation,
                    run_dir / CHECKPOINT_DIR,
                    old.provenance,
                )
                prepared.trainer.state = old.state  # the warm start's epoch-0 best
        state = prepared.trainer.fit(deadline=deadline)
        clock.phase("training", start)
        start = time.monotonic()
        export(prepared, state, clock.elapsed())
        clock.phase("export", start)
    finally:
        LOG.removeHandler(handler)
        handler.close()

    # 4. the bundle on the held-out files, written to OUT
    start = time.monotonic()
    new_label = f"{name} (this bundle)"
    bundle = load_bundle(run_dir / BUNDLE_DIR, device)
    from litege_core.learned import Predictor

    new_results = evaluate_methods(
        shapes,
        comparison_methods({new_label: Predictor(bundle, device, fusion="none")}, baselines=False),
        settings,
        seed=options.seed,
    )
    clock.phase("evaluation", start)
    results = new_results + reference_results
    order = [new_label, *predictors, HEAT, KNN]
    table = comparison_table(sorted(results, key=lambda r: settings.index(r.setting)), order)
    means = mean_by_method(results)
    best_reference = min(predictors, key=lambda label: means[label])
    held_out = {
        "split": "test",
        "n_shapes": len(shapes),
        "files": sorted({s.name.rsplit("-", 1)[0] for s in shapes}),
        "settings": list(settings),
        "mean_over_settings": means,
        "by_setting": {
            setting: {
                r.method: {"mean": r.mean, "median": r.median}
                for r in results
                if r.setting == setting
            }
            for setting in settings
        },
        "reference": best_reference,
        "beats_reference": means[new_label] < means[best_reference],
    }
    LOG.info("held-out comparison (mean error, GT mean = 100):\n%s", table)
    manifest = _write_out(run_dir / BUNDLE_DIR, out, held_out)
    evaluation_md = "\n".join(
        [
            f"{data['held_out'].capitalize()} of `{options.meshes}` ({len(shapes)} shapes): "
            "mean error (median), GT mean = 100.",
            "",
            table,
            "",
        ]
    )
    (out / EVALUATION).write_text(evaluation_md)
    collection = {
        "meshes": str(options.meshes),
        "seed": options.seed,
        "files": data["files"],
        "shapes": data["shapes"],
        "solver": options.solver if options.distance_fn is None else "custom",
        "augmentation": data["augmentation"],
        "init": options.init,
    }
    (out / CARD).write_text(_model_card(manifest, table, collection, _credits(options.meshes)))
    load_bundle(out)  # what is served loads
    clock.seconds["total"] = clock.elapsed()
    training = manifest["training"]
    summary = {
        "bundle": str(out),
        "name": manifest["name"],
        "content_hash": manifest["content_hash"],
        "serve": f"litege geodesic FILE --sources 0 --model {out} -o distances.npy",
        "time_budget_s": options.time_budget_s,
        "seconds": clock.seconds,
        "data": data,
        "training": {
            "init": options.init,
            "epochs": training["epochs"],
            "steps": training["steps"],
            "best_epoch": training["best_epoch"],
            "stopped_by_budget": state.stopped_by_budget,
            "val_mean_error": manifest["metrics"]["val_mean_error"],
            "run_dir": str(run_dir),
        },
        "held_out": {k: held_out[k] for k in ("n_shapes", "mean_over_settings", "reference")}
        | {"beats_reference": held_out["beats_reference"]},
    }
    (out / SUMMARY).write_text(json.dumps(summary, indent=2) + "\n")
    LOG.info(
        "bundle %s written to %s in %.0f s: held-out mean %.2f vs %.2f for %s",
        name,
        out,
        clock.seconds["total"],
        means[new_label],
        means[best_reference],
        best_reference,
    )
    return summary


def _write_out(bundle_dir: Path, out: Path, held_out: dict[str, Any]) -> dict[str, Any]:
    """Copy the exported bundle's files into ``out`` and rewrite its manifest with the
    held-out comparison under ``metrics.held_out`` (same files, same content hash)."""
    from litege_core.learned.bundle import MANIFEST, manifest_core, write_manifest

    source = json.loads((bundle_dir / MANIFEST).read_text())
    make_directory(out)
    for filename in source["files"]:
        shutil.copy2(bundle_dir / filename, out / filename)
    metrics = {**source["metrics"], "held_out": held_out}
    manifest = write_manifest(
        out, manifest_core(source), list(source["files"]), source["training"], metrics
    )
    if manifest["content_hash"] != source["content_hash"]:  # pragma: no cover - same files
        raise RuntimeError("the copied bundle changed its content hash")
    return manifest


def _credits(meshes: str | Path) -> str | None:
    for filename in CREDIT_FILES:
        path = Path(meshes) / filename
        if path.is_file():
            return path.read_text()
    return None


def _model_card(
    manifest: dict[str, Any], table: str, collection: dict[str, Any], credits: str | None
) -> str:
    from litege_core.learned.cards import collection_model_card

    return collection_model_card(manifest, table, collection, credits)


# --------------------------------------------------------------------------- matching


def shared_topology(meshes: str | Path) -> tuple[Sequence[str], int, NDArray]:
    """Check that every mesh file of a folder has the same vertex count and faces (vertex
    ``i`` is the same point on every shape, as matching from a folder needs).

    Returns:
        ``(files, n_vertices, faces)``.

    Raises:
        InputError: fewer than three files, a point cloud, or two files of different
            topology (naming both and how they differ).
    """
    from litege_core.io import load_shape
    from litege_core.synth.folder import FOLDER_LIMITS

    files = check_folder(meshes)
    topologies = []
    for name in files:
        shape = load_shape(Path(meshes) / name, kind="mesh", limits=FOLDER_LIMITS)
        topologies.append((name, shape.n_points, np.asarray(shape.faces, dtype=np.int64)))
    return files, *_one_topology(topologies)


def rig_topology(meshes: str | Path) -> tuple[Sequence[str], int, NDArray]:
    """Check that every mesh file of a folder is a rigged, animated glTF (a skinned mesh and at
    least one animation, :func:`~litege_core.synth.folder.rigged_model`) and that their skinned
    bodies share one topology (matching from the poses of one character, or of several files of
    one rig). One file is enough: its poses are the shapes.

    Returns:
        ``(files, n_vertices, faces)`` of the skinned bodies.

    Raises:
        InputError: no mesh file, a file that is not such a rig (the first ten named), or two
            bodies of different topology.
    """
    from litege_core.synth.folder import list_meshes, rigged_model

    files = list_meshes(meshes)
    rigs = [(name, rigged_model(str(Path(meshes) / name))) for name in files]
    others = [name for name, rig in rigs if rig is None]
    if others:
        raise InputError(
            f"--poses needs rigged, animated glTF files (.glb or .gltf with a skinned mesh and "
            f"at least one animation); {len(others)} of {len(files)} are not: "
            f"{', '.join(others[:10])}"
        )
    return files, *_one_topology(
        [(name, len(rig.mesh.vertices), rig.mesh.faces) for name, rig in rigs if rig is not None]
    )


def _one_topology(topologies: list[tuple[str, int, NDArray]]) -> tuple[int, NDArray]:
    """``(n_vertices, faces)`` shared by every ``(file, n_vertices, faces)``.

    Raises:
        InputError: two files of different topology, naming both and how they differ.
    """
    first_name, n_vertices, first_faces = topologies[0]
    for name, n_points, faces in topologies[1:]:
        if n_points == n_vertices and np.array_equal(faces, first_faces):
            continue
        if n_points != n_vertices:
            how = f"{n_points} vertices against {n_vertices}"
        elif faces.shape != first_faces.shape:
            how = f"{faces.shape[0]} faces against {first_faces.shape[0]}"
        else:
            row = int(np.flatnonzero((faces != first_faces).any(axis=1))[0])
            how = f"face {row} is {faces[row].tolist()}, not {first_faces[row].tolist()}"
        raise InputError(
            f"matching from a folder needs meshes that share one topology (the same "
            f"vertex count and faces, vertex i the same point on every shape): {name} and "
            f"{first_name} differ ({how}). Remesh them onto one template first, or train "
            "a geodesic model instead: litege train geodesic --meshes DIR --out BUNDLE"
        )
    return n_vertices, first_faces


__all__ = [
    "DATA_SHARE",
    "BudgetedFactory",
    "DataBudgetReached",
    "FolderTrainOptions",
    "build_folder_data",
    "check_folder",
    "folder_config",
    "measure_step_rate",
    "plan_schedule",
    "rig_topology",
    "shared_topology",
    "train_from_meshes",
]
