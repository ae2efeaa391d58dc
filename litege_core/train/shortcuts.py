"""Training of the cloud graph's shortcut scorer (:mod:`litege_core.learned.shortcuts`) on the
kept edges of clouds whose true geodesics are known
(:func:`~litege_core.evaluation.cloud_edges.kept_edges`: procedural animals in contact poses,
never the dev set): ``scripts/train_shortcut_scorer.py``."""

from __future__ import annotations

import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import torch

from litege_core.learned.shortcuts import (
    N_EDGE_INPUTS,
    N_NEIGHBOUR_INPUTS,
    NEIGHBOURS,
    ScorerWeights,
    edge_inputs,
    neighbour_inputs,
)

if TYPE_CHECKING:
    from litege_core.evaluation.cloud_edges import KeptEdges


class ShortcutScorer(torch.nn.Module):
    """The trainable scorer: the layers of :class:`~litege_core.learned.shortcuts.ScorerWeights`
    (its ``state_dict`` is what :func:`~litege_core.learned.shortcuts.save_shortcut_scorer`
    stores), batched in torch for training."""

    def __init__(self, width: int = 32, neighbours: int = NEIGHBOURS) -> None:
        super().__init__()
        if width < 1 or neighbours < 1:
            raise ValueError(f"scorer width and neighbours must be >= 1, got {width}, {neighbours}")
        self.width, self.neighbours = int(width), int(neighbours)
        self.point = torch.nn.Sequential(
            torch.nn.Linear(N_NEIGHBOUR_INPUTS, width),
            torch.nn.ReLU(),
            torch.nn.Linear(width, 2 * width),
            torch.nn.ReLU(),
        )
        self.ends = torch.nn.Linear(2 * width, 2 * width, bias=False)
        self.edge = torch.nn.Linear(N_EDGE_INPUTS, 2 * width)
        self.head = torch.nn.Sequential(
            torch.nn.ReLU(), torch.nn.Linear(2 * width, width), torch.nn.ReLU(),
            torch.nn.Linear(width, 1),
        )  # fmt: skip

    def embed(self, inputs: torch.Tensor) -> torch.Tensor:
        """``(R, K, 3)`` neighbour inputs → ``(R, 3, 2w)``, as
        :meth:`~litege_core.learned.shortcuts.ScorerWeights.embed`."""
        flipped = inputs * torch.tensor([1.0, -1.0, 1.0], dtype=inputs.dtype)
        sides = self.ends(self.point(torch.stack([inputs, flipped], dim=1)).amax(dim=2))
        return torch.cat([sides, sides.mean(dim=1, keepdim=True)], dim=1)

    def logits(
        self,
        embedded: torch.Tensor,
        i: torch.Tensor,
        j: torch.Tensor,
        side_i: torch.Tensor,
        side_j: torch.Tensor,
        features: torch.Tensor,
    ) -> torch.Tensor:
        """``(E,)`` logits, as :meth:`~litege_core.learned.shortcuts.ScorerWeights.logits`."""
        hidden = embedded[i, side_i] + embedded[j, side_j] + self.edge(features)
        return self.head(hidden).squeeze(-1)

    def weights(self) -> ScorerWeights:
        """The numpy weights the library scores with."""
        state = {key: value.detach().cpu().numpy() for key, value in self.state_dict().items()}
        return ScorerWeights.from_state(state, self.neighbours)


@dataclass
class ScorerExamples:
    """Training edges of many clouds, their points stacked.

    Attributes:
        inputs: ``(P, K, 3)`` every cloud's :func:`neighbour_inputs`, stacked.
        i, j: ``(E,)`` the edges' ends (rows of ``inputs``).
        side_i, side_j, features: the edges' :func:`edge_inputs`.
        labels: ``(E,)`` 1.0 for a shortcut.
        negatives: the share of each cloud's other edges drawn (the loss weighs the
            shortcuts as in the full edge set).
    """

    inputs: torch.Tensor
    i: torch.Tensor
    j: torch.Tensor
    side_i: torch.Tensor
    side_j: torch.Tensor
    features: torch.Tensor
    labels: torch.Tensor
    negatives: float


def scorer_examples(
    clouds: Sequence[KeptEdges],
    negatives: float = 0.15,
    neighbours: int = NEIGHBOURS,
    seed: int = 0,
) -> ScorerExamples:
    """Every shortcut of each cloud and a ``negatives`` share of its other kept edges (drawn
    with ``seed``)."""
    rng = np.random.default_rng(seed)
    parts: dict[str, list[np.ndarray]] = {
        k: [] for k in ("inputs", "i", "j", "side_i", "side_j", "features", "labels")
    }
    offset = 0
    for cloud in clouds:
        positive, negative = np.flatnonzero(cloud.shortcut), np.flatnonzero(~cloud.shortcut)
        drawn = rng.choice(negative, size=round(negatives * negative.size), replace=False)
        which = np.concatenate([positive, drawn])
        i, j = cloud.i[which].astype(np.int64), cloud.j[which].astype(np.int64)
        n = cloud.points.shape[0]
        parts["inputs"].append(
            neighbour_inputs(
                cloud.points, cloud.nearest[:, :neighbours], cloud.normals, cloud.spacing,
                np.arange(n),
            )
        )  # fmt: skip
        side_i, side_j, features = edge_inputs(
            cloud.points, cloud.normals, cloud.thickness, cloud.spacing, i, j
        )
        for key, value in (
            ("i", i + offset), ("j", j + offset), ("side_i", side_i), ("side_j", side_j),
            ("features", features), ("labels", cloud.shortcut[which].astype(np.float32)),
        ):  # fmt: skip
            parts[key].append(value)
        offset += n
    stacked = {key: torch.from_numpy(np.concatenate(value)) for key, value in parts.items()}
    return ScorerExamples(**stacked, negatives=negatives)


def fit_edge_scorer(
    make_model: Callable[[], torch.nn.Module],
    logits_of: Callable[[torch.nn.Module, torch.Tensor, torch.Generator], torch.Tensor],
    labels: torch.Tensor,
    negatives: float,
    steps: int,
    batch: int = 512,
    learning_rate: float = 2e-3,
    seed: int = 0,
    log_every: int = 1000,
) -> torch.nn.Module:
    """The training loop of a binary edge scorer: BCE with the positives weighted as in the
    full edge set (a share ``negatives`` of the negatives was kept), Adam with a cosine
    schedule, ``steps`` batches of ``batch`` items drawn with replacement, seeded.

    Args:
        make_model: builds the model, after the global seed is set (its initial weights).
        logits_of: ``(model, drawn (batch,) int64 items, generator) → (batch,)`` logits; the
            generator is the loop's own (the draws), for any augmentation.
        labels: ``(E,)`` float32, 1 for a positive.
    """
    torch.manual_seed(seed)
    generator = torch.Generator().manual_seed(seed)
    share = float(labels.mean())
    weight = torch.tensor((1.0 - share) / max(share, 1e-9) * negatives)
    loss_of = torch.nn.BCEWithLogitsLoss(pos_weight=weight)
    model = make_model()
    optimiser = torch.optim.Adam(model.parameters(), lr=learning_rate)
    schedule = torch.optim.lr_scheduler.CosineAnnealingLR(optimiser, max(steps, 1))
    started = time.perf_counter()
    for step in range(steps):
        drawn = torch.randint(0, labels.shape[0], (batch,), generator=generator)
        loss = loss_of(logits_of(model, drawn, generator), labels[drawn])
        optimiser.zero_grad()
        loss.backward()
        optimiser.step()
        schedule.step()
        if log_every and step % log_every == 0:
            elapsed = time.perf_counter() - started
            print(f"step {step}: loss {loss.item():.4f}, {elapsed:.0f} s", file=sys.stderr)
    return model.eval()


def train_shortcut_scorer(
    examples: ScorerExamples,
    steps: int,
    width: int = 32,
    batch: int = 512,
    learning_rate: float = 2e-3,
    seed: int = 0,
    log_every: int = 1000,
) -> ShortcutScorer:
    """Fit a :class:`ShortcutScorer` with :func:`fit_edge_scorer`; each batch of edges
    embeds only its ends."""
    if not bool(examples.labels.any()):
        raise ValueError("the training clouds have no shortcuts: nothing to learn")

    def logits_of(scorer: torch.nn.Module, drawn: torch.Tensor, _: torch.Generator):
        assert isinstance(scorer, ShortcutScorer)
        ends, inverse = torch.unique(
            torch.cat([examples.i[drawn], examples.j[drawn]]), return_inverse=True
        )
        return scorer.logits(
            scorer.embed(examples.inputs[ends]),
            inverse[: drawn.shape[0]],
            inverse[drawn.shape[0] :],
            examples.side_i[drawn],
            examples.side_j[drawn],
            examples.features[drawn],
        )

    trained = fit_edge_scorer(
        lambda: ShortcutScorer(width, examples.inputs.shape[1]),
        logits_of,
        examples.labels,
        examples.negatives,
        steps,
        batch,
        learning_rate,
        seed,
        log_every,
    )
    assert isinstance(trained, ShortcutScorer)
    return trained


__all__ = [
    "ScorerExamples",
    "ShortcutScorer",
    "fit_edge_scorer",
    "scorer_examples",
    "train_shortcut_scorer",
]
