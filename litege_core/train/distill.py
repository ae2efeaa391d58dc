"""Distil a small distance head from a trained geodesic bundle (issue 17, "a cheaper head").

The teacher is a :class:`~litege_core.learned.Predictor` on the trained bundle; no ground
truth is needed. The student (:class:`~litege_core.nets.small_head.SmallHead`) reads the
teacher's point embeddings ``e_p`` and learns the teacher's *head output* (network units,
before ``/ 1.42`` and the residual ``+ ‖s − d‖``), so the predictor's ``_finish`` applies to it
unchanged.

**Data, generated on the fly.** A pool of :attr:`DistillConfig.pool_views` views, refreshed
while training (the oldest view is replaced every :attr:`~DistillConfig.refresh_every` steps).
View ``v`` is a procedural shape of the bundle's category, family ``families[v % F]`` and seed
:data:`DISTILL_SEED_OFFSET` ``+ v`` — disjoint from the datasets' seeds (train ``0…``,
validation ``1,000,000…``, test ``2,000,000…``, merged datasets offset by multiples of
``10,000,000``) and from the agreement shapes (:data:`AGREEMENT_SEED_OFFSET`). With
probability :attr:`~DistillConfig.mesh_fraction` the view is the mesh itself, randomly
rotated; otherwise an augmented cloud exactly like the training views
(:func:`litege_core.train.augment.augmented_view`: 300–8000 area-weighted points, noise and
cuts by two planes with the training probabilities, random rotation). Poses are not checked
for self-intersection (``reject=False``, 15× faster; the student copies the teacher whatever
the pose). Each view is registered by the teacher (its canonicalization and descriptor; a
cloud whose augmentation turned its frame, ``AugmentConfig.axis_turn_probability``, in that
turned frame), its embeddings ``(N, n)`` kept, and :attr:`~DistillConfig.pairs_per_view`
pairs labelled once by the teacher head: a fraction :attr:`~DistillConfig.near_fraction` are
near pairs (a point and one of its :attr:`~DistillConfig.near_neighbours` nearest points), the
rest uniform.

**Loss.** ``Σ w |s − t| / Σ w`` over a batch, ``s``, ``t`` the student and teacher head
outputs, ``w = (1 + c) / (G_t / Ḡ + c)`` with ``G_t`` the teacher's geodesic (canonical
units), ``Ḡ`` the mean over the first pool and ``c`` = :attr:`~DistillConfig.relative_weight`.
The error the project reports is absolute (``|G − G_gt|`` over the mean ground truth), so plain
L1 is the objective; the factor, bounded in ``[(1 + c) / (G_max/Ḡ + c), (1 + c)/c]`` (about
0.6 to 2 at ``c = 1``), gives short pairs — where a fixed absolute error is a large relative
one, and where a distance field's near field and the path tracer look — twice the weight of
average ones, without the blow-up of ``1 / G`` as ``G → 0``.

**Schedule.** Adam, linear warm-up, cosine decay to :attr:`~DistillConfig.final_lr_fraction`
over a progress ``max(step / steps, elapsed / minutes)``: the run ends at whichever budget
comes first; when the step budget binds, every draw (views, pairs, batches, initial weights)
is a function of :attr:`~DistillConfig.seed` and the result is reproducible up to the matrix
kernels' float rounding (which may depend on memory alignment).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
import torch
from numpy.typing import NDArray

from litege_core.errors import InputError
from litege_core.learned import Predictor
from litege_core.nets.small_head import SmallHead
from litege_core.sampling import sample_surface
from litege_core.shape import Shape
from litege_core.synth import families, generate_shape
from litege_core.train.augment import augmented_view
from litege_core.train.config import AugmentConfig
from litege_core.variants import random_rotation

DISTILL_SEED_OFFSET = 5_000_000
"""First procedural seed of the distillation views (no dataset uses 5,000,000–9,999,999)."""

AGREEMENT_SEED_OFFSET = 6_000_000
"""First procedural seed of the held-out shapes of :func:`measure_agreement`."""

MODEL_CATEGORY = {"quadrupeds": "quadruped", "humans": "biped"}
"""Procedural category of each shipped geodesic model."""

_LABEL_CHUNK = 16_384  # teacher pairs per head call while labelling a view


@dataclass(frozen=True)
class DistillConfig:
    """Settings of one distillation run (see the module docstring).

    Attributes:
        features: ``m``, student point-feature width.
        hidden: ``k``, student hidden width.
        minutes: wall-clock budget of the run (pool building included).
        steps: step budget; the run stops at whichever budget is spent first.
        batch_pairs: pairs per optimisation step.
        views_per_batch: views a batch draws its pairs from (equal shares).
        pool_views: views held at once.
        pairs_per_view: teacher-labelled pairs per view.
        refresh_every: steps between two new views (each replaces the oldest).
        near_fraction: share of near pairs among a view's pairs.
        near_neighbours: a near pair joins a point and one of its this many nearest points.
        mesh_fraction: share of views that are the (rotated) mesh instead of a cloud.
        extra_fraction: share of views made from the extra meshes given to
            :func:`distill_small_head` (0: procedural shapes only).
        lr: peak Adam learning rate.
        final_lr_fraction: learning rate at the end, as a fraction of ``lr``.
        warmup_steps: linear warm-up.
        relative_weight: ``c`` of the loss weight ``(1 + c) / (G/Ḡ + c)`` (0: plain L1... up
            to a constant; large: relative error).
        seed: seed of every random stream.
        seed_offset: first procedural seed of the views.
        log_every: steps between two log lines.
        augment: the cloud views' settings (the training defaults).
    """

    features: int = 128
    hidden: int = 64
    minutes: float = 15.0
    steps: int = 40_000
    batch_pairs: int = 4096
    views_per_batch: int = 8
    pool_views: int = 48
    pairs_per_view: int = 32_768
    refresh_every: int = 16
    near_fraction: float = 0.25
    near_neighbours: int = 32
    mesh_fraction: float = 0.3
    extra_fraction: float = 0.0
    lr: float = 2e-3
    final_lr_fraction: float = 0.02
    warmup_steps: int = 200
    relative_weight: float = 1.0
    seed: int = 0
    seed_offset: int = DISTILL_SEED_OFFSET
    log_every: int = 200
    augment: AugmentConfig = field(default_factory=AugmentConfig)

    def __post_init__(self) -> None:
        positive: tuple[str, ...] = ("features", "hidden", "steps", "batch_pairs")
        positive += ("views_per_batch", "pool_views", "pairs_per_view", "refresh_every")
        positive += ("near_neighbours",)
        for name in positive:
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise InputError(f"{name} must be a positive integer, got {value!r}")
        if not self.minutes > 0 or not self.lr > 0:
            raise InputError("minutes and lr must be positive")
        for name in ("near_fraction", "mesh_fraction", "extra_fraction", "final_lr_fraction"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise InputError(f"{name} must lie in [0, 1]")
        if self.relative_weight < 0 or self.views_per_batch > self.pool_views:
            raise InputError("need relative_weight ≥ 0 and views_per_batch ≤ pool_views")

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass
class LabelledView:
    """One view with its teacher labels.

    Attributes:
        index: view number ``v`` (procedural seed ``seed_offset + v``).
        kind: ``"mesh"`` or ``"cloud"``.
        embeddings: ``(N, n)`` teacher point embeddings ``e_p`` (float32).
        src, dst: ``(P,)`` int64 point indices of the labelled pairs.
        target: ``(P,)`` teacher head outputs (network units).
        geodesic: ``(P,)`` teacher geodesics, canonical units (``target / 1.42 + ‖s − d‖``).
    """

    index: int
    kind: str
    embeddings: torch.Tensor
    src: torch.Tensor
    dst: torch.Tensor
    target: torch.Tensor
    geodesic: torch.Tensor


@dataclass
class DistillResult:
    """What :func:`distill_small_head` returns.

    Attributes:
        head: the trained student (eval mode, CPU).
        steps: optimisation steps run.
        views: views generated.
        seconds: wall time of the run.
        stopped_by: ``"steps"`` or ``"minutes"``.
        history: ``[(step, seconds, mean loss since the previous entry)]``.
        settings: the config, category, families and seeds (JSON).
    """

    head: SmallHead
    steps: int
    views: int
    seconds: float
    stopped_by: str
    history: list[tuple[int, float, float]]
    settings: dict[str, Any]


def _category_families(teacher: Predictor, category: str | None) -> tuple[str, tuple[str, ...]]:
    name = category or MODEL_CATEGORY.get(teacher.bundle.name) or teacher.bundle.category
    try:
        return name, families(name)
    except InputError as exc:
        raise InputError(
            f"cannot distil bundle {teacher.bundle.name!r}: no procedural category {name!r}"
        ) from exc


def view_shape(
    category: str, family: str, seed: int, rng: np.random.Generator, config: DistillConfig
) -> tuple[Shape, str, NDArray | None]:
    """The input a user could send for procedural shape ``(category, family, seed)``: the
    rotated mesh (probability ``mesh_fraction``) or an augmented cloud (see
    :func:`mesh_view`)."""
    generated = generate_shape(category, family, seed, reject=False)
    return mesh_view(generated.vertices, generated.faces, rng, config)


def mesh_view(
    vertices: NDArray, faces: NDArray, rng: np.random.Generator, config: DistillConfig
) -> tuple[Shape, str, NDArray | None]:
    """The input a user could send for a mesh ``(V, 3)``, ``(F, 3)``: the randomly rotated mesh
    (probability ``mesh_fraction``) or an augmented cloud; its kind; and the turn of its
    canonical frame (``(3, 3)``, the augmented view's frame jitter and axis turn as in
    training; ``None`` for none)."""
    vertices, faces = np.asarray(vertices, np.float64), np.asarray(faces)
    if rng.random() < config.mesh_fraction:
        rotation = random_rotation(rng)
        return Shape.from_arrays(vertices @ rotation.T, faces), "mesh", None
    area = float(Shape.from_arrays(vertices, faces).area)
    view = augmented_view(vertices, faces, area, config.augment, rng)
    return Shape.from_arrays(view.points), "cloud", view.frame


def _pairs(points: NDArray, count: int, config: DistillConfig, rng: np.random.Generator) -> tuple:
    """``count`` (src, dst) index pairs, ``near_fraction`` of them near pairs, none i = j."""
    from scipy.spatial import cKDTree

    n = points.shape[0]
    n_near = round(count * config.near_fraction) if n > 1 else 0
    src = rng.integers(0, n, count)
    dst = rng.integers(0, n, count)
    if n_near:
        k = min(config.near_neighbours, n - 1)
        _, neighbours = cKDTree(points).query(points[src[:n_near]], k=k + 1)
        pick = rng.integers(1, k + 1, n_near)
        dst[:n_near] = np.asarray(neighbours).reshape(n_near, k + 1)[np.arange(n_near), pick]
    same = src == dst
    dst[same] = (dst[same] + 1) % n
    return src, dst


def label_view(
    teacher: Predictor,
    shape: Shape,
    index: int,
    kind: str,
    config: DistillConfig,
    seed: int,
    frame: NDArray | None = None,
) -> LabelledView:
    """Register ``shape`` with the teacher (in its PCA frame turned by ``frame`` ``(3, 3)``
    when given) and label :attr:`~DistillConfig.pairs_per_view` of its pairs (see
    :class:`LabelledView`)."""
    rng = np.random.default_rng([seed, index, 1])
    if frame is None:
        state = teacher.register(shape)
    else:
        state = teacher.register_turned(shape, frame[None])[0]
    folded = teacher.folded
    with torch.no_grad():
        x = state.canonical_vertices
        embeddings = folded.embed(x, state.shape_bias)
        features = folded.features(embeddings)
        src_np, dst_np = _pairs(state.canonical_points, config.pairs_per_view, config, rng)
        src = torch.from_numpy(src_np).to(x.device)
        dst = torch.from_numpy(dst_np).to(x.device)
        target = torch.cat(
            [
                folded.head(
                    features[src[s : s + _LABEL_CHUNK]] - features[dst[s : s + _LABEL_CHUNK]],
                    inplace=True,
                )
                for s in range(0, src.shape[0], _LABEL_CHUNK)
            ]
        )
        geodesic = target / teacher.target_scale
        if teacher.residual:
            geodesic = geodesic + torch.linalg.vector_norm(x[src] - x[dst], dim=-1)
    return LabelledView(
        index, kind, embeddings.cpu(), src.cpu(), dst.cpu(), target.cpu(), geodesic.cpu()
    )


def _learning_rate(config: DistillConfig, step: int, progress: float) -> float:
    warm = min(1.0, (step + 1) / max(1, config.warmup_steps))
    f = config.final_lr_fraction
    return config.lr * warm * (f + (1.0 - f) * 0.5 * (1.0 + math.cos(math.pi * min(progress, 1.0))))


def distill_small_head(
    teacher: Predictor,
    config: DistillConfig = DistillConfig(),
    *,
    category: str | None = None,
    extra_meshes: Sequence[tuple[NDArray, NDArray]] = (),
    log: Callable[[str], None] | None = None,
) -> DistillResult:
    """Train a :class:`SmallHead` on the teacher's head outputs (module docstring).

    Args:
        teacher: the full-head predictor of the bundle to distil (CPU is fine).
        config: sizes, budgets and seeds.
        category: procedural category of the views (default: from the bundle name —
            ``quadrupeds`` → quadruped, ``humans`` → biped — else the bundle's category).
        extra_meshes: ``(vertices, faces)`` meshes beside the procedural shapes (e.g. posed
            collection animals, :func:`litege_core.train.tnet.collection_shape_set`): with
            probability :attr:`~DistillConfig.extra_fraction` a view is made from the next of
            them (in order, cycled) instead of a procedural shape.
        log: called with one line of progress at a time.

    Returns:
        The student and the run's summary.
    """
    if teacher.head != "full":
        raise InputError("the teacher must be a full-head predictor")
    say = log or (lambda line: None)
    category, names = _category_families(teacher, category)
    start = time.monotonic()
    budget = 60.0 * config.minutes
    torch.manual_seed(config.seed)
    generator = torch.Generator().manual_seed(config.seed)

    if config.extra_fraction > 0 and not extra_meshes:
        raise InputError("extra_fraction > 0 needs extra meshes")
    made = extra_made = 0

    def new_view() -> LabelledView:
        nonlocal made, extra_made
        index = made
        made += 1
        view_rng = np.random.default_rng([config.seed, index, 0])
        if extra_meshes and view_rng.random() < config.extra_fraction:
            vertices, faces = extra_meshes[extra_made % len(extra_meshes)]
            extra_made += 1
            shape, kind, frame = mesh_view(vertices, faces, view_rng, config)
            kind = f"extra {kind}"
        else:
            shape, kind, frame = view_shape(
                category, names[index % len(names)], config.seed_offset + index, view_rng, config
            )
        return label_view(teacher, shape, index, kind, config, config.seed, frame)

    pool = [new_view() for _ in range(config.pool_views)]
    mean_g = float(torch.cat([v.geodesic for v in pool]).mean())
    say(
        f"pool of {len(pool)} views ({sum(v.kind.endswith('mesh') for v in pool)} meshes, "
        f"{sum(v.kind.startswith('extra') for v in pool)} of extra meshes) in "
        f"{time.monotonic() - start:.1f} s; mean teacher geodesic {mean_g:.4f}"
    )
    head = SmallHead(teacher.folded.width, config.features, config.hidden, teacher.folded.output)
    with torch.no_grad():
        head.final.bias.fill_(float(torch.cat([v.target for v in pool]).mean()))
    optimizer = torch.optim.Adam(head.parameters(), lr=config.lr)
    c = config.relative_weight
    share = max(1, config.batch_pairs // config.views_per_batch)
    history: list[tuple[int, float, float]] = []
    running, running_n = 0.0, 0
    step, stopped_by, oldest = 0, "steps", 0
    while step < config.steps:
        elapsed = time.monotonic() - start
        if elapsed >= budget:
            stopped_by = "minutes"
            break
        progress = max(step / config.steps, elapsed / budget)
        for group in optimizer.param_groups:
            group["lr"] = _learning_rate(config, step, progress)
        chosen = torch.randperm(len(pool), generator=generator)[: config.views_per_batch]
        e_src, e_dst, targets, geodesics = [], [], [], []
        for v in chosen.tolist():
            view = pool[v]
            rows = torch.randint(0, view.src.shape[0], (share,), generator=generator)
            e_src.append(view.embeddings[view.src[rows]])
            e_dst.append(view.embeddings[view.dst[rows]])
            targets.append(view.target[rows])
            geodesics.append(view.geodesic[rows])
        out = head(torch.cat(e_src), torch.cat(e_dst))
        weight = (1.0 + c) / (torch.cat(geodesics) / mean_g + c) if c > 0 else None
        error = (out - torch.cat(targets)).abs()
        loss = (error * weight).sum() / weight.sum() if weight is not None else error.mean()
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        optimizer.step()
        running += float(loss.detach())
        running_n += 1
        step += 1
        if step % config.refresh_every == 0:
            pool[oldest] = new_view()
            oldest = (oldest + 1) % len(pool)
        if step % config.log_every == 0:
            seconds = time.monotonic() - start
            history.append((step, seconds, running / running_n))
            say(
                f"step {step} {seconds:.0f} s loss {running / running_n:.5f} "
                f"lr {optimizer.param_groups[0]['lr']:.2e} views {made}"
            )
            running, running_n = 0.0, 0
    seconds = time.monotonic() - start
    if running_n:
        history.append((step, seconds, running / running_n))
    say(f"done: {step} steps, {made} views, {seconds:.0f} s (stopped by {stopped_by})")
    head.eval()
    settings = {
        **config.to_dict(),
        "category": category,
        "families": list(names),
        "view_seeds": [config.seed_offset, config.seed_offset + made - 1],
        "extra_meshes": len(extra_meshes),
        "extra_views": extra_made,
        "mean_teacher_geodesic": mean_g,
    }
    return DistillResult(head, step, made, seconds, stopped_by, history, settings)


def agreement_inputs(
    category: str, n_shapes: int = 8, seed_offset: int = AGREEMENT_SEED_OFFSET
) -> dict[str, list[Shape]]:
    """Held-out inputs of :func:`measure_agreement`: ``n_shapes`` procedural shapes (seeds
    ``seed_offset + i``, families cycled) as meshes and as clean clouds of 2000 and 300
    area-weighted points."""
    names = families(category)
    inputs: dict[str, list[Shape]] = {"mesh": [], "cloud_2000": [], "cloud_300": []}
    for i in range(n_shapes):
        generated = generate_shape(category, names[i % len(names)], seed_offset + i)
        vertices, faces = np.asarray(generated.vertices), np.asarray(generated.faces)
        inputs["mesh"].append(Shape.from_arrays(vertices, faces))
        for n in (2000, 300):
            points = sample_surface(vertices, faces, n, seed_offset + i).points
            inputs[f"cloud_{n}"].append(Shape.from_arrays(points))
    return inputs


def measure_agreement(
    teacher: Predictor,
    student: Predictor,
    inputs: dict[str, list[Shape]],
    sources: int = 16,
) -> dict[str, dict[str, float]]:
    """Student vs teacher distances on the same registrations.

    For every setting of ``inputs``: ``sources`` evenly spaced source points of each shape to
    every point, ``|G_student − G_teacher|`` in canonical units pooled over the shapes, over
    the mean teacher distance, ×100
    (the unit of the project's geodesic error, with the teacher standing in for the ground
    truth): ``mean``, ``median``, ``p99``; and ``max_relative``, the largest
    ``|ΔG| / G_teacher`` of pairs at least 10 % of the mean distance apart.
    """
    if student.bundle.content_hash != teacher.bundle.content_hash:
        raise InputError("teacher and student predictors must serve the same bundle")
    report: dict[str, dict[str, float]] = {}
    for setting, shapes in inputs.items():
        diffs, refs = [], []
        for shape in shapes:
            state = teacher.register(shape)
            index = np.linspace(0, shape.n_points - 1, sources).round().astype(np.int64)
            reference = teacher.distances(state, index) * state.transform.scale  # canonical
            predicted = student.distances(state, index) * state.transform.scale
            diffs.append(predicted - reference)
            refs.append(reference)
        diff = np.abs(np.concatenate([d.ravel() for d in diffs]).astype(np.float64))
        ref = np.concatenate([r.ravel() for r in refs]).astype(np.float64)
        scale = 100.0 / ref.mean()
        far = ref > 0.1 * ref.mean()
        report[setting] = {
            "mean": float(diff.mean() * scale),
            "median": float(np.median(diff) * scale),
            "p99": float(np.quantile(diff, 0.99) * scale),
            "max_relative": float((diff[far] / ref[far]).max()),
            "pairs": int(diff.size),
        }
    return report


__all__ = [
    "AGREEMENT_SEED_OFFSET",
    "DISTILL_SEED_OFFSET",
    "MODEL_CATEGORY",
    "DistillConfig",
    "DistillResult",
    "LabelledView",
    "agreement_inputs",
    "distill_small_head",
    "label_view",
    "measure_agreement",
    "view_shape",
]
