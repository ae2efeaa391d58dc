"""A whole training run: dataset → basis → view tables → network → epochs → bundle.

:func:`prepare_run` does everything before the first step (once per run: the tables are
built in memory, deterministically from the config, and rebuilt identically on resume);
:func:`train_geodesic` trains (optionally resuming from a checkpoint) and exports the best
model with :func:`~litege_core.learned.bundle.save_bundle` into ``RUN_DIR/bundle``.

Launched by ``torchrun`` (``WORLD_SIZE > 1``), :func:`train_geodesic` joins the process group
and trains data-parallel (:mod:`~litege_core.train.distributed`): rank 0 fits or reads the
basis first, then every rank builds the same tables; rank 0 writes the log file, checkpoints
and the bundle, whose manifest every rank returns.
"""

from __future__ import annotations

import logging
import platform
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, cast

import numpy as np
import torch

import litege_core
from litege_core.datasets import GeodesicDataset
from litege_core.descriptor import UdfPcaBasis
from litege_core.errors import InputError
from litege_core.files import make_directory
from litege_core.learned import (
    ModelBundle,
    load_bundle,
    load_shipped,
    save_bundle,
    shipped_bundles,
)
from litege_core.nets import GeodesicNet
from litege_core.nets.geodesic import OutputKind
from litege_core.train.basis import prepare_basis
from litege_core.train.config import TrainConfig, check_time_budget
from litege_core.train.data import (
    PairSampler,
    ValidationPairs,
    ViewTables,
    build_view_tables,
    coordinate_statistics,
    dataset_fingerprint,
    datasets_fingerprint,
    load_training_arrays,
    validation_pairs,
)
from litege_core.train.distributed import (
    DistributedContext,
    convert_sync_batchnorm,
    init_distributed,
    revert_sync_batchnorm,
)
from litege_core.train.trainer import Trainer, TrainState, evaluate, seed_everything

LOG = logging.getLogger("litege.train")
BUNDLE_DIR = "bundle"
CHECKPOINT_DIR = "checkpoints"
LOG_FILE = "train.log"
_VAL_SEED_OFFSET = 7919  # validation views and pairs use seed + offset


@dataclass
class PreparedRun:
    """Everything :func:`train_geodesic` needs, built by :func:`prepare_run`."""

    config: TrainConfig
    device: torch.device
    basis: UdfPcaBasis
    basis_source: str
    train: ViewTables
    validation: ValidationPairs
    network: GeodesicNet
    trainer: Trainer
    fingerprint: dict[str, Any]
    coord_mean: list[float]
    coord_std: list[float]
    seconds: dict[str, float]


@dataclass
class RunResult:
    """What :func:`train_geodesic` returns."""

    state: TrainState
    manifest: dict[str, Any] | None
    run_dir: Path
    prepared: PreparedRun


def load_init_bundle(init: str | Path) -> ModelBundle:
    """The bundle a run is warm-started from: a shipped model name or a bundle directory."""
    path = Path(init)
    if path.is_dir():
        return load_bundle(path)
    if str(init) in shipped_bundles():
        return load_shipped(str(init))
    raise InputError(
        f"--init {init!r} is neither a bundle directory nor a shipped model {shipped_bundles()}"
    )


def prepare_run(
    config: TrainConfig,
    init: str | Path | None = None,
    distributed: DistributedContext | None = None,
) -> PreparedRun:
    """Load the dataset, prepare the basis, build the tables, create network and trainer.

    With ``init`` (a shipped model name or a bundle directory) the run is warm-started: the
    bundle's basis replaces the configured one and its network (weights, coordinate
    normalization, width) is the starting point; the optimizer and schedule start fresh.
    With ``distributed`` the run is this rank's part of a data-parallel run: its device is
    the context's, the network's BatchNorm layers are synchronized across ranks.
    """
    init_bundle = None if init is None else load_init_bundle(init)
    if config.train.threads:
        torch.set_num_threads(config.train.threads)
    device = config.resolve_device() if distributed is None else distributed.device
    run_dir = config.run_dir
    make_directory(run_dir)
    seconds: dict[str, float] = {}
    start = time.perf_counter()
    dataset = GeodesicDataset(config.data.dataset)
    datasets = config.data.datasets
    fingerprint = (
        dataset_fingerprint(datasets[0]) if len(datasets) == 1 else datasets_fingerprint(datasets)
    )
    train_arrays, train_faces = load_training_arrays(
        datasets, "train", config.data.max_train_shapes
    )
    val_arrays, val_faces = load_training_arrays(datasets, "val", config.data.max_val_shapes)
    if len(val_arrays["seed"]) == 0:
        raise InputError(f"datasets {datasets} have no validation shapes")
    seconds["load"] = time.perf_counter() - start

    start = time.perf_counter()
    if init_bundle is not None:
        basis = init_bundle.basis
        basis_source = f"init bundle {init_bundle.name} ({init_bundle.content_hash[:12]})"
    else:

        def basis_for_run() -> tuple[UdfPcaBasis, str]:
            return prepare_basis(
                config.basis,
                run_dir,
                train_arrays,
                train_faces,
                dataset.spec.category,
                config.train.seed,
            )

        if distributed is None:
            basis, basis_source = basis_for_run()
        else:  # rank 0 first: a basis it fits is saved in the run directory for the others
            if distributed.is_main:
                basis, basis_source = basis_for_run()
            distributed.barrier()
            if not distributed.is_main:
                basis, basis_source = basis_for_run()
    seconds["basis"] = time.perf_counter() - start

    start = time.perf_counter()
    common: dict[str, Any] = dict(
        basis=basis,
        clean_samples=config.data.clean_samples,
        augment=config.augment,
        device=device,
        chunk=config.data.view_chunk,
    )
    train = build_view_tables(
        train_arrays,
        faces=train_faces,
        n_views=config.data.views_per_shape,
        seed=config.train.seed,
        **common,
    )
    val_tables = build_view_tables(
        val_arrays,
        faces=val_faces,
        n_views=1 + config.data.val_augmented_views,
        seed=config.train.seed + _VAL_SEED_OFFSET,
        **common,
    )
    val = validation_pairs(
        val_tables,
        config.data.val_sources,
        config.data.val_targets,
        config.train.seed + _VAL_SEED_OFFSET,
    )
    seconds["tables"] = time.perf_counter() - start
    LOG.info(
        "tables: %d train views of %d shapes, %d val views (%d fixed pairs), %d vertices, "
        "%d source rows, built in %.1f s on %s",
        train.n_views,
        train.n_shapes,
        val_tables.n_views,
        val.n_pairs,
        train.n_vertices,
        train.n_rows,
        seconds["tables"],
        device,
    )

    seed_everything(config.train.seed)
    if init_bundle is not None:
        network = init_bundle.network.float().train()
        mean = network.coord_mean.double().cpu().numpy()
        std = network.coord_std.double().cpu().numpy()
        if (network.width, network.output) != (config.network.width, config.network.output):
            LOG.info(
                "warm start: the init bundle's network (width %d, output %s) replaces the "
                "configured one (width %d, output %s)",
                network.width,
                network.output,
                config.network.width,
                config.network.output,
            )
    else:
        output = cast(OutputKind, config.network.output)  # checked by NetworkConfig
        network = GeodesicNet(config.network.width, basis.n_components, output)
        mean, std = coordinate_statistics(train)
        network.set_coord_normalization(mean, std)
    network.to(device)
    if distributed is not None:
        convert_sync_batchnorm(network, device)
    sampler = PairSampler(
        train,
        config.train.batch_views,
        config.train.sources_per_view,
        config.train.targets_per_view,
        config.train.seed,
    )
    provenance = {"dataset": fingerprint["manifest_sha256"], "basis_hash": basis.content_hash}
    if init_bundle is not None:
        provenance["init_bundle"] = init_bundle.content_hash
    trainer = Trainer(
        config, network, sampler, val, run_dir / CHECKPOINT_DIR, provenance, distributed
    )
    return PreparedRun(
        config=config,
        device=device,
        basis=basis,
        basis_source=basis_source,
        train=train,
        validation=val,
        network=network,
        trainer=trainer,
        fingerprint=fingerprint,
        coord_mean=mean.tolist(),
        coord_std=std.tolist(),
        seconds=seconds,
    )


def residual_statistics(tables: ViewTables) -> dict[str, float]:
    """Mean, std and 99th percentile of the training views' PCA reconstruction residuals
    (all views, and clean views only): the reference for an out-of-distribution score."""
    residual = tables.residual.double().cpu().numpy()
    clean = residual[tables.kind.cpu().numpy() == 0]
    return {
        "residual_mean": float(residual.mean()),
        "residual_std": float(residual.std()),
        "residual_p99": float(np.quantile(residual, 0.99)),
        "residual_clean_mean": float(clean.mean()),
        "residual_clean_std": float(clean.std()),
    }


def export(prepared: PreparedRun, state: TrainState, seconds_total: float) -> dict[str, Any]:
    """Load the best weights, evaluate them and write ``RUN_DIR/bundle``; returns the
    bundle manifest."""
    config = prepared.config
    trainer = prepared.trainer
    trainer.load_best()
    report = evaluate(prepared.network, prepared.validation)
    steps_per_second = state.step / state.step_seconds if state.step_seconds > 0 else None
    training = {
        "config": config.to_dict(),
        "config_hash": config.content_hash(),
        "dataset": prepared.fingerprint,
        "basis_source": prepared.basis_source,
        "init_bundle": prepared.trainer.provenance.get("init_bundle"),
        "n_train_shapes": prepared.train.n_shapes,
        "n_train_views": prepared.train.n_views,
        "n_val_views": prepared.validation.tables.n_views,
        "steps": state.step,
        "epochs": state.epoch,
        "best_epoch": state.best_epoch,
        "stopped_early": state.stopped_early,
        "pairs_per_step": config.train.pairs_per_step,
        "steps_per_second": steps_per_second,
        "coord_mean": prepared.coord_mean,
        "coord_std": prepared.coord_std,
        **residual_statistics(prepared.train),
        "seconds": {**prepared.seconds, "train": state.seconds, "total": seconds_total},
        "device": str(prepared.device),
        "device_name": (
            torch.cuda.get_device_name(prepared.device)
            if prepared.device.type == "cuda"
            else platform.processor() or platform.machine()
        ),
        "torch": torch.__version__,
        "litege": litege_core.__version__,
        "history": state.history,
    }
    metrics = {
        "val_mean_error": report.mean,
        "val_median_error": report.median,
        "val_l1": report.l1,
        "val_by_kind": report.by_kind,
        "val_gt_mean": report.gt_mean,
        "val_pairs": report.n_pairs,
        "normalization": "validation ground-truth mean = 100",
    }
    manifest = save_bundle(
        config.run_dir / BUNDLE_DIR,
        name=config.output.name,
        category=config.output.category,
        basis=prepared.basis,
        network=prepared.network.cpu(),
        training=training,
        metrics=metrics,
        weights_dtype=config.output.torch_weights_dtype,
    )
    prepared.network.to(prepared.device)
    LOG.info(
        "exported %s: val mean %.3f median %.3f (best epoch %d) → %s",
        config.output.name,
        report.mean,
        report.median,
        state.best_epoch,
        config.run_dir / BUNDLE_DIR,
    )
    return manifest


def train_geodesic(
    config: TrainConfig,
    *,
    resume: str | Path | None = None,
    init: str | Path | None = None,
    max_epochs: int | None = None,
    export_bundle: bool = True,
    time_budget_s: float | None = None,
) -> RunResult:
    """Run (or resume) a training and export the bundle.

    Args:
        config: the run configuration.
        resume: a ``last.safetensors`` checkpoint to continue from.
        init: warm start from this bundle (shipped name or directory; see
            :func:`prepare_run`). A resumed run must be given the same ``init``.
        max_epochs: stop after this many epochs in this call (no export unless the run is
            finished); ``None``: train to the end.
        export_bundle: write ``RUN_DIR/bundle`` when training is finished.
        time_budget_s: wall-clock budget of this call's training, in seconds (the trainer's
            deadline, counted from the start of training): a run stopped by it exports its
            best checkpoint as a finished run does, and can be resumed for more epochs.

    Raises:
        InputError: a time budget that is not positive, or a run directory that cannot be made.
    """
    check_time_budget(time_budget_s)
    start = time.perf_counter()
    run_dir = config.run_dir
    make_directory(run_dir)
    distributed = init_distributed(config.resolve_device())  # None unless under torchrun
    main = distributed is None or distributed.is_main
    handler: logging.Handler = (
        logging.FileHandler(run_dir / LOG_FILE) if main else logging.NullHandler()
    )
    handler.setFormatter(logging.Formatter("%(asctime)s %(message)s", "%Y-%m-%dT%H:%M:%S"))
    LOG.addHandler(handler)
    level = LOG.level
    if not main:  # the other ranks only report problems
        LOG.setLevel(logging.WARNING)
    elif LOG.level == logging.NOTSET or LOG.level > logging.INFO:
        LOG.setLevel(logging.INFO)
    try:
        LOG.info(
            "training %s: %d epochs × %d steps × %d pairs, lr %g → %g (%s cosine), seed %d",
            config.output.name,
            config.train.epochs,
            config.train.steps_per_epoch,
            config.train.pairs_per_step,
            config.train.lr,
            config.train.eta_min,
            config.train.schedule,
            config.train.seed,
        )
        prepared = prepare_run(config, init, distributed)
        if resume is not None:
            changed = prepared.trainer.load_checkpoint(resume)
            LOG.info(
                "resumed from %s at epoch %d, step %d%s",
                resume,
                prepared.trainer.state.epoch,
                prepared.trainer.state.step,
                f" (changed: {', '.join(changed)})" if changed else "",
            )
        elif init is not None:
            prepared.trainer.start_from_baseline()
        deadline = None if time_budget_s is None else time.monotonic() + time_budget_s
        state = prepared.trainer.fit(max_epochs, deadline=deadline)
        if distributed is not None:
            revert_sync_batchnorm(prepared.network)  # a plain network to export and return
        finished = (
            state.stopped_early or state.stopped_by_budget or state.epoch >= config.train.epochs
        )
        manifest = None
        if export_bundle and finished:
            if main:
                manifest = export(prepared, state, time.perf_counter() - start)
            if distributed is not None:
                manifest = distributed.broadcast(manifest)
        if distributed is not None:  # every rank done with its collectives before teardown
            distributed.barrier()
        return RunResult(state, manifest, run_dir, prepared)
    finally:
        LOG.removeHandler(handler)
        handler.close()
        if not main:
            LOG.setLevel(level)
        if distributed is not None:
            distributed.close()


__all__ = [
    "BUNDLE_DIR",
    "CHECKPOINT_DIR",
    "LOG_FILE",
    "PreparedRun",
    "RunResult",
    "export",
    "prepare_run",
    "residual_statistics",
    "train_geodesic",
]
