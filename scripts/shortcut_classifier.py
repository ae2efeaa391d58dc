"""Can a learned scorer of local patches find the shortcuts the fused cloud graph keeps? (issue 14,
diagnosis after ``scripts/shortcut_edges.py``).

``shortcut_edges.py`` found that the fused cloud graph's error on the real dev set is mostly its
shortcuts (edges between parts that touch), that the network veto is blind to them and that
single local features see them only roughly (thickness AUC ~0.88). This script trains a small
PointNet on the edges of procedural animals in contact poses (``--train``: datasets we build,
never the dev set) and measures how well it ranks the shortcuts of other sets (``--eval``: the
held-out procedural contact poses, the calibration shapes, the real dev set) and what cutting
the edges it scores above a threshold does to the graph's error.

* An edge's input is a patch: the ``--patch`` nearest points of each end, in the edge's own
  frame (x along the chord, z the patch's least-variance axis), over the cloud's spacing, with a
  ±1 flag for the end each came from; beside it the chord over the spacing, the thickness at
  both ends and the chord's normal cosine (``shortcut_edges.py``'s features).
* Labels: a kept edge is a shortcut when its true geodesic surely exceeds ``--stretch`` × its
  chord (:func:`~litege_core.evaluation.cloud_edges.kept_edges`).
* Training: all shortcuts and a ``--negatives`` share of the other edges, balanced by weight,
  with the frame's symmetries (chord direction, normal sign) drawn at random; Adam, cosine
  schedule, seed 0, one torch thread.

Every number comes from this script::

    python scripts/shortcut_classifier.py --train data/quadruped-steep-train@quadrupeds \\
        --eval data/quadruped-steep-cal@quadrupeds,data/folder-cal@quadrupeds,tosca
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse
from datetime import UTC, datetime

import numpy as np
import torch
from numpy.typing import NDArray

from litege_core.evaluation.cloud_edges import KeptEdges, collect_kept_edges, shortcut_cut_table
from litege_core.evaluation.speed import cpu_name
from litege_core.learned.cloud_surface import normal_cosines
from litege_core.train.shortcuts import fit_edge_scorer

PATCH = 24
"""Nearest points of each end of an edge in its patch (``--patch``)."""
N_EXTRA = 4
"""Edge features beside the patch (:func:`edge_features`)."""


def edge_patches(edges: KeptEdges, which: NDArray, patch: int = PATCH) -> NDArray:
    """``(E, 2 patch, 4)`` float32 patches of the edges ``which``: both ends' ``patch`` nearest
    points in
    the edge's frame (rows x: the unit chord, z: the patch's least-variance axis made
    perpendicular to x, y = z × x), centred on the chord's midpoint, over the spacing, and a
    flag (+1: near the start, −1: near the end)."""
    i, j, points = edges.i[which], edges.j[which], edges.points
    around = np.concatenate([edges.nearest[i, :patch], edges.nearest[j, :patch]], axis=1)
    local = points[around] - (0.5 * (points[i] + points[j]))[:, None, :]  # (E, 2P, 3)
    chord = points[j] - points[i]
    x = chord / np.maximum(np.linalg.norm(chord, axis=1, keepdims=True), 1e-12)
    centred = local - local.mean(axis=1, keepdims=True)
    _, axes = np.linalg.eigh(np.einsum("epi,epj->eij", centred, centred))
    z = axes[:, :, 0] - np.einsum("ei,ei->e", axes[:, :, 0], x)[:, None] * x
    z /= np.maximum(np.linalg.norm(z, axis=1, keepdims=True), 1e-12)
    frame = np.stack([x, np.cross(z, x), z], axis=1)  # (E, 3, 3): the frame's axes as rows
    coords = np.einsum("eij,epj->epi", frame, local) / edges.spacing
    flag = np.repeat([1.0, -1.0], patch)[None, :, None]
    flags = np.broadcast_to(flag, (coords.shape[0], 2 * patch, 1))
    return np.concatenate([coords, flags], axis=2).astype(np.float32)


def edge_features(edges: KeptEdges, which: NDArray) -> NDArray:
    """``(E, N_EXTRA)`` float32: the chord over the spacing, the thickness at the thicker and at
    the thinner end, the chord's normal cosine."""
    i, j, chord = edges.i[which], edges.j[which], edges.chord[which]
    thick_i, thick_j = edges.thickness[i], edges.thickness[j]
    cosine = normal_cosines(edges.points, edges.normals, i, j, chord)
    columns = [chord / edges.spacing, np.maximum(thick_i, thick_j), np.minimum(thick_i, thick_j)]
    return np.column_stack([*columns, cosine]).astype(np.float32)


class PatchScorer(torch.nn.Module):
    """A PointNet over an edge's patch (shared point MLP, max-pooled) and its features → the
    logit of being a shortcut."""

    def __init__(self, width: int = 96) -> None:
        super().__init__()
        self.points = torch.nn.Sequential(
            torch.nn.Linear(4, width),
            torch.nn.ReLU(),
            torch.nn.Linear(width, 2 * width),
            torch.nn.ReLU(),
        )
        self.head = torch.nn.Sequential(
            torch.nn.Linear(2 * width + N_EXTRA, width), torch.nn.ReLU(), torch.nn.Linear(width, 1)
        )

    def forward(self, patches: torch.Tensor, features: torch.Tensor) -> torch.Tensor:
        """``(B, 2P, 4)``, ``(B, N_EXTRA)`` → ``(B,)`` logits."""
        pooled = self.points(patches).amax(dim=1)
        return self.head(torch.cat([pooled, features], dim=1)).squeeze(1)


def turned(patches: torch.Tensor, generator: torch.Generator) -> torch.Tensor:
    """The patches in the frame's other valid orientations, drawn per edge: the chord walked
    the other way (x, y and the end flags negated: a half turn about z) and the normal's other
    sign (y and z negated: a half turn about x)."""
    out = patches.clone()
    reverse = torch.rand(out.shape[0], generator=generator) < 0.5
    flip = torch.rand(out.shape[0], generator=generator) < 0.5
    out[reverse] *= torch.tensor([-1.0, -1.0, 1.0, -1.0])
    out[flip] *= torch.tensor([1.0, -1.0, -1.0, 1.0])
    return out


def training_set(
    edges: list[KeptEdges], negatives: float, patch: int = PATCH, seed: int = 0
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Patches, features and labels of every shortcut and a ``negatives`` share of the other
    edges of each shape."""
    rng = np.random.default_rng(seed)
    patches, features, labels = [], [], []
    for shape in edges:
        positive, negative = np.flatnonzero(shape.shortcut), np.flatnonzero(~shape.shortcut)
        drawn = rng.choice(negative, size=round(negatives * negative.size), replace=False)
        which = np.concatenate([positive, drawn])
        patches.append(edge_patches(shape, which, patch))
        features.append(edge_features(shape, which))
        labels.append(shape.shortcut[which])
    return (
        torch.from_numpy(np.concatenate(patches)),
        torch.from_numpy(np.concatenate(features)),
        torch.from_numpy(np.concatenate(labels).astype(np.float32)),
    )


def train_scorer(
    patches: torch.Tensor,
    features: torch.Tensor,
    labels: torch.Tensor,
    steps: int,
    negatives: float,
    width: int = 96,
    batch: int = 512,
    seed: int = 0,
    log_every: int = 500,
) -> PatchScorer:
    """Fit a :class:`PatchScorer` (:func:`~litege_core.train.shortcuts.fit_edge_scorer`),
    each batch's patches turned at random."""
    model = fit_edge_scorer(
        lambda: PatchScorer(width),
        lambda m, drawn, generator: m(turned(patches[drawn], generator), features[drawn]),
        labels,
        negatives,
        steps,
        batch,
        seed=seed,
        log_every=log_every,
    )
    assert isinstance(model, PatchScorer)
    return model


def shortcut_scores(
    model: PatchScorer, edges: KeptEdges, patch: int = PATCH, block: int = 8192
) -> NDArray:
    """``(E,)`` the model's probability that each kept edge is a shortcut."""
    scores = []
    with torch.no_grad():
        for start in range(0, edges.chord.size, block):
            which = np.arange(start, min(start + block, edges.chord.size))
            patches = torch.from_numpy(edge_patches(edges, which, patch))
            logits = model(patches, torch.from_numpy(edge_features(edges, which)))
            scores.append(torch.sigmoid(logits).numpy())
    return np.concatenate(scores) if scores else np.zeros(0)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--train", default="data/quadruped-steep-train@quadrupeds")
    parser.add_argument(
        "--eval", default="data/quadruped-steep-cal@quadrupeds,data/folder-cal@quadrupeds,tosca"
    )
    parser.add_argument("--settings", default="cloud_2000,noise_0.01")
    parser.add_argument("--steps", type=int, default=8000)
    parser.add_argument("--patch", type=int, default=PATCH)
    parser.add_argument("--negatives", type=float, default=0.15)
    parser.add_argument("--width", type=int, default=96)
    parser.add_argument("--thresholds", default="0.1,0.2,0.3,0.5")
    parser.add_argument("--stretch", type=float, default=3.0)
    parser.add_argument("--sources", type=int, default=12)
    parser.add_argument("--eval-root", default="../shared/eval-data")
    parser.add_argument("--cache", default="out/exact-cache")
    parser.add_argument("--limit", type=int, default=None, help="the first shapes of each set")
    args = parser.parse_args()
    torch.set_num_threads(1)
    settings = args.settings.split(",")
    thresholds = tuple(float(t) for t in args.thresholds.split(","))

    def collect(key: str, seed: int) -> dict[str, list[KeptEdges]]:
        return collect_kept_edges(
            key, settings, eval_root=args.eval_root, sources=args.sources, cache=args.cache,
            limit=args.limit, stretch=args.stretch, seed=seed, neighbours=args.patch,
        )  # fmt: skip

    training = [
        shape
        for key in args.train.split(",")
        for shapes in collect(key, 1).values()
        for shape in shapes
    ]
    patches, features, labels = training_set(training, args.negatives, args.patch)
    if not labels.any():
        raise SystemExit("the training clouds have no shortcuts: nothing to learn")
    print("\n### A learned scorer of the fused cloud graph's shortcuts (issue 14, diagnosis)\n")
    print(
        f"- date {datetime.now(UTC):%Y-%m-%d %H:%M} UTC; machine {cpu_name()}, one torch thread; "
        f"trained on {args.train} ({len(training)} clouds, cloud seed 1: {labels.shape[0]} "
        f"edges, {int(labels.sum())} shortcuts), {args.steps} steps of 512, width {args.width}, "
        f"patches of 2 × {args.patch} points; scored on clouds of seed 0; {args.sources} FPS "
        f"sources per real shape, exact rows, GT mean 100; a shortcut: a kept edge whose true "
        f"geodesic exceeds {args.stretch} × its chord; command "
        f"`python scripts/shortcut_classifier.py --train {args.train} --eval {args.eval} "
        f"--settings {args.settings} --steps {args.steps} --patch {args.patch} "
        f"--width {args.width}`"
    )
    model = train_scorer(patches, features, labels, args.steps, args.negatives, args.width)
    for key in args.eval.split(","):
        for setting, shapes in collect(key, 0).items():
            scores = [shortcut_scores(model, s, args.patch) for s in shapes]
            print(f"\n{shortcut_cut_table(f'{key}, {setting}', shapes, scores, thresholds)}")


if __name__ == "__main__":
    main()
