"""The training loop of the geodesic network: L1 on residual targets, Adam, cosine schedule,
validation each epoch, best-validation checkpoint, exact resume, early stopping, export.

**Forward in training mode.** A batch holds ``B`` views with ``R_b`` sources and ``T_b``
targets each (:class:`~litege_core.train.data.PairBatch`). :func:`pair_outputs` runs the shape
MLP once per view (``B`` rows), the coordinate / fusion / point MLPs once per point (one call on
the ``B·(R_b + T_b)`` stacked sources and targets, so BatchNorm normalizes them together, as
the reference normalizes its ``2B`` stacked source and destination rows) and the head on the
``B·R_b·T_b`` cross pairs. Shape and point embeddings are therefore never recomputed per pair.
Because every view contributes the same number of pairs, the shape-MLP batch statistics over
the ``B`` distinct descriptors equal those over the per-pair duplicated descriptors of the
reference's ``forward``. (:meth:`GeodesicNet.pairwise` is not used for training: it embeds the
sources and the targets in two separate calls, i.e. with two different BatchNorm batches.)

**Schedule.** The learning rate is a pure function of the global step
(:func:`cosine_lr`: cosine from ``lr`` to ``eta_min`` over all ``epochs × steps_per_epoch``
steps, or per epoch), written into the optimizer before every step. Nothing about the
schedule is restored from a checkpoint, so the reference's resume bug (``T_max=1``
restored, spec §3.5 / §10.2) cannot occur.

**Checkpoints** (no pickle). ``checkpoints/last.safetensors`` is written atomically after
every epoch and holds the model state (``model/…``, BatchNorm statistics and coordinate
normalization included), the Adam state (``optim/<param>/<key>``) and the batch generator
state (``sampler/rng``) as tensors; its header metadata holds a JSON document with the epoch
and step counters, the best validation error and epoch, the patience counter, the history,
the Adam hyper-parameters, the config and the dataset / basis fingerprints.
``checkpoints/best.safetensors`` holds the weights of the best validation epoch. Resuming
from ``last`` reproduces an uninterrupted run bit for bit on the same machine and device.

**Validation** is the geodesic error of spec §7.1 on fixed validation pairs: predictions
``output/1.42 + ‖s − d‖`` against ``scale · g_raw``, absolute errors with the ground truth
rescaled to mean 100 (normalized by the validation ground-truth mean), mean and median; the
mean selects the checkpoint and drives early stopping (it is the validation L1 up to the
constant 1.42 / GT mean, except for the clipping of negative residual targets).

**Time budget.** ``fit(deadline=...)`` (a :func:`time.monotonic` instant) stops the run at a
wall-clock budget: the deadline is checked every :data:`BUDGET_CHECK_STEPS` steps, an epoch
cut short there is validated and checkpointed like a full one (it counts as an epoch, with
fewer steps), and no new epoch starts after the deadline (``TrainState.stopped_by_budget``).
The best checkpoint is exported as usual. A run stopped by its budget can be resumed, but it
no longer reproduces an uninterrupted run bit for bit (its epochs hold fewer steps).

**Data parallel** (``torchrun``; :mod:`~litege_core.train.distributed`). With a
:class:`~litege_core.train.distributed.DistributedContext` every rank draws the same global
batch and trains on its share of the views through DistributedDataParallel (synchronized
BatchNorm), so a step equals one process's step on the global batch up to floating-point
reduction order. Rank 0 alone validates (the report is broadcast), writes checkpoints and
logs; time-budget checks are agreed by all ranks.
"""

from __future__ import annotations

import json
import logging
import math
import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from safetensors import SafetensorError, safe_open
from safetensors.torch import save_file

from litege_core.errors import ArtifactError, InputError
from litege_core.metrics import geodesic_error
from litege_core.nets import GeodesicNet, geodesic_from_residual, load_state, state_to_tensors
from litege_core.train.config import TrainConfig
from litege_core.train.data import PairBatch, PairSampler, ValidationPairs, gather_pairs
from litege_core.train.distributed import DistributedContext

LOG = logging.getLogger("litege.train")
CHECKPOINT_FORMAT = "litege-train-checkpoint"
CHECKPOINT_VERSION = 1
LAST = "last.safetensors"
BEST = "best.safetensors"
_HEADER_KEY = "litege_checkpoint"
VAL_CHUNK_PAIRS = 1 << 15  # head rows per validation call
BUDGET_CHECK_STEPS = 10  # steps between two looks at the clock of a time-budgeted run

#: config keys that must not change when a run is resumed (the rest may: epochs, patience,
#: learning rates, device, output).
RESUME_FIXED = {
    "data": None,
    "augment": None,
    "basis": None,
    "network": None,
    "train": ("batch_views", "sources_per_view", "targets_per_view", "steps_per_epoch", "seed"),
}


# --------------------------------------------------------------------------- pieces


def cosine_lr(step: int, config: TrainConfig) -> float:
    """Learning rate of (0-based) global ``step``: ``η_min + (η_0 − η_min)(1 + cos πt)/2``
    with ``t = step / total_steps`` (``schedule="step"``) or ``t = epoch / epochs``
    (``schedule="epoch"``, constant within an epoch)."""
    opt = config.train
    if opt.schedule == "epoch":
        fraction = (step // opt.steps_per_epoch) / opt.epochs
    else:
        fraction = step / opt.total_steps
    fraction = min(max(fraction, 0.0), 1.0)
    return opt.eta_min + (opt.lr - opt.eta_min) * 0.5 * (1.0 + math.cos(math.pi * fraction))


def pair_outputs(
    net: GeodesicNet, descriptors: torch.Tensor, points: torch.Tensor, n_sources: int
) -> torch.Tensor:
    """Network outputs on the cross pairs of each view, each point embedded once.

    Args:
        net: the network (training or eval mode).
        descriptors: ``(B, E)`` view descriptors.
        points: ``(B, R + T, 3)`` canonical coordinates, the ``R = n_sources`` sources first.
        n_sources: ``R``.

    Returns:
        ``(B, R, T)`` outputs in target units (1.42 × canonical units, ≥ 0).
    """
    shape_emb = net.shape_embedding(descriptors)  # (B, n)
    emb = net.point_embedding(points, shape_emb)  # (B, R + T, n)
    return net.head(emb[:, :n_sources, None, :], emb[:, None, n_sources:, :])


class PairForward(torch.nn.Module):
    """:func:`pair_outputs` as a module's ``forward``: DistributedDataParallel synchronizes
    gradients of what runs through ``forward``, so this is what a data-parallel run wraps."""

    def __init__(self, net: GeodesicNet) -> None:
        super().__init__()
        self.net = net

    def forward(
        self, descriptors: torch.Tensor, points: torch.Tensor, n_sources: int
    ) -> torch.Tensor:
        return pair_outputs(self.net, descriptors, points, n_sources)


def training_loss(net: GeodesicNet, batch: PairBatch) -> torch.Tensor:
    """Mean L1 between the outputs and the residual targets of a batch (scalar)."""
    n_sources = batch.target.shape[1]
    outputs = pair_outputs(net, batch.descriptors, batch.points, n_sources)
    return torch.nn.functional.l1_loss(outputs, batch.target)


@dataclass(frozen=True)
class ValidationReport:
    """Validation metrics (errors with the ground truth rescaled to mean 100).

    Attributes:
        mean: mean absolute error over all fixed pairs (the selection metric).
        median: median absolute error.
        l1: mean |output − residual target| in target units (1.42 × canonical).
        by_kind: ``{"clean": {"mean", "median"}, "augmented": {...}}``.
        gt_mean: ground-truth mean of the pairs, canonical units.
        n_pairs: evaluated pairs.
    """

    mean: float
    median: float
    l1: float
    by_kind: dict[str, dict[str, float]]
    gt_mean: float
    n_pairs: int

    def to_dict(self) -> dict[str, Any]:
        return {
            "mean": self.mean,
            "median": self.median,
            "l1": self.l1,
            "by_kind": self.by_kind,
            "gt_mean": self.gt_mean,
            "n_pairs": self.n_pairs,
        }


@torch.no_grad()
def evaluate(net: GeodesicNet, pairs: ValidationPairs) -> ValidationReport:
    """Geodesic error of ``net`` (put in eval mode, restored afterwards) on fixed pairs."""
    was_training = net.training
    net.eval()
    tables = pairs.tables
    per_view = pairs.rows.shape[1] * pairs.targets.shape[1]
    chunk = max(1, VAL_CHUNK_PAIRS // per_view)
    predicted, truth, l1 = [], [], []
    try:
        for start in range(0, tables.n_views, chunk):
            views = torch.arange(start, min(start + chunk, tables.n_views), device=tables.device)
            batch = gather_pairs(tables, views, pairs.rows[views], pairs.targets[views])
            out = pair_outputs(net, batch.descriptors, batch.points, pairs.rows.shape[1])
            predicted.append(geodesic_from_residual(out, batch.euclidean).flatten(1))
            truth.append(batch.geodesic.flatten(1))
            l1.append((out - batch.target).abs().flatten(1))
    finally:
        net.train(was_training)
    pred = torch.cat(predicted).double().cpu().numpy()  # (Nv, P)
    gt = torch.cat(truth).double().cpu().numpy()
    overall = geodesic_error(pred, gt)
    kinds = tables.kind.cpu().numpy()
    by_kind = {}
    for name, code in (("clean", 0), ("augmented", 1)):
        mask = kinds == code
        if mask.any():
            report = geodesic_error(pred[mask], gt[mask], gt_mean=overall.gt_mean)
            by_kind[name] = {"mean": report.mean, "median": report.median}
    return ValidationReport(
        mean=overall.mean,
        median=overall.median,
        l1=float(torch.cat(l1).double().mean()),
        by_kind=by_kind,
        gt_mean=overall.gt_mean,
        n_pairs=overall.n_pairs,
    )


# --------------------------------------------------------------------------- checkpoints


def _optimizer_tensors(optimizer: torch.optim.Optimizer) -> tuple[dict[str, torch.Tensor], dict]:
    state = optimizer.state_dict()
    tensors = {}
    for index, entries in state["state"].items():
        for key, value in entries.items():
            tensor = value if isinstance(value, torch.Tensor) else torch.tensor(value)
            tensors[f"optim/{index}/{key}"] = tensor.detach().cpu().contiguous().clone()
    return tensors, {"param_groups": state["param_groups"]}


def _optimizer_state(tensors: dict[str, torch.Tensor], header: dict) -> dict[str, Any]:
    state: dict[int, dict[str, torch.Tensor]] = {}
    for name, tensor in tensors.items():
        if name.startswith("optim/"):
            _, index, key = name.split("/", 2)
            state.setdefault(int(index), {})[key] = tensor
    groups = []
    for group in header["param_groups"]:
        group = dict(group)
        if isinstance(group.get("betas"), list):
            group["betas"] = tuple(group["betas"])
        groups.append(group)
    return {"state": state, "param_groups": groups}


def write_checkpoint(path: Path, tensors: dict[str, torch.Tensor], header: dict[str, Any]) -> None:
    """Write tensors + a JSON header into one safetensors file, atomically."""
    path.parent.mkdir(parents=True, exist_ok=True)
    temporary = path.with_name(f"{path.name}.tmp-{os.getpid()}")
    metadata = {"format": CHECKPOINT_FORMAT, _HEADER_KEY: json.dumps(header, sort_keys=True)}
    try:
        save_file(tensors, str(temporary), metadata=metadata)
        os.replace(temporary, path)
    finally:
        if temporary.exists():
            temporary.unlink()


def read_checkpoint(path: str | Path) -> tuple[dict[str, torch.Tensor], dict[str, Any]]:
    """Inverse of :func:`write_checkpoint`; ArtifactError on a damaged or foreign file."""
    try:
        with safe_open(str(path), framework="pt") as handle:
            metadata = handle.metadata() or {}
            tensors = {name: handle.get_tensor(name) for name in handle.keys()}  # noqa: SIM118
    except (OSError, SafetensorError, ValueError) as exc:
        raise ArtifactError(f"cannot read checkpoint {path}: {exc}") from exc
    if metadata.get("format") != CHECKPOINT_FORMAT or _HEADER_KEY not in metadata:
        raise ArtifactError(f"{path} is not a LiteGE training checkpoint")
    try:
        header = json.loads(metadata[_HEADER_KEY])
    except ValueError as exc:
        raise ArtifactError(f"{path}: checkpoint header is not valid JSON: {exc}") from exc
    if header.get("version") != CHECKPOINT_VERSION:
        raise ArtifactError(f"{path}: unsupported checkpoint version {header.get('version')!r}")
    return tensors, header


def check_resumable(saved: dict[str, Any], config: TrainConfig) -> list[str]:
    """Raise InputError when ``config`` changes a key of :data:`RESUME_FIXED` relative to the
    checkpoint's config; return the names of the other keys that changed."""
    current = config.to_dict()
    fixed: list[str] = []
    changed: list[str] = []
    for section, values in current.items():
        for key, value in values.items():
            if saved.get(section, {}).get(key) == value:
                continue
            keys = RESUME_FIXED.get(section, ())
            (fixed if keys is None or key in keys else changed).append(f"{section}.{key}")
    if fixed:
        raise InputError(f"cannot resume: the config changed {fixed} since the checkpoint")
    return changed


# --------------------------------------------------------------------------- trainer


@dataclass
class EpochRecord:
    """One line of the training history."""

    epoch: int
    step: int
    loss: float
    val_mean: float
    val_median: float
    val_l1: float
    lr: float
    seconds: float
    train_seconds: float
    best: bool

    def to_dict(self) -> dict[str, Any]:
        return dict(self.__dict__)


@dataclass
class TrainState:
    """Counters and bests that a checkpoint carries besides tensors."""

    epoch: int = 0  # completed epochs
    step: int = 0  # completed optimizer steps
    best_error: float = math.inf
    best_epoch: int = 0
    bad_epochs: int = 0
    stopped_early: bool = False
    stopped_by_budget: bool = False  # fit() reached its wall-clock deadline
    seconds: float = 0.0  # epochs including validation
    step_seconds: float = 0.0  # optimizer steps only
    history: list[dict[str, Any]] = field(default_factory=list)


class Trainer:
    """Runs epochs of fixed steps with validation, checkpoints and early stopping.

    Args:
        config: the run configuration.
        network: a :class:`GeodesicNet` on the tables' device, coordinate normalization set.
        sampler: batch sampler over the training tables.
        validation: fixed validation pairs.
        checkpoint_dir: where ``last.safetensors`` and ``best.safetensors`` go.
        provenance: JSON-safe fingerprints stored in (and checked against) checkpoints, e.g.
            ``{"dataset": ..., "basis_hash": ...}``.
        distributed: this rank's place in a data-parallel run (``None``: one process). The
            network's BatchNorm layers must already be synchronized
            (:func:`~litege_core.train.distributed.convert_sync_batchnorm`).
    """

    def __init__(
        self,
        config: TrainConfig,
        network: GeodesicNet,
        sampler: PairSampler,
        validation: ValidationPairs,
        checkpoint_dir: str | Path,
        provenance: dict[str, Any] | None = None,
        distributed: DistributedContext | None = None,
    ) -> None:
        self.config = config
        self.net = network
        self.sampler = sampler
        self.validation = validation
        self.checkpoint_dir = Path(checkpoint_dir)
        self.provenance = provenance or {}
        self.optimizer = torch.optim.Adam(network.parameters(), lr=config.train.lr)
        self.state = TrainState()
        self.distributed = distributed
        self._ddp: torch.nn.Module | None = None  # built at the first step (after a resume)
        if distributed is not None:
            distributed.local_slice(config.train.batch_views)  # divisible, or InputError

    @property
    def is_main(self) -> bool:
        """Whether this process validates, checkpoints and logs (rank 0, or the only one)."""
        return self.distributed is None or self.distributed.is_main

    # ----------------------------------------------------------------- checkpoints
    def _header(self, optim_meta: dict) -> dict[str, Any]:
        return {
            "version": CHECKPOINT_VERSION,
            **self.state.__dict__,
            "optimizer": optim_meta,
            "config": self.config.to_dict(),
            "provenance": self.provenance,
        }

    def save_checkpoint(self, path: Path | None = None) -> Path:
        """Write the full training state (default ``checkpoint_dir/last.safetensors``)."""
        path = self.checkpoint_dir / LAST if path is None else Path(path)
        tensors = {f"model/{k}": v for k, v in state_to_tensors(self.net).items()}
        optim_tensors, optim_meta = _optimizer_tensors(self.optimizer)
        tensors.update(optim_tensors)
        tensors["sampler/rng"] = self.sampler.get_state().clone()
        write_checkpoint(path, tensors, self._header(optim_meta))
        return path

    def load_checkpoint(self, path: str | Path) -> list[str]:
        """Restore a state written by :meth:`save_checkpoint`; returns the config keys that
        differ from the checkpoint's (allowed ones only; others raise InputError)."""
        tensors, header = read_checkpoint(path)
        changed = check_resumable(header["config"], self.config)
        for key, value in self.provenance.items():
            if header.get("provenance", {}).get(key) != value:
                raise InputError(f"cannot resume from {path}: its {key} differs from this run's")
        model = {k[len("model/") :]: v for k, v in tensors.items() if k.startswith("model/")}
        load_state(self.net, {k: v.to(self.net.coord_mean.device) for k, v in model.items()})
        optim = _optimizer_state(tensors, header["optimizer"])
        try:
            self.optimizer.load_state_dict(optim)
        except (ValueError, KeyError, RuntimeError) as exc:
            raise ArtifactError(f"{path}: optimizer state does not fit: {exc}") from exc
        if "sampler/rng" not in tensors:
            raise ArtifactError(f"{path}: checkpoint lacks the sampler state")
        self.sampler.set_state(tensors["sampler/rng"])
        names = TrainState.__dataclass_fields__
        self.state = TrainState(**{k: header[k] for k in names if k in header})
        return changed

    def _save_best(self) -> None:
        write_checkpoint(
            self.checkpoint_dir / BEST,
            state_to_tensors(self.net),
            {
                "version": CHECKPOINT_VERSION,
                "epoch": self.state.epoch,
                "val_mean": self.state.best_error,
                "network": self.net.config(),
            },
        )

    def start_from_baseline(self) -> float:
        """Score the starting network (a warm start) as epoch 0's best, so the exported model
        is never worse on this validation set than the one the run started from. Returns
        the starting validation error."""
        report = self._validate()
        self.state.best_error = report.mean
        self.state.best_epoch = 0
        if self.is_main:
            self._save_best()
        LOG.info("warm start: validation error %.3f before training", report.mean)
        return report.mean

    def load_best(self) -> None:
        """Load the best-validation weights into the network (no-op before any epoch)."""
        path = self.checkpoint_dir / BEST
        if path.exists():
            tensors, _ = read_checkpoint(path)
            device = self.net.coord_mean.device
            load_state(self.net, {k: v.to(device) for k, v in tensors.items()})

    # ----------------------------------------------------------------- loop
    def _validate(self) -> ValidationReport:
        """:func:`evaluate` on rank 0, broadcast to the other ranks."""
        if self.distributed is None:
            return evaluate(self.net, self.validation)
        report = evaluate(self.net, self.validation) if self.is_main else None
        shared = self.distributed.broadcast(report)
        if shared is None:  # pragma: no cover - rank 0 always has a report
            raise RuntimeError("no validation report from rank 0")
        return shared

    def _deadline_passed(self, deadline: float) -> bool:
        """Whether the time budget is spent (on any rank: all ranks stop together)."""
        passed = time.monotonic() >= deadline
        return passed if self.distributed is None else self.distributed.any(passed)

    def _step_loss(self) -> torch.Tensor:
        """The loss of the next batch (this rank's share of it in a data-parallel run)."""
        if self.distributed is None:
            return training_loss(self.net, self.sampler.sample())
        if self._ddp is None:
            from litege_core.train.distributed import wrap_ddp

            self._ddp = wrap_ddp(PairForward(self.net), self.distributed)
        views, rows, targets = self.sampler.draw()  # the global batch, the same on every rank
        share = self.distributed.local_slice(views.shape[0])
        batch = gather_pairs(self.sampler.tables, views[share], rows[share], targets[share])
        outputs = self._ddp(batch.descriptors, batch.points, batch.target.shape[1])
        return torch.nn.functional.l1_loss(outputs, batch.target)

    def train_epoch(self, deadline: float | None = None) -> float:
        """One epoch of ``steps_per_epoch`` steps; returns the mean training loss.

        With ``deadline`` (a :func:`time.monotonic` instant) the epoch ends early, after a
        multiple of :data:`BUDGET_CHECK_STEPS` steps, once the deadline has passed (so it takes at
        least ``min(BUDGET_CHECK_STEPS, steps_per_epoch)`` steps)."""
        opt = self.config.train
        self.net.train()
        total = torch.zeros((), dtype=torch.float64, device=self.net.coord_mean.device)
        steps = 0
        for _ in range(opt.steps_per_epoch):
            if (
                deadline is not None
                and steps
                and steps % BUDGET_CHECK_STEPS == 0
                and self._deadline_passed(deadline)
            ):
                break
            lr = cosine_lr(self.state.step, self.config)
            for group in self.optimizer.param_groups:
                group["lr"] = lr
            loss = self._step_loss()
            self.optimizer.zero_grad(set_to_none=True)
            loss.backward()
            self.optimizer.step()
            total += loss.detach()
            self.state.step += 1
            steps += 1
        if self.distributed is not None:  # equal shares: the mean of the ranks' means
            total = self.distributed.mean(total)
        return float(total) / steps

    def fit(self, max_epochs: int | None = None, *, deadline: float | None = None) -> TrainState:
        """Train until ``epochs`` are done, early stopping triggers or the deadline passes.

        Args:
            max_epochs: stop after this many epochs *in this call* (the schedule still spans
                the configured ``epochs``; used to interrupt and resume).
            deadline: a :func:`time.monotonic` instant: the wall-clock budget of this call
                (see the module docstring); the epoch running then is cut short after its
                current chunk of :data:`BUDGET_CHECK_STEPS` steps, validated and checkpointed,
                and ``state.stopped_by_budget`` is set.
        """
        try:
            return self._fit(max_epochs, deadline)
        finally:
            # The DistributedDataParallel wrapper holds the process group and Gloo's pending
            # work: dropped here (rebuilt at the next step) so that destroying the group
            # really frees them, instead of their threads dying at interpreter exit (SIGABRT).
            self._ddp = None

    def _fit(self, max_epochs: int | None, deadline: float | None) -> TrainState:
        opt = self.config.train
        run = 0
        self.state.stopped_by_budget = False
        while self.state.epoch < opt.epochs and not self.state.stopped_early:
            if max_epochs is not None and run >= max_epochs:
                break
            if deadline is not None and self._deadline_passed(deadline):
                self.state.stopped_by_budget = True
                break
            start = time.perf_counter()
            lr = cosine_lr(self.state.step, self.config)
            step_before = self.state.step
            loss = self.train_epoch(deadline)
            steps = self.state.step - step_before
            if steps < opt.steps_per_epoch:  # cut short by the deadline
                self.state.stopped_by_budget = True
            train_seconds = time.perf_counter() - start
            report = self._validate()
            self.state.epoch += 1
            improved = report.mean < self.state.best_error
            if improved:
                self.state.best_error = report.mean
                self.state.best_epoch = self.state.epoch
                self.state.bad_epochs = 0
            else:
                self.state.bad_epochs += 1
            seconds = time.perf_counter() - start
            self.state.seconds += seconds
            self.state.step_seconds += train_seconds
            record = EpochRecord(
                self.state.epoch,
                self.state.step,
                loss,
                report.mean,
                report.median,
                report.l1,
                lr,
                seconds,
                train_seconds,
                improved,
            )
            self.state.history.append(record.to_dict())
            if opt.patience and self.state.bad_epochs >= opt.patience:
                self.state.stopped_early = True
            if improved and self.is_main:
                self._save_best()
            if self.is_main:
                self.save_checkpoint()
            LOG.info(
                "epoch %d/%d step %d loss %.5f val %.3f (median %.3f, clean %.3f, aug %.3f) "
                "lr %.2e %.1f s (%.1f steps/s)%s%s",
                self.state.epoch,
                opt.epochs,
                self.state.step,
                loss,
                report.mean,
                report.median,
                report.by_kind.get("clean", {}).get("mean", float("nan")),
                report.by_kind.get("augmented", {}).get("mean", float("nan")),
                lr,
                seconds,
                steps / train_seconds,
                " [best]" if improved else "",
                " [early stop]" if self.state.stopped_early else "",
            )
            run += 1
            if self.state.stopped_by_budget:
                LOG.info(
                    "time budget reached: epoch %d stopped after %d of %d steps",
                    self.state.epoch,
                    steps,
                    opt.steps_per_epoch,
                )
                break
        return self.state


def seed_everything(seed: int) -> None:
    """Seed torch's and numpy's global generators (the network initialization uses torch's)."""
    torch.manual_seed(seed)
    np.random.seed(seed % (2**32))  # noqa: NPY002 - only for third-party code using the global


__all__ = [
    "BEST",
    "BUDGET_CHECK_STEPS",
    "LAST",
    "EpochRecord",
    "PairForward",
    "TrainState",
    "Trainer",
    "ValidationReport",
    "check_resumable",
    "cosine_lr",
    "evaluate",
    "pair_outputs",
    "read_checkpoint",
    "seed_everything",
    "training_loss",
    "write_checkpoint",
]
