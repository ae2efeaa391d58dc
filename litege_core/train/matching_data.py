"""Training tables of the matching network (reference-spec §3.4, §1.6).

Every view of a training shape is what a user would send, randomly rotated, then put through
the *inference* frame (:func:`~litege_core.matching.frame.align_shapes`: unit-area or Poisson
scaling, then the T-Net), so the T-Net's alignment noise is baked into the training inputs as
it is at test time (spec §1.6 "Important"). Views the T-Net misaligns by more than
``reject_angle`` are dropped (the training-time rejection filter, 0.66 rad). Misaligned from
what: a procedural or posed-template dataset is stored in the canonical frame, but a user's
collection is stored in its own convention (a glTF: y up, facing +z), so its reference frame is
the one the T-Net agrees on (:func:`stored_frame_offset`).

A training pair is two views of *different* shapes ``(a, b)``, a shared source row ``r`` and a
vertex ``t``: the source is vertex ``sources[r]`` on X = view ``a`` and the destination vertex
``t`` on Y = view ``b`` (or, with probability ½, source ``t`` on X and destination
``sources[r]`` on Y), and the target is ``target_scale × ½ (g_a(r, t) + g_b(r, t))`` with the
unit-area geodesics ``g`` (the shared template topology makes vertex ``t`` correspond).

Tables of several template datasets (the procedural shapes and one dataset per rigged
species, whose triangulations differ) are joined by :func:`concatenate_tables`: vertex and
distance arrays are padded to the largest vertex count, and every view pair is drawn within
one dataset (``group_start`` / ``group_size``), with ``t`` below that dataset's vertex count.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np
import torch
from numpy.typing import ArrayLike, NDArray

from litege_core.descriptor import UdfPcaBasis
from litege_core.errors import InputError
from litege_core.matching.frame import MatchingPipeline, align_shapes
from litege_core.nets import TNet
from litege_core.shape import Shape
from litege_core.train.augment import augmented_view
from litege_core.train.config import AugmentConfig
from litege_core.variants import random_rotation

REJECT_ANGLE = 0.66
"""T-Net misalignment (rad) above which a training view is rejected (spec §1.6)."""


@dataclass
class MatchingTables:
    """Per-view tensors on one device (``W`` views of ``S`` shapes, ``V`` vertices, ``R`` rows).

    Attributes:
        descriptors: ``(W, E)`` float32.
        vertices: ``(W, V, 3)`` float32 vertices in the view's aligned unit-area frame.
        shape: ``(W,)`` int64 shape of each view.
        distances: ``(S, R, V)`` unit-area geodesics from the shape's source rows (float32).
        sources: ``(S, R)`` int64 source vertex of each row.
        angle: ``(W,)`` float32 T-Net misalignment of each view (rad).
        n_vertices: ``(S,)`` int64 vertices of each shape (``V`` but in joined tables, whose
            shorter shapes are padded).
        group_start, group_size: ``(W,)`` int64 first view and number of views of the
            dataset a view belongs to (pairs are drawn within it).
    """

    descriptors: torch.Tensor
    vertices: torch.Tensor
    shape: torch.Tensor
    distances: torch.Tensor
    sources: torch.Tensor
    angle: torch.Tensor
    n_vertices: torch.Tensor
    group_start: torch.Tensor
    group_size: torch.Tensor

    def to(self, device: torch.device | str) -> MatchingTables:
        return MatchingTables(**{f.name: getattr(self, f.name).to(device) for f in fields(self)})

    @property
    def n_views(self) -> int:
        return int(self.shape.shape[0])


def misalignment(
    transform_rotation: NDArray, view_rotation: NDArray, offset: NDArray | None = None
) -> float:
    """Angle (rad) of the residual rotation ``R_frame · R_view`` from ``offset`` (the identity
    by default: the shapes are stored in the canonical frame; 0 = perfectly undone)."""
    residual = transform_rotation @ view_rotation
    if offset is not None:
        residual = np.asarray(offset).T @ residual
    return float(_angle(np.trace(residual)))


def _angle(trace: ArrayLike) -> NDArray:
    """Angle (rad) of rotations from their traces."""
    return np.arccos(np.clip((np.asarray(trace) - 1.0) / 2.0, -1.0, 1.0))


def stored_frame_offset(
    arrays: dict[str, NDArray],
    faces: NDArray,
    tnet: TNet,
    pipeline: MatchingPipeline,
    *,
    seed: int,
    n_shapes: int = 32,
    agree_angle: float = REJECT_ANGLE,
) -> tuple[NDArray, float]:
    """Where the T-Net's canonical frame lies in the frame a dataset's shapes are stored in.

    Up to ``n_shapes`` shapes of the split (evenly spread over it) are each turned by a seeded
    random rotation ``R_view`` and aligned by the T-Net (``R_frame``, as in training); where the
    T-Net holds, ``R_frame · R_view`` is one rotation ``C`` for all of them. ``C`` is the
    residual with the most others within ``agree_angle`` of it, refined to the rotation nearest
    the mean of those (chordal mean).

    Returns:
        ``(C (3, 3), share)``: the offset (pass it to :func:`build_matching_tables`) and the
        share of the residuals within ``agree_angle`` of it.
    """
    raw = np.asarray(arrays["vertices"], dtype=np.float64)
    picked = np.unique(np.linspace(0, raw.shape[0] - 1, min(n_shapes, raw.shape[0])).astype(int))
    shapes, turns = [], []
    for s in picked:
        turn = random_rotation(np.random.default_rng([seed, int(arrays["seed"][s]), 0xF4A3]))
        shapes.append(Shape.from_arrays(raw[s] @ turn.T, faces))
        turns.append(turn)
    frames = align_shapes(shapes, tnet, pipeline, seed=seed)
    residuals = np.stack(
        [transform.rotation @ turn for (transform, _, _), turn in zip(frames, turns, strict=True)]
    )
    between = np.einsum("aij,bij->ab", residuals, residuals)  # trace(R_aᵀ R_b)
    near = _angle(between) <= agree_angle
    members = near[int(np.argmax(near.sum(axis=1)))]
    u, _, vt = np.linalg.svd(residuals[members].mean(axis=0))
    offset = u @ np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt))]) @ vt
    share = float(np.mean(_angle(np.einsum("ij,aij->a", offset, residuals)) <= agree_angle))
    return offset, share


def build_matching_tables(
    arrays: dict[str, NDArray],
    faces: NDArray,
    n_shared: int,
    basis: UdfPcaBasis,
    tnet: TNet,
    pipeline: MatchingPipeline,
    *,
    n_views: int,
    augment: AugmentConfig,
    seed: int,
    reject_angle: float = REJECT_ANGLE,
    device: torch.device | str = "cpu",
    chunk: int = 32,
    frame_offset: NDArray | None = None,
) -> MatchingTables:
    """Views of every shape of a split (view 0 the clean mesh, the others augmented clouds).

    Args:
        arrays: a dataset split (vertices ``(S, V, 3)`` raw, sources ``(S, R)``, distances
            ``(S, R, V)`` raw units, area ``(S,)``, seed ``(S,)``).
        faces: ``(F, 3)`` shared triangulation.
        n_shared: the first ``n_shared`` rows are the shared sources (kept; the rest dropped).
        basis, tnet, pipeline: the matching frame and descriptor.
        n_views: views per shape; augment: settings of views 1..n-1 (``rotate`` should be
            on: view 0 is always rotated); seed: run seed; reject_angle: the filter (rad).
        frame_offset: the T-Net's canonical frame in the shapes' stored frame
            (:func:`stored_frame_offset`), that views are misaligned from; ``None``: the
            shapes are stored in the canonical frame.
    """
    if n_views < 1:
        raise InputError("n_views must be at least 1")
    if augment.frame_jitter_degrees > 0 or augment.axis_turn_probability > 0:
        raise InputError(
            "augment.frame_jitter_degrees and augment.axis_turn_probability are for geodesic "
            "training: the matching network's frames come from its T-Net"
        )
    raw = np.asarray(arrays["vertices"], dtype=np.float64)
    n_shapes = raw.shape[0]
    engine = basis.engine(device)
    descriptors, vertices, shape_of, angles = [], [], [], []
    pending: list[tuple[int, Shape, NDArray, NDArray]] = []

    def flush() -> None:
        if not pending:
            return
        frames = align_shapes([p[1] for p in pending], tnet, pipeline, seed=seed)
        kept = []
        for (s, _, user_vertices, rotation), (transform, cloud, _) in zip(
            pending, frames, strict=True
        ):
            angle = misalignment(transform.rotation, rotation, frame_offset)
            if angle > reject_angle:
                continue
            kept.append(cloud.astype(np.float32))
            vertices.append(transform.apply(user_vertices).astype(np.float32))
            shape_of.append(s)
            angles.append(angle)
        if kept:
            descriptors.append(engine.describe_batch(kept).detach().float().cpu())
        pending.clear()

    for s in range(n_shapes):
        for j in range(n_views):
            rng = np.random.default_rng([seed, int(arrays["seed"][s]), j])
            if j == 0:  # the clean mesh, randomly rotated
                rotation = random_rotation(rng)
                user_vertices = raw[s] @ rotation.T
                shape = Shape.from_arrays(user_vertices, faces)
            else:
                view = augmented_view(raw[s], faces, float(arrays["area"][s]), augment, rng)
                rotation = view.rotation
                user_vertices = raw[s] @ rotation.T
                shape = Shape.from_arrays(view.points, None)
            pending.append((s, shape, user_vertices, rotation))
            if len(pending) >= chunk:
                flush()
    flush()
    if not shape_of:
        raise InputError("every view was rejected by the T-Net filter")
    scale = 1.0 / np.sqrt(np.asarray(arrays["area"], dtype=np.float64))
    distances = np.asarray(arrays["distances"][:, :n_shared], dtype=np.float32)
    distances = distances * scale[:, None, None].astype(np.float32)
    n_kept = len(shape_of)
    return MatchingTables(
        descriptors=torch.cat(descriptors).to(device),
        vertices=torch.from_numpy(np.stack(vertices)).to(device),
        shape=torch.tensor(shape_of, dtype=torch.int64, device=device),
        distances=torch.from_numpy(distances).to(device),
        sources=torch.from_numpy(arrays["sources"][:, :n_shared].astype(np.int64)).to(device),
        angle=torch.tensor(angles, dtype=torch.float32, device=device),
        n_vertices=torch.full((n_shapes,), raw.shape[1], dtype=torch.int64, device=device),
        group_start=torch.zeros(n_kept, dtype=torch.int64, device=device),
        group_size=torch.full((n_kept,), n_kept, dtype=torch.int64, device=device),
    )


def _zero_pad(tensor: torch.Tensor, length: int, dim: int) -> torch.Tensor:
    """``tensor`` zero-padded along ``dim`` to ``length``."""
    missing = length - tensor.shape[dim]
    if missing == 0:
        return tensor
    pad_shape = list(tensor.shape)
    pad_shape[dim] = missing
    return torch.cat([tensor, tensor.new_zeros(pad_shape)], dim=dim)


def concatenate_tables(parts: list[MatchingTables]) -> MatchingTables:
    """Join the tables of several template datasets (see the module docstring): views and
    shapes are renumbered, vertices ``(W, V, 3)`` and distances ``(S, R, V)`` zero-padded to
    the largest ``V``, rows cut to the smallest ``R``; pairs stay within each part.

    Raises:
        InputError: no parts, or parts with different descriptor sizes.
    """
    if not parts:
        raise InputError("no matching tables to join")
    if len({int(p.descriptors.shape[1]) for p in parts}) != 1:
        raise InputError("matching tables with different descriptor sizes cannot be joined")
    n_rows = min(int(p.sources.shape[1]) for p in parts)
    n_max = max(int(p.vertices.shape[1]) for p in parts)
    shapes_before = 0
    views_before = 0
    shape, starts, sizes = [], [], []
    for part in parts:
        shape.append(part.shape + shapes_before)
        starts.append(part.group_start + views_before)
        sizes.append(part.group_size)
        shapes_before += int(part.sources.shape[0])
        views_before += part.n_views
    return MatchingTables(
        descriptors=torch.cat([p.descriptors for p in parts]),
        vertices=torch.cat([_zero_pad(p.vertices, n_max, 1) for p in parts]),
        shape=torch.cat(shape),
        distances=torch.cat([_zero_pad(p.distances[:, :n_rows], n_max, 2) for p in parts]),
        sources=torch.cat([p.sources[:, :n_rows] for p in parts]),
        angle=torch.cat([p.angle for p in parts]),
        n_vertices=torch.cat([p.n_vertices for p in parts]),
        group_start=torch.cat(starts),
        group_size=torch.cat(sizes),
    )


@dataclass
class MatchingBatch:
    """``P`` training pairs: coordinates, descriptors and targets (target units)."""

    src: torch.Tensor
    dst: torch.Tensor
    desc_src: torch.Tensor
    desc_dst: torch.Tensor
    target: torch.Tensor


def view_pairs(tables: MatchingTables, n_pairs: int, generator: torch.Generator) -> torch.Tensor:
    """``(n_pairs, 2)`` random ordered pairs of views of different shapes of one dataset
    (``a`` uniform over all views, ``b`` uniform over the views of ``a``'s dataset)."""
    w = tables.n_views
    device = tables.shape.device
    a = torch.randint(0, w, (n_pairs,), generator=generator, device=device)
    start, size = tables.group_start[a], tables.group_size[a]

    def partner() -> torch.Tensor:
        u = torch.rand(n_pairs, generator=generator, device=device)
        return start + torch.minimum((u * size).long(), size - 1)

    b = partner()
    same = tables.shape[a] == tables.shape[b]
    for _ in range(8):  # redraw the (rare) same-shape pairs
        if not same.any():
            break
        b = torch.where(same, partner(), b)
        same = tables.shape[a] == tables.shape[b]
    if same.any():
        raise InputError("need views of at least two different shapes")
    return torch.stack([a, b], dim=1)


def sample_batch(
    tables: MatchingTables,
    n_view_pairs: int,
    rows_per_pair: int,
    targets_per_pair: int,
    target_scale: float,
    generator: torch.Generator,
) -> MatchingBatch:
    """A random training batch of ``n_view_pairs × rows_per_pair × targets_per_pair`` pairs."""
    device = tables.shape.device
    pairs = view_pairs(tables, n_view_pairs, generator)
    n_rows = tables.sources.shape[1]
    per = rows_per_pair * targets_per_pair
    a = pairs[:, 0].repeat_interleave(per)
    b = pairs[:, 1].repeat_interleave(per)
    total = a.shape[0]
    sa, sb = tables.shape[a], tables.shape[b]
    row = torch.randint(0, n_rows, (total,), generator=generator, device=device)
    n_vertices = tables.n_vertices[sa]
    u = torch.rand(total, generator=generator, device=device)
    t = torch.minimum((u * n_vertices).long(), n_vertices - 1)
    source_vertex = tables.sources[sa, row]
    target = 0.5 * (tables.distances[sa, row, t] + tables.distances[sb, row, t]) * target_scale
    swap = torch.rand(total, generator=generator, device=device) < 0.5
    x_vertex = torch.where(swap, t, source_vertex)
    y_vertex = torch.where(swap, source_vertex, t)
    return MatchingBatch(
        src=tables.vertices[a, x_vertex],
        dst=tables.vertices[b, y_vertex],
        desc_src=tables.descriptors[a],
        desc_dst=tables.descriptors[b],
        target=target,
    )


@dataclass
class ValidationSet:
    """Fixed validation pairs of clean views of different shapes.

    Attributes:
        pairs: ``(Q, 2)`` view pairs.
        batch: fixed regression pairs for the (masked) L1.
    """

    pairs: torch.Tensor
    batch: MatchingBatch


def validation_set(
    tables: MatchingTables,
    n_view_pairs: int,
    rows_per_pair: int,
    targets_per_pair: int,
    target_scale: float,
    seed: int,
) -> ValidationSet:
    generator = torch.Generator(device=tables.shape.device).manual_seed(seed)
    batch = sample_batch(
        tables, n_view_pairs, rows_per_pair, targets_per_pair, target_scale, generator
    )
    pairs = view_pairs(tables, n_view_pairs, generator)
    return ValidationSet(pairs=pairs, batch=batch)


__all__ = [
    "REJECT_ANGLE",
    "MatchingBatch",
    "MatchingTables",
    "ValidationSet",
    "build_matching_tables",
    "concatenate_tables",
    "misalignment",
    "sample_batch",
    "stored_frame_offset",
    "validation_set",
    "view_pairs",
]
