"""Which geodesic model a shape belongs to: a small PointNet category classifier (issue 14).

The service's ``auto`` model registers an upload under every model and, without a router,
keeps the one of lowest OOD z-score. On real humans that rule errs (BENCHMARKS
"auto-routing-cost": 8 of 20 FAUST meshes and 13 of 20 FAUST 300-point clouds go to
``quadrupeds``, at 2.5× the error). A :class:`CategoryRouter` looks at the shape itself:

* **input** — the shape's canonical samples in the frame the descriptor sees
  (:func:`~litege_core.canonical.canonicalize_bbox` of the predictor's 2,000 surface samples
  of a mesh, or of the cloud), :data:`ROUTER_POINTS` of them drawn with a fixed seed;
* **network** — a per-point MLP (3 → 64 → 128 → 256), max- and mean-pooled, then 512 → 128 →
  ``C`` class logits (:class:`RouterNet`, ~60 K parameters);
* **training** — posed procedural and collection shapes of each category, sparse, noisy and cut
  views, with random axis sign flips, a random order of the two minor axes and small rotations
  of the frame, so that no decision rests on the PCA sign rule
  (:mod:`litege_core.train.router`); never on the dev set;
* **files** — ``router.safetensors`` (float32 weights) and ``router.json`` (categories,
  training summary, weights hash), shipped in ``litege_core/models/router/``.

Categories are the bundles' own (``quadruped``, ``biped``: :attr:`ModelBundle.category`), so a
caller maps them to whichever loaded model has that category. The router decides where it is
confident (probability ≥ ``min_probability``, from its file); elsewhere the caller keeps its
own rule (the service: the lowest z-score).
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
import torch
from numpy.typing import NDArray
from torch import nn

from litege_core.canonical import canonicalize_bbox
from litege_core.errors import ArtifactError, InputError
from litege_core.files import file_sha256, read_json_object, write_json_atomic
from litege_core.learned.bundle import SHIPPED_DIR
from litege_core.learned.describe import shape_samples
from litege_core.nets.state import load_state, state_to_tensors
from litege_core.shape import Shape

ROUTER_POINTS = 512
"""Canonical samples the router reads per shape."""

ROUTER_WEIGHTS = "router.safetensors"
ROUTER_CONFIG = "router.json"
ROUTER_KIND = "litege-category-router"
ROUTER_FORMAT = 1
SHIPPED_ROUTER = SHIPPED_DIR / "router"
DEFAULT_MIN_PROBABILITY = 0.9
"""Confidence from which the router's choice replaces the caller's rule."""


class RouterNet(nn.Module):
    """PointNet classifier: ``(B, P, 3)`` canonical points → ``(B, C)`` logits."""

    def __init__(
        self, n_classes: int, widths: Sequence[int] = (64, 128, 256), hidden: int = 128
    ) -> None:
        super().__init__()
        if n_classes < 2:
            raise InputError(f"a router needs at least 2 categories, got {n_classes}")
        layers: list[nn.Module] = []
        width = 3
        for out in widths:
            layers += [nn.Linear(width, out), nn.ReLU()]
            width = out
        self.widths, self.hidden, self.n_classes = tuple(int(w) for w in widths), hidden, n_classes
        self.point_mlp = nn.Sequential(*layers)
        self.classifier = nn.Sequential(
            nn.Linear(2 * width, hidden), nn.ReLU(), nn.Linear(hidden, n_classes)
        )

    def forward(self, points: torch.Tensor) -> torch.Tensor:
        features = self.point_mlp(points)  # (B, P, W)
        pooled = torch.cat([features.amax(dim=1), features.mean(dim=1)], dim=1)
        return self.classifier(pooled)

    def config(self) -> dict[str, Any]:
        return {"n_classes": self.n_classes, "widths": list(self.widths), "hidden": self.hidden}


def router_points(points: NDArray, n_points: int = ROUTER_POINTS, seed: int = 0) -> NDArray:
    """``(P, 3)`` samples of a shape → ``(n_points, 3)`` float32 router input: the samples in
    their :func:`canonicalize_bbox` frame, ``n_points`` of them drawn without replacement
    (with replacement when there are fewer) by a generator seeded with ``seed``."""
    canonical = canonicalize_bbox(points).apply(points)
    rng = np.random.default_rng(seed)
    count = canonical.shape[0]
    pick = rng.choice(count, n_points, replace=count < n_points)
    return canonical[pick].astype(np.float32)


@dataclass
class CategoryRouter:
    """A trained :class:`RouterNet` with its categories.

    Attributes:
        net: the classifier (eval mode, CPU).
        categories: ``C`` bundle categories (``quadruped``, ``biped``), in logit order.
        min_probability: confidence from which :meth:`route` decides.
        metadata: training summary (JSON).
    """

    net: RouterNet
    categories: tuple[str, ...]
    min_probability: float = DEFAULT_MIN_PROBABILITY
    metadata: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if len(self.categories) != self.net.n_classes:
            raise InputError(
                f"{len(self.categories)} categories for a {self.net.n_classes}-class network"
            )
        if not 0.0 < self.min_probability <= 1.0:
            raise InputError("min_probability must lie in (0, 1]")
        self.net.eval()

    def probabilities(self, shapes: Sequence[Shape], seed: int = 0) -> NDArray:
        """``(B, C)`` float64 category probabilities of ``shapes`` (meshes are sampled as the
        predictor samples them, with ``seed``)."""
        if not shapes:
            return np.zeros((0, len(self.categories)))
        batch = np.stack([router_points(shape_samples(s, seed=seed), seed=seed) for s in shapes])
        with torch.no_grad():
            logits = self.net(torch.from_numpy(batch))
        return torch.softmax(logits.double(), dim=1).numpy()

    def route(
        self, shapes: Sequence[Shape], models: Mapping[str, str], seed: int = 0
    ) -> list[str | None]:
        """The model each shape belongs to, from ``models`` (category → model name), or
        ``None`` where the router is not confident enough or no model has its category."""
        chosen: list[str | None] = []
        for row in self.probabilities(shapes, seed):
            best = int(np.argmax(row))
            confident = row[best] >= self.min_probability
            chosen.append(models.get(self.categories[best]) if confident else None)
        return chosen

    def save(self, directory: str | os.PathLike) -> dict[str, Any]:
        """Write ``router.safetensors`` and ``router.json`` into ``directory``."""
        from safetensors.torch import save_file

        directory = Path(directory)
        directory.mkdir(parents=True, exist_ok=True)
        tensors = {k: v.float().contiguous() for k, v in state_to_tensors(self.net).items()}
        temporary = directory / (ROUTER_WEIGHTS + ".tmp")
        save_file(tensors, str(temporary))
        os.replace(temporary, directory / ROUTER_WEIGHTS)
        (directory / ROUTER_WEIGHTS).chmod(0o644)
        config = {
            "kind": ROUTER_KIND,
            "format_version": ROUTER_FORMAT,
            "network": self.net.config(),
            "categories": list(self.categories),
            "min_probability": self.min_probability,
            "points": ROUTER_POINTS,
            "weights_sha256": file_sha256(directory / ROUTER_WEIGHTS),
            "metadata": self.metadata,
            "created": datetime.now(UTC).isoformat(timespec="seconds"),
        }
        write_json_atomic(directory / ROUTER_CONFIG, config)
        return config

    @classmethod
    def load(cls, directory: str | os.PathLike) -> CategoryRouter:
        """Read a router written by :meth:`save`.

        Raises:
            ArtifactError: missing or damaged files, or a weights hash mismatch.
        """
        from safetensors.torch import load_file

        directory = Path(directory)
        if not (directory / ROUTER_CONFIG).is_file():
            raise ArtifactError(f"no router in {directory} (no {ROUTER_CONFIG})")
        config = read_json_object(directory / ROUTER_CONFIG, "router config")
        weights = directory / ROUTER_WEIGHTS
        try:
            if config.get("kind") != ROUTER_KIND or config.get("format_version") != ROUTER_FORMAT:
                raise ArtifactError(f"{directory} does not hold a format-{ROUTER_FORMAT} router")
            if not weights.is_file() or file_sha256(weights) != config["weights_sha256"]:
                raise ArtifactError(f"router weights in {directory} are missing or changed")
            network = config["network"]
            net = RouterNet(int(network["n_classes"]), network["widths"], int(network["hidden"]))
            load_state(net, load_file(str(weights)))
            return cls(
                net,
                tuple(config["categories"]),
                float(config["min_probability"]),
                dict(config.get("metadata", {})),
            )
        except (KeyError, TypeError, ValueError, InputError) as exc:
            raise ArtifactError(f"router in {directory} is inconsistent: {exc}") from exc


def first_of_each_category(categories: Mapping[str, str]) -> dict[str, str]:
    """``model name → category`` (in loading order) → ``category → the first model of it``:
    the ``models`` argument of :meth:`CategoryRouter.route`."""
    chosen: dict[str, str] = {}
    for name, category in categories.items():
        chosen.setdefault(category, name)
    return chosen


def load_router(directory: str | os.PathLike | None = None) -> CategoryRouter | None:
    """The router in ``directory`` (default: the shipped one; ``None`` if none is shipped)."""
    if directory is None:
        if not (SHIPPED_ROUTER / ROUTER_CONFIG).is_file():
            return None
        directory = SHIPPED_ROUTER
    return CategoryRouter.load(directory)


__all__ = [
    "DEFAULT_MIN_PROBABILITY",
    "ROUTER_CONFIG",
    "ROUTER_POINTS",
    "ROUTER_WEIGHTS",
    "SHIPPED_ROUTER",
    "CategoryRouter",
    "RouterNet",
    "first_of_each_category",
    "load_router",
    "router_points",
]
