"""Geodesic paths by gradient descent of the learned distance (paper; reference-spec §6),
finished on the surface when the descent stalls.

A returned polyline runs **from the source to the target** (``points[0]`` is the source,
``points[-1]`` the target), as the service returns it. It is *traced* the other way: a walker
starts at the target ``t`` and repeatedly moves against the gradient of the predicted distance
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
  any case after ``max_steps`` iterations (tries, accepted or not). ``converged`` says whether
  the learned walk really reached the source: ``‖x − s‖ ≤ max(tolerance, step)`` where it
  stopped.
* **Finishing on the surface.** A walker that stopped within one step ``η`` of the source
  joins it directly (a hop no longer than its own moves). One that stopped farther away (it
  stalled, or ran out of ``max_steps``) is finished by an on-surface route from its stall point
  to the source — never by a straight jump through the air:

  - mesh: a straight move inside the stall triangle to its nearest corner, then
    ``"edge-flip"``, the locally shortest geodesic between that corner and the source's
    (nearest) corner by edge flips from the shortest edge path (potpourri3d's
    ``EdgeFlipGeodesicSolver``, about 1 ms on 5K vertices; its points lie on mesh edges), and
    a straight move inside the source's triangle. Where geometry-central refuses the mesh
    (non-manifold edges or vertices) the route is ``"mesh-edges"``, the Dijkstra shortest path
    along mesh edges.
  - point cloud: ``"knn-graph"``, the Dijkstra shortest path on the symmetric
    :data:`KNN_NEIGHBOURS`-nearest-neighbour graph of the cloud (every vertex a cloud point),
    or, for a predictor that fuses, on the fusion's own vetoed graph (its
    ``surface_router``).
  - ``"straight"``: only where no surface route exists — the stall point and the source lie on
    different connected components of the mesh (or of the cloud's k-NN graph).

  :attr:`GeodesicPath.segments` says which method produced which part of the polyline.

``route="surface"`` skips the walk: every path is that on-surface route from the target to the
source; ``route="auto"`` (the default) takes it where the predictor fuses its distances with a
graph (:data:`ROUTES`).

All walkers of one call advance together as one batch (one network evaluation with gradient
and one projection per step for all active walkers; finished walkers are masked out). The
on-surface router of a shape (edge graph, k-NN graph, edge-flip solver) is built on the first
stall and kept with the :class:`~litege_core.learned.ShapeState`.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np
import torch
from numpy.typing import ArrayLike, NDArray

from litege_core.errors import ArrayShapeError, InputError
from litege_core.learned.state import ResolvedPoints, ShapeState
from litege_core.projection import CloudProjector
from litege_core.query import QueryLike, parse_query

if TYPE_CHECKING:
    import scipy.sparse as sp

    from litege_core.engines._topology import MeshTopology

MESH_STEP_FRACTION = 0.5
"""Default step on a mesh, as a fraction of its mean edge length."""

CLOUD_STEP_FRACTION = 1.5
"""Default step on a point cloud, as a multiple of its mean nearest-neighbour spacing."""

CLOUD_CANDIDATES = 6
"""Cloud points nearest to a stepped position among which a cloud walker picks the lowest G."""

MAX_HALVINGS = 3
"""Rejected moves are retried with the step halved this many times before the walker stops."""

KNN_NEIGHBOURS = 8
"""Neighbours per point of the k-NN graph that finishes stalled walks on point clouds."""

LEARNED = "learned"
"""Method of a path part traced by the learned walk (the hop to the source included)."""
EDGE_FLIP = "edge-flip"
"""Locally shortest geodesic on a mesh by edge flips (potpourri3d), from corner to corner."""
MESH_EDGES = "mesh-edges"
"""Dijkstra shortest path along mesh edges (meshes geometry-central refuses)."""
KNN_GRAPH = "knn-graph"
"""Dijkstra shortest path on the point cloud's k-NN graph."""
STRAIGHT = "straight"
"""A straight segment, only between parts of a shape that no surface route connects."""
PATH_METHODS = (LEARNED, EDGE_FLIP, MESH_EDGES, KNN_GRAPH, STRAIGHT)
"""Every value :attr:`GeodesicPath.segments` can name."""
SURFACE = "surface"
"""``route`` of :func:`trace_paths`: no learned walk, the on-surface route from the start (the
finishing route of the module docstring, from the target to the source)."""
ROUTES = ("auto", LEARNED, SURFACE)
"""Values of :func:`trace_paths`' ``route``: ``auto`` (the default) is ``surface`` where the
predictor fuses its distances with a graph (the shipped models: their distances are mostly or
wholly the graph's, so their paths follow the same graph: on the real dev meshes an edge-flip
path errs 0.28 / 0.07 against the learned walk's 7.24 / 5.77, on their 2000-point clouds the
route on the fusion's vetoed graph 4.46 / 3.80 against 11.37 / 9.96 (TOSCA / FAUST, GT mean
100); BENCHMARKS.md "path-quality"), else ``learned``."""


class DistanceModel(Protocol):
    """What the tracer needs of a learned distance (:class:`~litege_core.learned.Predictor`)."""

    device: torch.device

    def check_state(self, state: ShapeState) -> None: ...

    def resolve(self, state: ShapeState, query: QueryLike, what: str = ...) -> ResolvedPoints: ...

    def point_features(self, state: ShapeState, positions: torch.Tensor) -> torch.Tensor: ...

    def predict_canonical(
        self,
        src_features: torch.Tensor,
        dst_features: torch.Tensor,
        src_positions: torch.Tensor,
        dst_positions: torch.Tensor,
    ) -> torch.Tensor: ...


_TRACER_NEEDS = ("check_state", "resolve", "point_features", "predict_canonical")
"""The methods of :class:`DistanceModel` the tracer calls."""


@dataclass(frozen=True)
class GeodesicPath:
    """A traced path, from the source to the target.

    Attributes:
        points: ``(L, 3)`` float64 polyline in the user's frame (read-only), ``L ≥ 2``;
            ``points[0]`` is the source, ``points[-1]`` the target.
        length: polyline length, user units.
        predicted_distance: the network's ``G(source, target)``, user units.
        n_steps: accepted gradient steps of the learned walk.
        converged: whether the learned walk (traced from the target) ended within
            ``max(tolerance, step)`` of the source; for a ``surface`` route (no walk,
            ``n_steps`` 0), whether a surface route joins the two points (not ``straight``).
        segments: the parts of the polyline as ``(start_index, method)`` pairs in order,
            ``method`` one of :data:`PATH_METHODS`; part ``k`` runs from
            ``points[start_k]`` to ``points[start_{k+1}]`` (the last one to ``points[-1]``).
            ``((0, "learned"),)`` when the walk reached the source; e.g.
            ``((0, "edge-flip"), (37, "learned"))`` when it stalled at ``points[37]`` and an
            edge-flip geodesic finished it (see the module docstring).
    """

    points: NDArray
    length: float
    predicted_distance: float
    n_steps: int
    converged: bool
    segments: tuple[tuple[int, str], ...]


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
    predictor: DistanceModel,
    state: ShapeState,
    sources: QueryLike,
    targets: QueryLike,
    *,
    step: float | None = None,
    max_steps: int | None = None,
    tolerance: float | None = None,
    route: str = "auto",
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
        route: ``"learned"`` (the walk, finished on the surface), ``"surface"`` (the
            on-surface route alone) or ``"auto"`` (``surface`` where the predictor fuses,
            :data:`ROUTES`).

    Returns:
        ``B`` :class:`GeodesicPath` in the order of the pairs, each from its source to its
        target.

    Raises:
        InputError: ``predictor`` is not a torch :class:`~litege_core.learned.Predictor`
            (e.g. the torch-free ``NumpyPredictor``, which has no gradients to walk along).
    """
    missing = [name for name in _TRACER_NEEDS if not callable(getattr(predictor, name, None))]
    if missing:
        raise InputError(
            f"paths need the torch Predictor (litege_core.learned.Predictor); "
            f"{type(predictor).__name__} has no {', '.join(missing)}"
        )
    predictor.check_state(state)
    if route not in ROUTES:
        raise InputError(f"route must be one of {list(ROUTES)}, got {route!r}")
    if route == "auto":
        route = SURFACE if getattr(predictor, "fusion", None) is not None else LEARNED
    src = predictor.resolve(state, parse_query(sources, "source", allow_all=False), "source")
    dst = predictor.resolve(state, parse_query(targets, "target", allow_all=False), "target")
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
        predicted_t = predictor.predict_canonical(
            src.features, dst.features, src.positions, dst.positions
        )
        coincide = torch.linalg.vector_norm(src.positions - dst.positions, dim=-1) == 0
        predicted = predicted_t.masked_fill(coincide, 0.0).double().cpu().numpy()
    if max_steps is None:
        max_steps = math.ceil(4.0 * float(predicted.max()) / step_c) + 64
    elif isinstance(max_steps, bool) or not isinstance(max_steps, int | np.integer):
        raise InputError(f"max_steps must be a non-negative integer, got {max_steps!r}")
    if max_steps < 0:
        raise InputError(f"max_steps must be a non-negative integer, got {max_steps!r}")
    walk = _Walk(predictor, state, src, dst.canonical, step_c, tol_c)
    if route == LEARNED:
        walk.run(int(max_steps))
    return walk.paths(src, dst, predicted / scale, surface=route == SURFACE)


def trace_path(
    predictor: DistanceModel,
    state: ShapeState,
    source: int | ArrayLike,
    target: int | ArrayLike,
    *,
    step: float | None = None,
    max_steps: int | None = None,
    tolerance: float | None = None,
    route: str = "auto",
) -> GeodesicPath:
    """One path from ``source`` to ``target`` (an index or an xyz point each); see
    :func:`trace_paths` for the arguments."""
    return trace_paths(
        predictor,
        state,
        parse_query(source, "source", allow_all=False, single=True),
        parse_query(target, "target", allow_all=False, single=True),
        step=step,
        max_steps=max_steps,
        tolerance=tolerance,
        route=route,
    )[0]


def _broadcast(
    predictor: DistanceModel, src: ResolvedPoints, dst: ResolvedPoints
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
        predictor: DistanceModel,
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
            features = predictor.point_features(self.state, pos)
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
        self,
        src: ResolvedPoints,
        dst: ResolvedPoints,
        predicted_user: NDArray,
        surface: bool = False,
    ) -> list[GeodesicPath]:
        """Assemble the polylines (source → target), finishing stalled walks on the surface;
        ``surface``: every walker (none has moved) takes the surface route."""
        transform = self.state.transform
        gap = np.linalg.norm(self.x - self.source, axis=1)
        limit = max(self.tolerance, self.step) * (1 + 1e-9)
        if surface:
            stalled = np.arange(self.x.shape[0])
        else:
            stalled = np.flatnonzero(gap > self.step * (1 + 1e-9))
        routes = self._finish(stalled, src) if stalled.size else {}
        results = []
        for b in range(self.x.shape[0]):  # assembling the outputs, after the walk
            inner = self.history[1 : self.n_steps[b] + 1, b]
            if self.cloud_index is not None and inner.shape[0]:  # cloud points, exactly
                inner = self.state.vertices[self._nearest_cloud_point(inner)]
            else:
                inner = transform.invert(inner)
            walk = np.concatenate([dst.user[b : b + 1], inner])  # target → where it stopped
            if b in routes:
                route, method = routes[b]
                finish = _dedupe(np.concatenate([walk[-1:], route, src.user[b : b + 1]]))
                points = np.concatenate([walk[:-1], finish])[::-1]
                segments: tuple[tuple[int, str], ...] = ((0, method),)
                if walk.shape[0] > 1:
                    segments += ((finish.shape[0] - 1, LEARNED),)
            else:
                points = np.concatenate([walk, src.user[b : b + 1]])[::-1]
                segments = ((0, LEARNED),)
            if points.shape[0] == 1:  # a surface route from a point to itself
                points = np.repeat(points, 2, axis=0)
            points = np.ascontiguousarray(points)
            points.setflags(write=False)
            length = float(np.linalg.norm(np.diff(points, axis=0), axis=1).sum())
            results.append(
                GeodesicPath(
                    points=points,
                    length=length,
                    predicted_distance=float(predicted_user[b]),
                    n_steps=int(self.n_steps[b]),
                    converged=bool(gap[b] <= limit) or (surface and segments[0][1] != STRAIGHT),
                    segments=segments,
                )
            )
        return results

    def _nearest_cloud_point(self, points: NDArray) -> NDArray:
        """Index of the cloud point nearest each of ``points`` (point clouds only)."""
        assert isinstance(self.projector, CloudProjector)  # cloud_index is set for clouds only
        return self.projector.nearest(points)[1]

    def _finish(self, stalled: NDArray, src: ResolvedPoints) -> dict[int, tuple[NDArray, str]]:
        """On-surface routes (user frame, vertex to vertex) from where the walkers ``stalled``
        stopped to their sources: ``{walker: (points (R, 3), method)}``."""
        state = self.state
        if self.cloud_index is not None:
            starts = self.cloud_index[stalled]
            if src.indices is not None:
                ends = src.indices[stalled]
            else:
                ends = self._nearest_cloud_point(self.source[stalled])
        else:
            starts = self._nearest_corner(self.x[stalled])
            if src.indices is not None:
                ends = src.indices[stalled]
            else:
                ends = self._nearest_corner(self.source[stalled])
        router_of = getattr(self.predictor, "surface_router", default_router)  # fusion-aware
        found = router_of(state).routes(starts, ends)
        return {int(b): route for b, route in zip(stalled, found, strict=True)}

    def _nearest_corner(self, canonical: NDArray) -> NDArray:
        """The corner nearest to each surface point ``(Q, 3)`` of the triangle it lies on."""
        projected = self.projector.project(canonical)
        corners = np.asarray(self.state.faces)[projected.face_index]  # (Q, 3)
        distance = np.linalg.norm(
            self.state.canonical_points[corners] - projected.points[:, None], axis=2
        )
        return corners[np.arange(corners.shape[0]), np.argmin(distance, axis=1)]


def default_router(state: ShapeState) -> SurfaceRouter:
    """The :class:`SurfaceRouter` of ``state``'s own graphs (kept with the state)."""
    router = state._lazy.get("surface_router")
    if router is None:
        router = state._lazy.setdefault(
            "surface_router", SurfaceRouter(state.vertices, state.faces)
        )
    return router


def _dedupe(points: NDArray) -> NDArray:
    """``points (L, 3)`` without consecutive exact repeats (the first one kept)."""
    keep = np.ones(points.shape[0], dtype=bool)
    keep[1:] = np.any(points[1:] != points[:-1], axis=1)
    return points[keep]


class SurfaceRouter:
    """Shortest on-surface routes between vertices of one mesh, or points of one cloud.

    Built from the user-frame arrays of a shape (see the module docstring for the methods);
    the graphs are built at construction, potpourri3d's edge-flip solver on first use. Safe to
    share between threads (queries on one router are serialized).

    Args:
        vertices: ``(N, 3)`` float64 vertices or cloud points.
        faces: ``(F, 3)`` int64 triangles, or ``None`` for a point cloud.
        graph: a point cloud's ``(N, N)`` graph to route on (any units; e.g. a fusion's vetoed
            k-NN graph), instead of its :data:`KNN_NEIGHBOURS`-NN graph, which still routes
            the pairs ``graph`` (or ``trees``) does not connect.
        trees: with ``graph``, ``(roots (R,), far (F,)) → (R, N)`` Dijkstra predecessors
            from the roots (scipy's: ``-9999`` for none) on the graph the routes follow, to be
            read towards the ``far`` nodes (a fusion's lazily vetoed graph:
            :func:`~litege_core.learned.fusion.route_trees`); ``None``: Dijkstra on ``graph``.
    """

    def __init__(
        self,
        vertices: NDArray,
        faces: NDArray | None,
        graph: sp.csr_array | None = None,
        trees: Callable[[NDArray, NDArray], NDArray] | None = None,
    ) -> None:
        # scipy and the engines load with the first router (a path), not with the predictor.
        from scipy.sparse.csgraph import connected_components

        from litege_core.engines._topology import MeshTopology
        from litege_core.engines.graph import edge_graph, knn_graph

        self.vertices = np.asarray(vertices, dtype=np.float64)
        self._lock = threading.Lock()
        self._flip: Any = None
        self._topology: MeshTopology | None = None
        n = self.vertices.shape[0]
        self._welds = np.arange(n, dtype=np.int64)  # a mesh's seam copies: their first copy
        self._given_graph = graph is not None and faces is None
        self._fallback: SurfaceRouter | None = None  # built on the first pair it must route
        self._trees = trees if self._given_graph else None
        if faces is None:
            self.graph: sp.csr_array = (
                knn_graph(self.vertices, KNN_NEIGHBOURS) if graph is None else graph
            )
            self.graph_method = KNN_GRAPH
            self._flip_refused = True
        else:
            topology = MeshTopology.from_arrays(self.vertices, np.asarray(faces, np.int64))
            edges = topology.edges
            lengths = np.linalg.norm(
                self.vertices[edges[:, 0]] - self.vertices[edges[:, 1]], axis=1
            )
            self.graph = edge_graph(n, edges, lengths)
            self.graph_method = MESH_EDGES
            self._topology = topology
            self._welds = topology.welds
            self._flip_refused = topology.nonmanifold_edges.shape[0] > 0
        _, self.component = connected_components(self.graph, directed=False)

    def routes(self, starts: NDArray, ends: NDArray) -> list[tuple[NDArray, str]]:
        """Routes from ``starts[i]`` to ``ends[i]`` (vertex / point indices): each a polyline
        ``(R, 3)`` from ``vertices[starts[i]]`` to ``vertices[ends[i]]`` (``R ≥ 1``) and the
        method that produced it."""
        # a seam copy routes as its first copy (the same position)
        starts = self._welds[np.asarray(starts, dtype=np.int64).reshape(-1)]
        ends = self._welds[np.asarray(ends, dtype=np.int64).reshape(-1)]
        from litege_core.engines.graph import dijkstra_tree

        with self._lock:
            out: list[tuple[NDArray, str] | None] = [None] * starts.size
            graph_pairs: dict[int, list[int]] = {}
            for i, (a, b) in enumerate(zip(starts.tolist(), ends.tolist(), strict=True)):
                if a == b:
                    out[i] = (self.vertices[[a]], self.graph_method)
                elif self.component[a] != self.component[b]:
                    out[i] = (self.vertices[[a, b]], STRAIGHT)
                else:
                    flipped = self._edge_flip(a, b)
                    if flipped is not None:
                        out[i] = (flipped, EDGE_FLIP)
                    else:
                        graph_pairs.setdefault(b, []).append(i)
            if graph_pairs:  # one Dijkstra tree per distinct end
                roots = np.fromiter(graph_pairs, dtype=np.int64, count=len(graph_pairs))
                if self._trees is not None:
                    far = starts[[i for rows in graph_pairs.values() for i in rows]]
                    predecessors = self._trees(roots, far)
                else:
                    predecessors = dijkstra_tree(self.graph, roots)[1]
            for tree, (end, rows) in enumerate(graph_pairs.items()):
                for i in rows:
                    chain = [int(starts[i])]
                    while chain[-1] != end and chain[-1] >= 0:
                        chain.append(int(predecessors[tree, chain[-1]]))
                    if chain[-1] == end:
                        out[i] = (self.vertices[chain], self.graph_method)
                    else:  # the trees' graph (a veto) splits them
                        out[i] = (self.vertices[[chain[0], end]], STRAIGHT)
        apart = [i for i, route in enumerate(out) if route is not None and route[1] == STRAIGHT]
        if apart and self._given_graph:  # the given graph splits them: the k-NN graph routes
            with self._lock:
                if self._fallback is None:
                    self._fallback = SurfaceRouter(self.vertices, None)
            found = self._fallback.routes(starts[apart], ends[apart])
            for i, route in zip(apart, found, strict=True):
                out[i] = route
        return [route for route in out if route is not None]

    def _edge_flip(self, a: int, b: int) -> NDArray | None:
        """potpourri3d's edge-flip geodesic from vertex ``a`` to ``b``, or ``None`` where
        geometry-central refuses the mesh (or this pair)."""
        if self._flip_refused or self._topology is None:
            return None
        topology = self._topology
        try:
            if self._flip is None:
                import potpourri3d as pp3d

                self._flip = pp3d.EdgeFlipGeodesicSolver(topology.vertices, topology.faces)
            found = self._flip.find_geodesic_path(
                int(topology.to_compact[a]), int(topology.to_compact[b])
            )
        except (RuntimeError, ValueError, ImportError):
            self._flip_refused = self._flip is None  # the mesh itself was refused
            return None
        points = np.array(found, dtype=np.float64).reshape(-1, 3)
        if points.shape[0] < 2 or not np.isfinite(points).all():
            return None
        start = self.vertices[a]
        if np.linalg.norm(points[-1] - start) < np.linalg.norm(points[0] - start):
            points = points[::-1].copy()  # whatever order potpourri3d returns: a → b
        points[0], points[-1] = self.vertices[a], self.vertices[b]
        return points


__all__ = [
    "CLOUD_CANDIDATES",
    "CLOUD_STEP_FRACTION",
    "EDGE_FLIP",
    "KNN_GRAPH",
    "KNN_NEIGHBOURS",
    "LEARNED",
    "MAX_HALVINGS",
    "MESH_EDGES",
    "MESH_STEP_FRACTION",
    "PATH_METHODS",
    "ROUTES",
    "STRAIGHT",
    "SURFACE",
    "GeodesicPath",
    "SurfaceRouter",
    "default_router",
    "trace_path",
    "trace_paths",
]
