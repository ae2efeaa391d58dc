"""Geodesic paths by gradient descent of the learned distance (paper; reference-spec §6).

For a source ``s`` and a target ``t`` the path is traced *from the target towards the source*:
a walker starts at ``t`` and repeatedly moves against the gradient of the predicted distance
``G(s, x)`` with respect to its own position ``x``, then is projected back onto the shape::

    x ← Proj(x − η · tangential(∇ₓ G(s, x)) / ‖tangential(∇ₓ G(s, x))‖)

* **Gradient.** ``G`` is the predictor's folded network, differentiated by autograd with
  respect to *canonical* coordinates (the coordinate z-score is inside the network), which is
  the true gradient. The authors' code multiplied a normalized-coordinate gradient by ``std``
  (a ``std²`` preconditioner, spec §6 🐞); that cannot happen here.
* **Step.** The component along the surface normal is removed (face normal of a mesh,
  local-PCA normal of a cloud), the direction is normalized, and the walker moves a fixed
  length ``η`` (``step``; default half the mean edge length of a mesh, 1.5 mean point spacings
  of a cloud, so that the walker reaches other cloud points).
* **Projection.** Mesh: the exact closest point on the triangles
  (:class:`~litege_core.projection.MeshProjector`). Point cloud: a cloud point — of the
  :data:`CLOUD_CANDIDATES` cloud points nearest to the stepped position, the one with the
  lowest ``G`` other than the current point (the paper snaps to the single nearest point,
  which on irregular samplings often *is* the current point, and the walk stalls). Every
  polyline vertex therefore lies on the input surface (on a cloud: is a cloud point).
* **Stopping rule.** A move is accepted only if it strictly decreases ``G``; a rejected move
  is retried with half the step, up to :data:`MAX_HALVINGS` times, after which the walker
  stops ("``G`` stops decreasing"). A walker also stops, successfully, when
  ``G(s, x) ≤ tolerance`` or ``‖x − s‖ ≤ tolerance`` (default ``tolerance = step``), and in
  any case after ``max_steps`` iterations (tries, accepted or not). The source is then
  appended, so every polyline starts exactly at the target and ends exactly at the source;
  ``converged`` says whether that last segment is short (``‖x − s‖ ≤ max(tolerance, step)``),
  i.e. whether the walk really reached the source.

All walkers of one call advance together as one batch (one network evaluation with gradient
and one projection per step for all active walkers; finished walkers are masked out).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
from numpy.typing import ArrayLike, NDArray

from litege_core.errors import ArrayShapeError, InputError
from litege_core.predictor import Predictor, ResolvedPoints, ShapeState
from litege_core.projection import CloudProjector

MESH_STEP_FRACTION = 0.5
"""Default step on a mesh, as a fraction of its mean edge length."""

CLOUD_STEP_FRACTION = 1.5
"""Default step on a point cloud, as a multiple of its mean nearest-neighbour spacing."""

CLOUD_CANDIDATES = 6
"""Cloud points nearest to a stepped position among which a cloud walker picks the lowest G."""

MAX_HALVINGS = 3
"""Rejected moves are retried with the step halved this many times before the walker stops."""


@dataclass(frozen=True)
class GeodesicPath:
    """A traced path.

    Attributes:
        points: ``(L, 3)`` float64 polyline in the user's frame (read-only), ``L ≥ 2``;
            ``points[0]`` is the target, ``points[-1]`` the source.
        length: polyline length, user units.
        predicted_distance: the network's ``G(source, target)``, user units.
        n_steps: accepted gradient steps.
        converged: whether the walk ended within ``max(tolerance, step)`` of the source.
    """

    points: NDArray
    length: float
    predicted_distance: float
    n_steps: int
    converged: bool


def _as_query(query: ArrayLike, what: str) -> ArrayLike:
    """A single index or xyz point becomes a batch of one."""
    if isinstance(query, torch.Tensor):
        query = query.detach().cpu().numpy()
    try:
        array = np.asarray(query)
    except (TypeError, ValueError) as exc:
        raise ArrayShapeError(f"{what} is not a regular array: {exc}") from exc
    if array.ndim == 0:
        return array.reshape(1)
    if array.ndim == 1 and array.shape[0] == 3 and np.issubdtype(array.dtype, np.floating):
        return array[None]
    return array


def _positive(value: float | None, name: str) -> float | None:
    if value is None:
        return None
    try:
        number = float(value)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{name} must be a positive number, got {value!r}") from exc
    if not (math.isfinite(number) and number > 0):
        raise InputError(f"{name} must be a positive number, got {value!r}")
    return number


def trace_paths(
    predictor: Predictor,
    state: ShapeState,
    sources: ArrayLike,
    targets: ArrayLike,
    *,
    step: float | None = None,
    max_steps: int | None = None,
    tolerance: float | None = None,
) -> list[GeodesicPath]:
    """Trace ``B`` paths on one shape at once.

    Args:
        predictor: the predictor ``state`` was registered with.
        state: the shape.
        sources: ``(B,)`` indices or ``(B, 3)`` xyz points (user frame; projected onto the
            surface). One source is broadcast against ``B`` targets and vice versa.
        targets: ``(B,)`` indices or ``(B, 3)`` xyz points.
        step: move length ``η`` in the user's units (default: see the module docstring).
        max_steps: cap on loop iterations (default ``4·max G / η + 64``).
        tolerance: stopping distance in the user's units (default ``step``).

    Returns:
        ``B`` :class:`GeodesicPath` in the order of the pairs.
    """
    predictor._check_state(state)
    src = predictor.resolve(state, _as_query(sources, "sources"), "source")
    dst = predictor.resolve(state, _as_query(targets, "targets"), "target")
    src, dst = _broadcast(predictor, src, dst)
    scale = state.transform.scale
    step_user = _positive(step, "step")
    if step_user is None:
        fraction = MESH_STEP_FRACTION if state.is_mesh else CLOUD_STEP_FRACTION
        step_c = fraction * state.spacing
    else:
        step_c = step_user * scale
    tol_user = _positive(tolerance, "tolerance")
    tol_c = step_c if tol_user is None else tol_user * scale
    with torch.no_grad():
        predicted = predictor.predict_canonical(
            src.features, dst.features, src.positions, dst.positions
        )
        coincide = torch.linalg.vector_norm(src.positions - dst.positions, dim=-1) == 0
        predicted = predicted.masked_fill(coincide, 0.0).double().cpu().numpy()
    if max_steps is None:
        max_steps = math.ceil(4.0 * float(predicted.max()) / step_c) + 64
    elif isinstance(max_steps, bool) or not isinstance(max_steps, int | np.integer):
        raise InputError(f"max_steps must be a non-negative integer, got {max_steps!r}")
    if max_steps < 0:
        raise InputError(f"max_steps must be a non-negative integer, got {max_steps!r}")
    walk = _Walk(predictor, state, src, dst.canonical, step_c, tol_c)
    walk.run(int(max_steps))
    return walk.paths(src, dst, predicted / scale)


def trace_path(
    predictor: Predictor,
    state: ShapeState,
    source: int | ArrayLike,
    target: int | ArrayLike,
    *,
    step: float | None = None,
    max_steps: int | None = None,
    tolerance: float | None = None,
) -> GeodesicPath:
    """One path from ``target`` to ``source`` (an index or an xyz point each); see
    :func:`trace_paths` for the arguments."""
    for value, name in ((source, "source"), (target, "target")):
        array = np.asarray(value)
        if not (array.ndim == 0 or (array.ndim == 1 and array.shape[0] == 3)):
            raise ArrayShapeError(
                f"{name} must be one index or one (3,) point, got shape {array.shape}"
            )
    return trace_paths(
        predictor,
        state,
        source,
        target,
        step=step,
        max_steps=max_steps,
        tolerance=tolerance,
    )[0]


def _broadcast(
    predictor: Predictor, src: ResolvedPoints, dst: ResolvedPoints
) -> tuple[ResolvedPoints, ResolvedPoints]:
    if src.count == dst.count:
        return src, dst
    if src.count == 1:
        return _repeat(src, dst.count), dst
    if dst.count == 1:
        return src, _repeat(dst, src.count)
    raise ArrayShapeError(
        f"got {src.count} sources and {dst.count} targets; pass as many of each, or one"
    )


def _repeat(points: ResolvedPoints, count: int) -> ResolvedPoints:
    return ResolvedPoints(
        points.features.expand(count, -1),
        points.positions.expand(count, -1),
        np.repeat(points.canonical, count, axis=0),
        np.repeat(points.user, count, axis=0),
        None if points.indices is None else np.repeat(points.indices, count),
    )


class _Walk:
    """The batched walkers of one :func:`trace_paths` call (canonical frame)."""

    def __init__(
        self,
        predictor: Predictor,
        state: ShapeState,
        src: ResolvedPoints,
        start: NDArray,
        step: float,
        tolerance: float,
    ) -> None:
        self.predictor = predictor
        self.state = state
        self.src = src
        self.source = src.canonical
        self.step = step
        self.tolerance = tolerance
        self.projector = state.projector
        first = self.projector.project(start)
        batch = start.shape[0]
        self.x = np.array(start, dtype=np.float64)  # exact start (already on the surface)
        self.normals = first.normals.copy()
        self.cloud_index = None if first.point_index is None else first.point_index.copy()
        self.proposed_index = np.zeros(0, dtype=np.int64)
        self.value, self.grad = self._evaluate(self.x, np.arange(batch))
        self.n_steps = np.zeros(batch, dtype=np.int64)
        self.halvings = np.zeros(batch, dtype=np.int64)
        self.history = np.empty((257, batch, 3))
        self.history[0] = self.x
        self.active = ~self._arrived(np.arange(batch), self.x, self.value)

    def _arrived(self, idx: NDArray, x: NDArray, value: NDArray) -> NDArray:
        gap = np.linalg.norm(x - self.source[idx], axis=1)
        return (gap <= self.tolerance) | (value <= self.tolerance)

    def _evaluate(self, x: NDArray, idx: NDArray) -> tuple[NDArray, NDArray]:
        """``G(s, x)`` (canonical units) and its gradient in ``x`` for walkers ``idx``."""
        predictor = self.predictor
        index = torch.from_numpy(idx).to(predictor.device)
        with torch.enable_grad():
            pos = torch.tensor(x, dtype=torch.float32, device=predictor.device)
            pos.requires_grad_(True)
            features = predictor.folded.features(predictor.folded.embed(pos, self.state.shape_bias))
            value = predictor.predict_canonical(
                self.src.features.index_select(0, index),
                features,
                self.src.positions.index_select(0, index),
                pos,
            )
            (grad,) = torch.autograd.grad(value.sum(), pos)
        return (
            value.detach().double().cpu().numpy(),
            grad.double().cpu().numpy(),
        )

    def _directions(self, idx: NDArray) -> NDArray:
        normals = self.normals[idx]
        direction = -self.grad[idx]
        direction -= np.einsum("bi,bi->b", direction, normals)[:, None] * normals
        norm = np.linalg.norm(direction, axis=1)
        flat = ~(norm > 1e-12)
        if flat.any():  # no usable gradient: head straight for the source, tangentially
            toward = self.source[idx[flat]] - self.x[idx[flat]]
            toward -= np.einsum("bi,bi->b", toward, normals[flat])[:, None] * normals[flat]
            direction[flat] = toward
            norm[flat] = np.linalg.norm(toward, axis=1)
        return direction / np.where(norm > 0, norm, 1.0)[:, None]

    def _record(self, idx: NDArray) -> None:
        needed = int(self.n_steps[idx].max()) + 1
        if needed > self.history.shape[0]:
            grown = np.empty((2 * needed, *self.history.shape[1:]))
            grown[: self.history.shape[0]] = self.history
            self.history = grown
        self.history[self.n_steps[idx], idx] = self.x[idx]

    def _propose(self, idx: NDArray, candidate: NDArray) -> tuple[NDArray, ...]:
        """Project the stepped positions ``candidate (A, 3)`` of walkers ``idx``; returns the
        new points, their normals, ``G`` and its gradient there (``G = inf``: no move)."""
        if self.cloud_index is None:
            projected = self.projector.project(candidate)
            value, grad = self._evaluate(projected.points, idx)
            still = np.all(projected.points == self.x[idx], axis=1)
            return projected.points, projected.normals, np.where(still, np.inf, value), grad
        assert isinstance(self.projector, CloudProjector)
        k = min(CLOUD_CANDIDATES, self.projector.points.shape[0])
        _, neighbours = self.projector.neighbours(candidate, k)  # (A, k)
        points = self.projector.points[neighbours]  # (A, k, 3)
        value, grad = self._evaluate(points.reshape(-1, 3), np.repeat(idx, k))
        value = value.reshape(-1, k)
        value[neighbours == self.cloud_index[idx, None]] = np.inf  # must move
        best = np.argmin(value, axis=1)
        rows = np.arange(idx.size)
        chosen = neighbours[rows, best]
        self.proposed_index = chosen
        return (
            points[rows, best],
            self.projector.normals[chosen],
            value[rows, best],
            grad.reshape(-1, k, 3)[rows, best],
        )

    def run(self, max_steps: int) -> None:
        for _ in range(max_steps):
            idx = np.flatnonzero(self.active)
            if idx.size == 0:
                break
            length = self.step * 0.5 ** self.halvings[idx]
            candidate = self.x[idx] + length[:, None] * self._directions(idx)
            points, normals, value, grad = self._propose(idx, candidate)
            accept = value < self.value[idx]
            ok = idx[accept]
            self.x[ok] = points[accept]
            self.normals[ok] = normals[accept]
            self.value[ok] = value[accept]
            self.grad[ok] = grad[accept]
            if self.cloud_index is not None:
                self.cloud_index[ok] = self.proposed_index[accept]
            self.n_steps[ok] += 1
            self.halvings[ok] = 0
            if ok.size:
                self._record(ok)
            rejected = idx[~accept]
            self.halvings[rejected] += 1
            arrived = ok[self._arrived(ok, self.x[ok], self.value[ok])]
            gave_up = rejected[self.halvings[rejected] > MAX_HALVINGS]
            self.active[arrived] = False
            self.active[gave_up] = False

    def paths(
        self, src: ResolvedPoints, dst: ResolvedPoints, predicted_user: NDArray
    ) -> list[GeodesicPath]:
        transform = self.state.transform
        gap = np.linalg.norm(self.x - self.source, axis=1)
        limit = max(self.tolerance, self.step) * (1 + 1e-9)
        results = []
        for b in range(self.x.shape[0]):  # assembling the outputs, after the walk
            inner = self.history[1 : self.n_steps[b] + 1, b]
            if self.cloud_index is not None and inner.shape[0]:  # cloud points, exactly
                inner = self.state.vertices[self.projector.nearest(inner)[1]]
            else:
                inner = transform.invert(inner)
            points = np.concatenate([dst.user[b : b + 1], inner, src.user[b : b + 1]])
            points.setflags(write=False)
            length = float(np.linalg.norm(np.diff(points, axis=0), axis=1).sum())
            results.append(
                GeodesicPath(
                    points=points,
                    length=length,
                    predicted_distance=float(predicted_user[b]),
                    n_steps=int(self.n_steps[b]),
                    converged=bool(gap[b] <= limit),
                )
            )
        return results


__all__ = [
    "CLOUD_CANDIDATES",
    "CLOUD_STEP_FRACTION",
    "MAX_HALVINGS",
    "MESH_STEP_FRACTION",
    "GeodesicPath",
    "trace_path",
    "trace_paths",
]
