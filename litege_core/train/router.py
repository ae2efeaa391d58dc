"""Train the category router of :mod:`litege_core.learned.router` (issue 14, ``auto`` routing).

**Data.** Labelled meshes, one category each (the caller gathers them: posed procedural shapes
of each category and posed collection shapes, :func:`litege_core.train.tnet.generate_shape_set`
and :func:`~litege_core.train.tnet.collection_shape_set`). Each step draws
:attr:`RouterTrainConfig.batch_size` meshes, the categories balanced, and for each a view a user
could send: ``n`` area-weighted samples (``n`` log-uniform in ``[min_points, max_points]``),
with probability ``noise_probability`` Gaussian noise of σ ~ U(0, ``noise_sigma``) (unit-area
units), with probability ``cut_probability`` everything beyond a random plane removed
(``cut_min``–``cut_max`` of the points). The view is put in its
:func:`~litege_core.canonical.canonicalize_bbox` frame (the router's input,
:func:`~litege_core.learned.router.router_points`), then the frame is perturbed: every axis
sign flipped with probability ½, the two minor axes swapped with probability ½, and a rotation
of up to ``max_turn_degrees`` about a random axis, so that no decision rests on the PCA sign
rule or axis order, which real shapes break.

**Loss and schedule.** Cross-entropy, Adam, cosine decay over ``steps`` (or ``minutes``,
whichever ends first). Every ``val_every`` steps the accuracy on a fixed validation set (views
of the validation meshes, drawn once) is logged; the best checkpoint is kept.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import torch
from numpy.typing import NDArray

from litege_core.errors import InputError
from litege_core.learned.router import RouterNet, router_points
from litege_core.sampling import sample_surface
from litege_core.validate import triangle_areas
from litege_core.variants import small_rotation

Mesh = tuple[NDArray, NDArray]


@dataclass(frozen=True)
class RouterTrainConfig:
    """Settings of one router training run (see the module docstring)."""

    steps: int = 6000
    minutes: float = 12.0
    batch_size: int = 32
    lr: float = 1e-3
    final_lr_fraction: float = 0.05
    min_points: int = 300
    max_points: int = 5000
    noise_probability: float = 0.3
    noise_sigma: float = 0.01
    cut_probability: float = 0.2
    cut_min: float = 0.05
    cut_max: float = 0.15
    max_turn_degrees: float = 20.0
    val_views: int = 3
    val_every: int = 250
    seed: int = 0

    def __post_init__(self) -> None:
        for name in ("steps", "batch_size", "min_points", "val_views", "val_every"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise InputError(f"{name} must be a positive integer, got {value!r}")
        if not 4 <= self.min_points <= self.max_points:
            raise InputError("need 4 ≤ min_points ≤ max_points")
        if not (self.minutes > 0 and self.lr > 0):
            raise InputError("minutes and lr must be positive")
        for name in ("noise_probability", "cut_probability", "final_lr_fraction"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise InputError(f"{name} must lie in [0, 1]")
        if not 0.0 <= self.cut_min <= self.cut_max < 1.0:
            raise InputError("need 0 ≤ cut_min ≤ cut_max < 1")


@dataclass
class RouterTrainResult:
    """The best network and the run's summary."""

    net: RouterNet
    steps: int
    seconds: float
    best_val_accuracy: float
    best_step: int
    history: list[tuple[int, float, float]]  # (step, train loss, val accuracy)


def view_points(mesh: Mesh, config: RouterTrainConfig, rng: np.random.Generator) -> NDArray:
    """One augmented view of a mesh, as ``(P, 3)`` points (module docstring)."""
    vertices, faces = mesh
    low, high = math.log(config.min_points), math.log(config.max_points)
    count = round(math.exp(rng.uniform(low, high)))
    points = sample_surface(vertices, faces, count, rng).points
    area = float(triangle_areas(vertices, faces).sum())
    if rng.random() < config.noise_probability:
        sigma = rng.uniform(0.0, config.noise_sigma) * math.sqrt(area)
        points = points + rng.normal(size=points.shape) * sigma
    if rng.random() < config.cut_probability:
        direction = rng.normal(size=3)
        heights = points @ (direction / np.linalg.norm(direction))
        fraction = rng.uniform(config.cut_min, config.cut_max)
        keep = heights <= np.quantile(heights, 1.0 - fraction)
        if keep.sum() >= config.min_points:
            points = points[keep]
    return points


def perturbed_frame(
    points: NDArray, config: RouterTrainConfig, rng: np.random.Generator
) -> NDArray:
    """Router input of a view with its canonical frame perturbed: ``(ROUTER_POINTS, 3)``
    float32 (:data:`~litege_core.learned.router.ROUTER_POINTS`)."""
    canonical = router_points(points, seed=int(rng.integers(2**31)))
    flips = np.where(rng.random(3) < 0.5, -1.0, 1.0)
    order = [0, 2, 1] if rng.random() < 0.5 else [0, 1, 2]
    turn = small_rotation(math.radians(config.max_turn_degrees), rng)
    return ((canonical[:, order] * flips) @ turn.T).astype(np.float32)


def _batch(
    meshes: Sequence[Mesh],
    by_label: Sequence[NDArray],
    config: RouterTrainConfig,
    rng: np.random.Generator,
) -> tuple[torch.Tensor, torch.Tensor]:
    labels = rng.integers(0, len(by_label), config.batch_size)  # balanced categories
    picks = [int(rng.choice(by_label[label])) for label in labels]
    points = np.stack(
        [perturbed_frame(view_points(meshes[i], config, rng), config, rng) for i in picks]
    )
    return torch.from_numpy(points), torch.from_numpy(labels)


def train_router(
    train: Sequence[tuple[Mesh, int]],
    val: Sequence[tuple[Mesh, int]],
    n_classes: int,
    config: RouterTrainConfig = RouterTrainConfig(),
    log: Callable[[str], None] | None = None,
) -> RouterTrainResult:
    """Train a :class:`RouterNet` on ``(mesh, label)`` pairs (module docstring).

    Args:
        train: training meshes with their label in ``[0, n_classes)``; every label present.
        val: validation meshes (their views are drawn once, with the config's seed).
        n_classes: number of categories.
    """
    say = log or (lambda line: None)
    labels = np.array([label for _, label in train])
    if set(labels.tolist()) != set(range(n_classes)):
        raise InputError(f"training labels must cover 0..{n_classes - 1}")
    meshes = [mesh for mesh, _ in train]
    by_label = [np.flatnonzero(labels == c) for c in range(n_classes)]
    rng = np.random.default_rng(config.seed)
    torch.manual_seed(config.seed)
    val_rng = np.random.default_rng([config.seed, 1])
    val_x = torch.from_numpy(
        np.stack(
            [
                perturbed_frame(view_points(mesh, config, val_rng), config, val_rng)
                for mesh, _ in val
                for _ in range(config.val_views)
            ]
        )
    )
    val_y = torch.tensor([label for _, label in val for _ in range(config.val_views)])
    net = RouterNet(n_classes)
    optimizer = torch.optim.Adam(net.parameters(), lr=config.lr)
    start, budget = time.monotonic(), 60.0 * config.minutes
    best_state, best_accuracy, best_step = None, -1.0, 0
    history: list[tuple[int, float, float]] = []
    running, step = 0.0, 0
    while step < config.steps and time.monotonic() - start < budget:
        progress = max(step / config.steps, (time.monotonic() - start) / budget)
        f = config.final_lr_fraction
        for group in optimizer.param_groups:
            group["lr"] = config.lr * (f + (1 - f) * 0.5 * (1 + math.cos(math.pi * progress)))
        x, y = _batch(meshes, by_label, config, rng)
        net.train()
        loss = torch.nn.functional.cross_entropy(net(x), y)
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        optimizer.step()
        running += float(loss.detach())
        step += 1
        if step % config.val_every == 0:
            net.eval()
            with torch.no_grad():
                accuracy = float((net(val_x).argmax(dim=1) == val_y).double().mean())
            history.append((step, running / config.val_every, accuracy))
            say(
                f"step {step} {time.monotonic() - start:.0f} s loss "
                f"{running / config.val_every:.4f} val accuracy {accuracy:.4f}"
            )
            running = 0.0
            if accuracy > best_accuracy:
                best_state = {k: v.clone() for k, v in net.state_dict().items()}
                best_accuracy, best_step = accuracy, step
    if best_state is not None:
        net.load_state_dict(best_state)
    net.eval()
    return RouterTrainResult(net, step, time.monotonic() - start, best_accuracy, best_step, history)


__all__ = [
    "RouterTrainConfig",
    "RouterTrainResult",
    "perturbed_frame",
    "train_router",
    "view_points",
]
