"""Train an :class:`~litege_core.nets.orientation.OrientationNet` (issue 15, step 1).

Items are the T-Net's training shapes (``[data]``: procedural animals and posed, optionally
bent, rigged animals in their canonical frames) with the T-Net's corruptions (``[augment]``:
500–2,000 surface samples, broken meshes, noise, per-axis stretch), each shown in a *base
frame* ``B`` (``cloud @ B``) of one of two kinds:

* a jittered cube turn ``B = J Kₜᵀ`` (``J`` a rotation by at most ``jitter`` rad about a random
  axis, ``Kₜ`` a random one of the 24 cube rotations): frames near a turn of the true one, as a
  T-Net frame that is wrong by a half turn;
* with probability ``pca_probability``, the cloud's own principal-axis frame
  (:func:`~litege_core.nets.tnet.pca_frames`), the base of the 24 candidate frames the matching
  pipeline weighs where the T-Net hesitates.

The label is the cube turn ``k`` whose candidate ``B Kₖ`` is nearest the true frame; the loss
is the cross-entropy of the network's 24 logits. Validation (fixed items of the val shapes)
reports the accuracy and the failure rate: the share of items whose chosen candidate is more
than 0.66 rad from the true frame (the frame reports' threshold).

    litege train orientation --config configs/orientation-quadrupeds.toml
"""

from __future__ import annotations

import json
import logging
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
import torch
from numpy.typing import NDArray
from safetensors import SafetensorError, safe_open
from safetensors.torch import save_file

from litege_core.errors import ArtifactError, InputError
from litege_core.nets import load_state, state_to_tensors
from litege_core.nets.orientation import OrientationNet
from litege_core.nets.tnet import CUBE_ROTATIONS, pca_frames
from litege_core.train.config import ConfigRoot, _check, run_log
from litege_core.train.tnet import FAILURE_THRESHOLD, ShapeSet, TNetAugmentConfig, TNetDataConfig
from litege_core.train.tnet.batches import augmented_cloud
from litege_core.train.tnet.shapes import training_shape_sets
from litege_core.variants import small_rotation

LOG = logging.getLogger("litege.train.orientation")

WEIGHTS_FILE = "orientation.safetensors"


@dataclass(frozen=True)
class OrientationNetworkConfig:
    """:class:`~litege_core.nets.orientation.OrientationNet` constructor arguments."""

    grid: int = 16
    extent: float = 2.5
    conv_widths: tuple[int, ...] = (16, 32, 64)
    fc_width: int = 128

    def __post_init__(self) -> None:
        _check(self.grid >= 2 and self.extent > 0.0, "network.grid ≥ 2 and extent > 0")
        _check(all(w >= 1 for w in self.conv_widths) and self.fc_width >= 1, "positive widths")


@dataclass(frozen=True)
class OrientationOptimConfig:
    """Batches, Adam + cosine schedule, base frames, validation, seed.

    Attributes:
        batch_size: clouds per step; steps: optimizer steps (an upper bound with
            ``time_budget_minutes``, which stops the run when spent).
        lr, eta_min: cosine schedule over ``steps``.
        jitter: rad, largest rotation ``J`` of a jittered cube-turn base frame.
        pca_probability: share of items shown in their principal-axis frame.
        val_items: fixed validation items (the val shapes cycled); val_every: steps between
            validations (the best weights by failure rate, then loss, are kept).
        skip_lying: leave out the procedural shapes drawn lying on their side: their true
            frame is the ground's (the body rolled ~83°), while real shapes are framed
            body-upright, so they would teach that a body on its side can be canonical.
    """

    batch_size: int = 64
    steps: int = 4000
    lr: float = 1e-3
    eta_min: float = 1e-5
    jitter: float = 0.6
    pca_probability: float = 0.5
    val_items: int = 480
    val_every: int = 250
    log_every: int = 50
    seed: int = 0
    threads: int = 1
    time_budget_minutes: float = 0.0
    skip_lying: bool = True

    def __post_init__(self) -> None:
        _check(self.batch_size >= 1 and self.steps >= 1, "batch_size and steps ≥ 1")
        _check(0.0 < self.eta_min <= self.lr, "need 0 < eta_min ≤ lr")
        _check(0.0 <= self.jitter < math.pi / 4, "train.jitter must lie in [0, π/4)")
        _check(0.0 <= self.pca_probability <= 1.0, "train.pca_probability must lie in [0, 1]")
        _check(self.val_items >= 1 and self.val_every >= 1, "val_items and val_every ≥ 1")
        _check(self.log_every >= 1 and self.threads >= 0, "log_every ≥ 1, threads ≥ 0")
        _check(self.time_budget_minutes >= 0.0, "train.time_budget_minutes must be ≥ 0")


@dataclass(frozen=True)
class OrientationOutputConfig:
    """``dir`` receives ``orientation.safetensors`` and ``train.log``."""

    dir: str = "out/orientation"

    def __post_init__(self) -> None:
        _check(bool(self.dir), "output.dir is required")


@dataclass(frozen=True)
class OrientationTrainConfig(ConfigRoot):
    """The whole orientation training configuration (TOML tables of the same names)."""

    WHAT: ClassVar[str] = "an orientation training config"

    data: TNetDataConfig = field(default_factory=TNetDataConfig)
    augment: TNetAugmentConfig = field(default_factory=TNetAugmentConfig)
    network: OrientationNetworkConfig = field(default_factory=OrientationNetworkConfig)
    train: OrientationOptimConfig = field(default_factory=OrientationOptimConfig)
    output: OrientationOutputConfig = field(default_factory=OrientationOutputConfig)


def without_lying(shapes: ShapeSet, category: str, steep_share: float = 0.0) -> ShapeSet:
    """``shapes`` less the procedural ``category`` shapes posed ``lying``: their drawn pose,
    unless ``steep_share`` posed them steep (:func:`~litege_core.synth.poses.steep_pose`)."""
    from litege_core.synth import families
    from litege_core.synth.generate import drawn_pose_mode
    from litege_core.synth.poses import steep_pose

    procedural = set(families(category))
    keep = [
        i
        for i, (family, seed) in enumerate(shapes.keys)
        if family not in procedural
        or (steep_pose(category, seed, steep_share) or drawn_pose_mode(category, family, seed))
        != "lying"
    ]
    return ShapeSet(
        [shapes.vertices[i] for i in keep],
        [shapes.faces[i] for i in keep],
        [shapes.keys[i] for i in keep],
    )


def nearest_turns(bases: NDArray) -> NDArray:
    """For base frames ``(B, 3, 3)``, the index ``(B,)`` of the cube turn ``K`` whose candidate
    ``base @ K`` is nearest the identity (largest ``tr(base K)``)."""
    cube = CUBE_ROTATIONS.numpy()
    return np.argmax(np.einsum("bij,kji->bk", bases, cube), axis=1)


def candidate_angles(bases: NDArray, turns: NDArray) -> NDArray:
    """Angle (rad) ``(B,)`` between each candidate ``bases[b] @ K[turns[b]]`` and the identity."""
    chosen = bases @ CUBE_ROTATIONS.numpy()[turns]
    cosine = (np.trace(chosen, axis1=1, axis2=2) - 1.0) / 2.0
    return np.arccos(np.clip(cosine, -1.0, 1.0))


def sample_items(
    shapes: ShapeSet,
    count: int,
    config: OrientationTrainConfig,
    rng: np.random.Generator,
) -> tuple[torch.Tensor, NDArray]:
    """``count`` training items: clouds in their base frames ``(count, N, 3)`` float32 (one
    random ``N`` for all) and the base frames ``(count, 3, 3)`` float64."""
    augment, opt = config.augment, config.train
    n_points = int(rng.integers(augment.min_points, augment.max_points + 1))
    clouds = np.empty((count, n_points, 3))
    bases = np.empty((count, 3, 3))
    cube = CUBE_ROTATIONS.numpy()
    for i in range(count):
        k = int(rng.integers(len(shapes.vertices)))
        cloud = augmented_cloud(shapes.vertices[k], shapes.faces[k], n_points, augment, rng)
        if rng.random() < opt.pca_probability:
            base = pca_frames(torch.from_numpy(cloud)[None])[0].numpy()
        else:
            base = small_rotation(opt.jitter, rng) @ cube[int(rng.integers(len(cube)))].T
        clouds[i], bases[i] = cloud @ base, base
    return torch.from_numpy(clouds).float(), bases


@dataclass
class OrientationRunResult:
    """What :func:`train_orientation` returns: the best network (eval mode) and its history."""

    net: OrientationNet
    best: dict[str, float]
    best_step: int
    steps: int
    seconds: float
    history: list[dict[str, Any]]


@torch.no_grad()
def evaluate(net: OrientationNet, clouds: torch.Tensor, bases: NDArray) -> dict[str, float]:
    """Loss, accuracy and failure rate (chosen candidate > 0.66 rad off) of fixed items."""
    net.eval()
    labels = torch.from_numpy(nearest_turns(bases))
    logits = torch.cat([net(chunk) for chunk in clouds.split(128)])
    chosen = logits.argmax(dim=1).numpy()
    return {
        "loss": float(torch.nn.functional.cross_entropy(logits, labels)),
        "accuracy": float((chosen == labels.numpy()).mean()),
        "failures": float((candidate_angles(bases, chosen) > FAILURE_THRESHOLD).mean()),
    }


def train_orientation(
    config: OrientationTrainConfig,
    *,
    train_shapes: ShapeSet | None = None,
    val_shapes: ShapeSet | None = None,
    weights_path: str | Path | None = None,
) -> OrientationRunResult:
    """Train per ``config`` (shapes generated per ``[data]`` unless given); the best weights
    (fewest validation failures, then lowest loss) are written to ``weights_path`` at each
    improvement and returned in the network."""
    opt = config.train
    if opt.threads > 0:
        torch.set_num_threads(opt.threads)
    if train_shapes is None or val_shapes is None:
        train_shapes, val_shapes = training_shape_sets(config.data)
    if opt.skip_lying:
        data = config.data
        train_shapes = without_lying(train_shapes, data.category, data.steep_share)
        val_shapes = without_lying(val_shapes, data.category, data.steep_share)
    val_clouds, val_bases = sample_items(
        val_shapes, opt.val_items, config, np.random.default_rng([opt.seed, 1])
    )
    torch.manual_seed(opt.seed)
    network = config.network
    net = OrientationNet(network.grid, network.extent, network.conv_widths, network.fc_width)
    optimizer = torch.optim.Adam(net.parameters(), lr=opt.lr)
    rng = np.random.default_rng([opt.seed, 0])
    LOG.info(
        "OrientationNet %s (%d parameters), %d train / %d val shapes, %d steps × %d clouds",
        net.config(), sum(p.numel() for p in net.parameters()), len(train_shapes.vertices),
        len(val_shapes.vertices), opt.steps, opt.batch_size,
    )  # fmt: skip
    best: dict[str, float] = {"failures": math.inf, "loss": math.inf}
    best_state, best_step, history = state_to_tensors(net), 0, []
    started, losses, step = time.perf_counter(), [], 0
    while step < opt.steps:
        lr = opt.eta_min + 0.5 * (opt.lr - opt.eta_min) * (1 + math.cos(math.pi * step / opt.steps))
        for group in optimizer.param_groups:
            group["lr"] = lr
        clouds, bases = sample_items(train_shapes, opt.batch_size, config, rng)
        net.train()
        loss = torch.nn.functional.cross_entropy(
            net(clouds), torch.from_numpy(nearest_turns(bases))
        )
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        optimizer.step()
        losses.append(float(loss.detach()))
        step += 1
        elapsed = time.perf_counter() - started
        last = step == opt.steps or (
            opt.time_budget_minutes > 0 and elapsed > opt.time_budget_minutes * 60.0
        )
        if step % opt.log_every == 0:
            LOG.info("step %d lr %.2e loss %.4f (%.2f steps/s)", step, lr,
                     float(np.mean(losses)), step / elapsed)  # fmt: skip
            losses = []
        if step % opt.val_every == 0 or last:
            scores = evaluate(net, val_clouds, val_bases)
            improved = (scores["failures"], scores["loss"]) < (best["failures"], best["loss"])
            history.append({"step": step, "val": scores, "improved": improved})
            if improved:
                best, best_step, best_state = scores, step, state_to_tensors(net)
                if weights_path is not None:
                    save_orientation(net, weights_path)
            LOG.info("val step %d: loss %.4f accuracy %.3f failures %.3f%s", step,
                     scores["loss"], scores["accuracy"], scores["failures"],
                     " *best*" if improved else "")  # fmt: skip
        if last:
            break
    load_state(net, best_state)
    net.eval()
    return OrientationRunResult(net, best, best_step, step, time.perf_counter() - started, history)


def save_orientation(net: OrientationNet, path: str | Path) -> None:
    """Write the network's weights (safetensors, its config in the metadata)."""
    save_file(state_to_tensors(net), str(path), metadata={"config": json.dumps(net.config())})


def load_orientation(path: str | Path) -> OrientationNet:
    """Read a network written by :func:`save_orientation` (eval mode, CPU).

    Raises:
        ArtifactError: a missing or unreadable file, or one that is not such a network.
    """
    try:
        with safe_open(str(path), framework="pt") as handle:
            config = json.loads((handle.metadata() or {})["config"])
            tensors = {key: handle.get_tensor(key) for key in handle.keys()}  # noqa: SIM118
        net = OrientationNet.from_config(config)
    except (SafetensorError, OSError, KeyError, ValueError, InputError) as exc:
        raise ArtifactError(f"{path} is not an orientation network: {exc}") from exc
    load_state(net, tensors)
    return net.eval()


def run_orientation_training(config: OrientationTrainConfig, out: str | Path | None = None) -> dict:
    """A whole run into ``output.dir`` (or ``out``): ``orientation.safetensors`` and
    ``train.log``; returns a summary."""
    if out is not None:
        config = config.replace(output={"dir": str(out)})
    run_dir = config.run_dir
    run_dir.mkdir(parents=True, exist_ok=True)
    with run_log(LOG, run_dir):
        result = train_orientation(config, weights_path=run_dir / WEIGHTS_FILE)
    return {
        "best_step": result.best_step,
        "best_val": result.best,
        "steps": result.steps,
        "seconds": round(result.seconds, 1),
        "weights": str(run_dir / WEIGHTS_FILE),
    }


__all__ = [
    "WEIGHTS_FILE",
    "OrientationNetworkConfig",
    "OrientationOptimConfig",
    "OrientationOutputConfig",
    "OrientationRunResult",
    "OrientationTrainConfig",
    "candidate_angles",
    "evaluate",
    "load_orientation",
    "nearest_turns",
    "run_orientation_training",
    "sample_items",
    "save_orientation",
    "train_orientation",
    "without_lying",
]
