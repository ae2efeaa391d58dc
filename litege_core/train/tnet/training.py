"""The T-Net training loop: cosine learning rate, steps, time budgets, the best weights by
validation and the run's report."""

from __future__ import annotations

import json
import logging
import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from litege_core.nets import TNet, load_state, state_to_tensors, tnet_loss
from litege_core.nets.tnet import pca_frames
from litege_core.train.config import run_log
from litege_core.train.tnet.batches import BatchLoader, TNetBatch, ValidationSet, validation_set
from litege_core.train.tnet.config import TNetOptimConfig, TNetTrainConfig
from litege_core.train.tnet.evaluation import alignment_report, device_of, validate
from litege_core.train.tnet.shapes import ShapeSet, training_shape_sets
from litege_core.train.tnet.weights import save_tnet, start_from

LOG = logging.getLogger("litege.train.tnet")

PLAN_AFTER_STEPS = 100
"""With ``train.time_budget_minutes``, the steps timed before the run is re-planned."""


def cosine_lr(step: int, config: TNetOptimConfig, total: int | None = None) -> float:
    """``η_min + (η_0 − η_min)(1 + cos(π·step/total))/2`` (``total``: ``steps`` by default)."""
    fraction = min(max(step / (total or config.steps), 0.0), 1.0)
    return config.eta_min + (config.lr - config.eta_min) * 0.5 * (1 + math.cos(math.pi * fraction))


def train_step(
    net: TNet, optimizer: torch.optim.Optimizer, batch: TNetBatch, point_weight: float
) -> dict[str, float]:
    """One Adam step on ``batch`` (network in training mode); the loss terms as floats."""
    device = device_of(net)
    canonical, rotated, R_gt = (t.to(device) for t in batch[:3])
    frames = None
    if batch.frame_turns is not None and net.prealign != "none":
        frames = pca_frames(rotated) @ batch.frame_turns.to(device, rotated.dtype)
    loss = tnet_loss(net.rotation(rotated, frames), R_gt, canonical, rotated, point_weight)
    optimizer.zero_grad(set_to_none=True)
    loss.total.backward()
    optimizer.step()
    return {
        name: float(value.detach())
        for name, value in zip(("loss", "angle", "point"), loss, strict=True)
    }


@dataclass
class TNetRunResult:
    """A finished run: the best network (eval mode) and what was measured."""

    net: TNet
    best_val: dict[str, float]
    best_step: int
    history: list[dict[str, Any]]
    seconds: float
    steps_per_second: float
    steps: int = 0
    """Optimizer steps run (``train.steps``, or the count a time budget planned)."""
    report: dict[str, Any] | None = None


def _resolve_device(name: str) -> torch.device:
    from litege_core.device import resolve_device

    return resolve_device(name)


def train_tnet(
    config: TNetTrainConfig,
    *,
    train_shapes: ShapeSet | None = None,
    val_shapes: ShapeSet | None = None,
    weights_path: str | Path | None = None,
    make_report: bool = True,
) -> TNetRunResult:
    """Train per ``config``; shapes are generated when not given (tests pass small ones).

    The best weights by validation mean angle are written to ``weights_path`` (when given)
    each time they improve; the returned network holds them, in eval mode.
    """
    opt = config.train
    if opt.threads > 0:
        torch.set_num_threads(opt.threads)
    device = _resolve_device(opt.device)
    started = time.perf_counter()
    if train_shapes is None or val_shapes is None:
        generated_train, generated_val = training_shape_sets(config.data)
        train_shapes = generated_train if train_shapes is None else train_shapes
        val_shapes = generated_val if val_shapes is None else val_shapes
    val = validation_set(val_shapes, config)
    with BatchLoader(train_shapes, config, opt.loader_workers) as loader:
        result = _optimize(config, loader, val, device, weights_path)
    result.seconds = time.perf_counter() - started
    if make_report:
        mark = time.perf_counter()
        result.report = alignment_report(result.net, train_shapes, val_shapes, config.report)
        LOG.info("alignment report in %.1f s", time.perf_counter() - mark)
    return result


def _planned_steps(config: TNetOptimConfig, done: int, elapsed: float) -> int:
    """The step count that fits ``time_budget_minutes`` at the rate of the first ``done`` steps
    (``elapsed`` wall seconds, validation included), at least ``done`` and at most ``steps``."""
    budget = config.time_budget_minutes * 60.0
    fitting = done + int((budget - elapsed) * done / max(elapsed, 1e-9))
    return min(config.steps, max(done, fitting))


def _optimize(
    config: TNetTrainConfig,
    loader: BatchLoader,
    val: ValidationSet,
    device: torch.device,
    weights_path: str | Path | None,
) -> TNetRunResult:
    """The optimization loop of :func:`train_tnet`; the network comes back with the best
    validation weights, in eval mode (also written to ``weights_path`` at each improvement).
    ``seconds`` of the result counts the optimizer steps only."""
    opt = config.train
    torch.manual_seed(opt.seed)
    network = config.network
    net = TNet(network.conv_widths, network.fc_widths, network.prealign)
    if opt.init:
        start_from(net, opt.init)
    net = net.to(device)
    optimizer = torch.optim.Adam(net.parameters(), lr=opt.lr)
    n_params = sum(p.numel() for p in net.parameters())
    LOG.info(
        "T-Net %s (%d parameters) on %s, %d steps × %d clouds of %d..%d points, %d loader "
        "processes%s",
        net.config(), n_params, device, opt.steps, opt.batch_size, config.augment.min_points,
        config.augment.max_points, opt.loader_workers,
        f", budget {opt.time_budget_minutes:g} min" if opt.time_budget_minutes else "",
    )  # fmt: skip

    best_val: dict[str, float] = {"mean": math.inf}
    best_state: dict[str, torch.Tensor] = state_to_tensors(net)
    best_step = 0
    history: list[dict[str, Any]] = []
    window: list[dict[str, float]] = []
    train_seconds = 0.0
    total = opt.steps
    started = time.perf_counter()
    step = 0
    while step < total:
        tick = time.perf_counter()
        for group in optimizer.param_groups:
            group["lr"] = cosine_lr(step, opt, total)
        net.train()
        batch = loader.batch(step)
        window.append(train_step(net, optimizer, batch, opt.point_weight))
        train_seconds += time.perf_counter() - tick
        step = done = step + 1
        if opt.time_budget_minutes > 0:
            elapsed = time.perf_counter() - started
            if done == min(PLAN_AFTER_STEPS, total):
                total = _planned_steps(opt, done, elapsed)
                LOG.info("time budget %g min: %d steps planned", opt.time_budget_minutes, total)
            elif elapsed > opt.time_budget_minutes * 60.0:
                LOG.info("time budget spent at step %d of %d planned", done, total)
                total = done
        if done % opt.log_every == 0 or done == total:
            means = {k: float(np.mean([w[k] for w in window])) for k in window[0]}
            LOG.info(
                "step %d/%d lr %.2e loss %.4f angle %.4f point %.4f (N=%d, %.2f steps/s)",
                done, total, optimizer.param_groups[0]["lr"], means["loss"], means["angle"],
                means["point"], batch.canonical.shape[1], done / train_seconds,
            )  # fmt: skip
            window = []
        if done % opt.val_every == 0 or done == total:
            scores = validate(net, val)
            improved = scores["mean"] < best_val["mean"]
            history.append({"step": done, "val": scores, "improved": improved})
            if improved:
                best_val, best_step = scores, done
                best_state = state_to_tensors(net)
                if weights_path is not None:
                    save_tnet(net, weights_path, _training_summary(config, best_step, best_val))
            LOG.info(
                "val step %d: mean %.4f (mesh %.4f, cloud500 %.4f, broken %.4f)%s",
                done, scores["mean"], scores["mesh"], scores["cloud500"], scores["broken"],
                " *best*" if improved else "",
            )  # fmt: skip
    load_state(net, best_state)
    net.eval()
    return TNetRunResult(
        net=net,
        best_val=best_val,
        best_step=best_step,
        history=history,
        seconds=train_seconds,
        steps_per_second=total / train_seconds if train_seconds > 0 else 0.0,
        steps=total,
    )


def _training_summary(config: TNetTrainConfig, best_step: int, best_val: dict) -> dict[str, Any]:
    return {
        "best_step": best_step,
        "best_val": best_val,
        "config": config.to_dict(),
        "config_hash": config.content_hash(),
    }


def run_tnet_training(
    config: TNetTrainConfig,
    out: str | Path | None = None,
    *,
    train_shapes: ShapeSet | None = None,
    val_shapes: ShapeSet | None = None,
) -> dict[str, Any]:
    """A whole run into ``RUN`` (``out`` or ``output.dir``): ``tnet.safetensors``,
    ``report.json``, ``train.log``. Returns the report. Shapes are generated per ``[data]``
    unless given."""
    if out is not None:
        config = config.replace(output={"dir": str(out)})
    run_dir = config.run_dir
    run_dir.mkdir(parents=True, exist_ok=True)
    with run_log(LOG, run_dir):
        LOG.info("config %s", json.dumps(config.to_dict(), sort_keys=True))
        weights = run_dir / "tnet.safetensors"
        result = train_tnet(
            config, train_shapes=train_shapes, val_shapes=val_shapes, weights_path=weights
        )
        summary = _training_summary(config, result.best_step, result.best_val)
        summary.update(
            seconds=round(result.seconds, 1),
            steps_per_second=round(result.steps_per_second, 3),
            steps_run=result.steps,
            threads=torch.get_num_threads(),
        )
        save_tnet(result.net, weights, summary)
        report = {
            "weights": str(weights),
            "network": result.net.config(),
            "training": summary,
            "history": result.history,
            "alignment": result.report,
        }
        (run_dir / "report.json").write_text(json.dumps(report, indent=2) + "\n")
        alignment = result.report or {}
        for name in ("train", "val", "val_cloud500", "val_broken"):
            stats = alignment.get(name, {})
            LOG.info(
                "%s: mean %.4f std %.4f median %.4f max %.4f failures>%.2f %d/%d",
                name, stats["mean"], stats["std"], stats["median"], stats["max"],
                stats["threshold"], stats["n_failures"], stats["n"],
            )  # fmt: skip
        return report


__all__ = [
    "PLAN_AFTER_STEPS",
    "TNetRunResult",
    "cosine_lr",
    "run_tnet_training",
    "train_step",
    "train_tnet",
]
