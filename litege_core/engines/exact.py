"""Exact polyhedral geodesics (MMP / Surazhsky-Kirsanov) from vertices to all vertices.

Two backends wrap the same C++ algorithm (Kirsanov's ``geodesic_algorithm_exact``), so they
agree to the last bit on well-formed meshes:

* ``"pygeodesic"`` (default): ``PyGeodesicAlgorithmExact`` keeps the mesh built between
  queries; measured marginally faster per row (see ``scripts/bench_geodesics.py``).
* ``"gdist"`` (tvb-gdist): ``compute_gdist`` rebuilds the mesh on each call.

Both segfault on faces with a repeated corner and on non-manifold edges; the engine drops the
former (zero-area faces, see :mod:`litege_core.engines._topology`) and refuses the latter
with an :class:`~litege_core.errors.InputError` before any C++ code runs. pygeodesic also
fails at random (``OverflowError`` on a garbage source index) when some vertices are
unreachable, so each connected component gets its own solver; vertices the source cannot
reach (other components, unreferenced vertices) get ``+inf``.

Rows can be computed in a pool of worker processes (``n_workers > 1``), useful for batch
ground-truth builds: each row is independent and single-threaded. A crashing worker becomes a
:class:`~litege_core.errors.ComputationError` instead of killing the caller.
"""

from __future__ import annotations

import multiprocessing
from collections.abc import Mapping
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from typing import ClassVar, Protocol

import numpy as np
from numpy.typing import NDArray

from litege_core.engines.base import MeshGeodesicEngine, ParamValue, wrap_foreign
from litege_core.errors import ComputationError, InputError, LiteGEError, MissingDependencyError
from litege_core.query import parse_indices
from litege_core.shape import Shape

EXACT_BACKENDS: tuple[str, ...] = ("pygeodesic", "gdist")
DEFAULT_EXACT_BACKEND = "pygeodesic"
_FOREIGN_ERRORS = (RuntimeError, ValueError, TypeError, OverflowError, MemoryError)


class _RowSolver(Protocol):
    def row(self, source: int) -> NDArray:
        """``(M,)`` float64 distances from compact vertex ``source`` to all compact vertices."""
        ...


class _PygeodesicRows:
    """pygeodesic backend; the mesh must reference every vertex (guaranteed by the caller)."""

    def __init__(self, vertices: NDArray, faces: NDArray) -> None:
        try:
            from pygeodesic.geodesic import PyGeodesicAlgorithmExact
        except ImportError as exc:  # pragma: no cover - dependency of the package
            raise MissingDependencyError(
                "backend 'pygeodesic' needs: pip install pygeodesic"
            ) from exc
        self._vertices = np.ascontiguousarray(vertices, dtype=np.float64)
        self._algorithm = PyGeodesicAlgorithmExact(
            self._vertices, np.ascontiguousarray(faces, dtype=np.int32)
        )

    def row(self, source: int) -> NDArray:
        # pygeodesic prints its errors and returns (None, None) instead of raising.
        distances, _ = self._algorithm.geodesicDistances(np.array([source], dtype=np.int32), None)
        if distances is None:
            raise ComputationError("pygeodesic failed (see its message on stdout)", source=source)
        return np.asarray(distances, dtype=np.float64)

    def path(self, source: int, target: int) -> NDArray:
        """``(L, 3)`` float64 exact geodesic polyline from compact vertex ``source`` to
        ``target`` (pygeodesic returns it target → source; reversed here)."""
        if source == target:
            return np.stack([self._vertices[source], self._vertices[source]])
        _, points = self._algorithm.geodesicDistance(int(source), int(target))
        if points is None or len(points) < 2:
            raise ComputationError(
                "pygeodesic returned no path (see its message on stdout)",
                source=source,
                target=target,
            )
        return np.ascontiguousarray(np.asarray(points, dtype=np.float64)[::-1])


class _GdistRows:
    """tvb-gdist backend: float64 vertices, int32 triangles."""

    def __init__(self, vertices: NDArray, faces: NDArray) -> None:
        try:
            import gdist
        except ImportError as exc:  # pragma: no cover - dependency of the package
            raise MissingDependencyError("backend 'gdist' needs: pip install tvb-gdist") from exc
        self._compute = gdist.compute_gdist
        self._vertices = np.ascontiguousarray(vertices, dtype=np.float64)
        self._faces = np.ascontiguousarray(faces, dtype=np.int32)

    def row(self, source: int) -> NDArray:
        distances = self._compute(
            self._vertices, self._faces, source_indices=np.array([source], dtype=np.int32)
        )
        return np.asarray(distances, dtype=np.float64)


def _make_row_solver(backend: str, vertices: NDArray, faces: NDArray) -> _RowSolver:
    try:
        if backend == "pygeodesic":
            return _PygeodesicRows(vertices, faces)
        return _GdistRows(vertices, faces)
    except LiteGEError:
        raise
    except _FOREIGN_ERRORS as exc:
        raise wrap_foreign("exact", exc) from exc


class _ComponentRows:
    """Exact rows computed on the connected component of each source.

    pygeodesic reads an uninitialised source index for vertices the front never reaches and
    then fails at random with ``OverflowError`` (seen on two disjoint spheres), so each
    component gets its own solver; the other components are ``+inf`` by construction. This
    also shortens each propagation on multi-component meshes.

    Args:
        backend: ``"pygeodesic"`` or ``"gdist"``.
        vertices: ``(N, 3)`` float64 original vertices.
        faces: ``(F, 3)`` int64 cleaned faces in original indices (no repeated corners, no
            duplicates, manifold edges).
        component: ``(N,)`` int64 connected-component label of each vertex.
    """

    def __init__(self, backend: str, vertices: NDArray, faces: NDArray, component: NDArray) -> None:
        self._backend = backend
        self._vertices = vertices
        self._component = component
        face_label = component[faces[:, 0]]
        order = np.argsort(face_label, kind="stable")
        labels, starts = np.unique(face_label[order], return_index=True)
        groups = np.split(faces[order], starts[1:])
        self._faces_of: dict[int, NDArray] = dict(zip(labels.tolist(), groups, strict=True))
        self._solvers: dict[int, tuple[NDArray, _RowSolver]] = {}
        self._path_solvers: dict[int, _PygeodesicRows] = {}

    @property
    def labels(self) -> list[int]:
        """Labels of the components that have faces."""
        return list(self._faces_of)

    def solver(self, label: int) -> tuple[NDArray, _RowSolver]:
        """``(vertex ids (m,), solver on those m vertices)`` of one component (cached)."""
        if label not in self._solvers:
            faces = self._faces_of[label]
            ids = np.unique(faces)
            local = np.searchsorted(ids, faces)
            solver = _make_row_solver(self._backend, self._vertices[ids], local)
            self._solvers[label] = (ids, solver)
        return self._solvers[label]

    def row(self, source: int) -> NDArray:
        """``(N,)`` float64 distances from vertex ``source``; ``+inf`` off its component."""
        out = np.full(self._vertices.shape[0], np.inf)
        label = int(self._component[source])
        if label in self._faces_of:
            ids, solver = self.solver(label)
            out[ids] = solver.row(int(np.searchsorted(ids, source)))
        out[source] = 0.0
        return out

    def path(self, source: int, target: int) -> NDArray:
        """``(L, 3)`` float64 exact geodesic polyline from vertex ``source`` to ``target``.

        Always computed with pygeodesic (the gdist backend has no path output; both run the
        same C++ algorithm). Raises :class:`InputError` when the two vertices lie on different
        connected components (no surface path joins them).
        """
        if source == target:
            return np.stack([self._vertices[source], self._vertices[source]]).astype(np.float64)
        label = int(self._component[source])
        if label != int(self._component[target]) or label not in self._faces_of:
            raise InputError(
                f"vertices {source} and {target} lie on different connected components of the "
                "mesh; no surface path joins them",
                source=source,
                target=target,
            )
        ids, solver = self.solver(label)
        if not isinstance(solver, _PygeodesicRows):
            if label not in self._path_solvers:
                self._path_solvers[label] = _PygeodesicRows(
                    self._vertices[ids], np.searchsorted(ids, self._faces_of[label])
                )
            solver = self._path_solvers[label]
        local = np.searchsorted(ids, [source, target]).tolist()
        return solver.path(int(local[0]), int(local[1]))


def _solve_rows(rows: _ComponentRows, sources: list[int]) -> NDArray:
    try:
        return np.stack([rows.row(source) for source in sources])
    except LiteGEError:
        raise
    except _FOREIGN_ERRORS as exc:
        raise wrap_foreign("exact", exc) from exc


# Per-process state of the pool workers (set once by the initializer).
_WORKER_ROWS: list[_ComponentRows] = []


def _init_worker(backend: str, vertices: NDArray, faces: NDArray, component: NDArray) -> None:
    _WORKER_ROWS[:] = [_ComponentRows(backend, vertices, faces, component)]


def _worker_rows(sources: list[int]) -> NDArray:
    return _solve_rows(_WORKER_ROWS[0], sources)


class ExactGeodesicEngine(MeshGeodesicEngine):
    """Exact geodesic distances on a triangle mesh, one MMP propagation per source.

    Args:
        shape: a mesh :class:`~litege_core.shape.Shape` (point clouds are refused).
        backend: ``"pygeodesic"`` (default) or ``"gdist"``.
        n_workers: processes used by one :meth:`distances` call (default 1: in-process).
            With ``n_workers > 1`` a ``spawn`` pool is started per call (about a second of
            start-up), so pass large batches; as with any ``spawn`` pool, a script calling
            it must guard its entry point with ``if __name__ == "__main__":``.

    Raises:
        InputError: a point cloud, an unknown backend, ``n_workers < 1``, or a mesh with
            non-manifold edges (which crash the C++ solver).

    Cost: about 0.1 s per source on a 5K-vertex mesh (O(N log N)-ish per row).
    """

    method: ClassVar[str] = "exact"

    def __init__(
        self, shape: Shape, backend: str = DEFAULT_EXACT_BACKEND, n_workers: int = 1
    ) -> None:
        super().__init__(shape)
        if backend not in EXACT_BACKENDS:
            raise InputError(
                f"unknown exact geodesic backend {backend!r}; expected one of {EXACT_BACKENDS}"
            )
        if isinstance(n_workers, bool) or not isinstance(n_workers, int | np.integer):
            raise InputError(f"n_workers must be an integer, got {n_workers!r}")
        if n_workers < 1:
            raise InputError(f"n_workers must be at least 1, got {n_workers}")
        self._backend = backend
        self._n_workers = int(n_workers)
        self._solver: _ComponentRows | None = None
        bad = self.topology.nonmanifold_edges
        if bad.shape[0]:
            raise InputError(
                f"the exact geodesic engine needs a manifold mesh: {bad.shape[0]} edges have more "
                f"than two faces (first: vertices {int(bad[0, 0])}-{int(bad[0, 1])}); "
                "repair the mesh or use method='heat' or 'edge_dijkstra'",
                n_nonmanifold_edges=int(bad.shape[0]),
            )

    @property
    def params(self) -> Mapping[str, ParamValue]:
        return {"backend": self._backend}

    @property
    def backend(self) -> str:
        """The backend in use."""
        return self._backend

    @property
    def n_workers(self) -> int:
        """Worker processes per :meth:`distances` call."""
        return self._n_workers

    def _worker_args(self) -> tuple[str, NDArray, NDArray, NDArray]:
        topology = self.topology
        faces = topology.to_original[topology.faces]
        return self._backend, self._shape.vertices, faces, topology.component

    def prepare(self) -> ExactGeodesicEngine:
        """Build the in-process solvers of every component (a few ms for 5K vertices)."""
        if self._solver is None:
            self._solver = _ComponentRows(*self._worker_args())
            try:
                for label in self._solver.labels:
                    self._solver.solver(label)
            except LiteGEError:
                raise
            except _FOREIGN_ERRORS as exc:
                raise wrap_foreign(self.method, exc) from exc
        return self

    def path(self, source: int, target: int) -> NDArray:
        """The exact geodesic path between two vertices (in-process, pygeodesic).

        Args:
            source: vertex index of the start.
            target: vertex index of the end.

        Returns:
            ``(L, 3)`` float64 polyline, ``L >= 2``, ``points[0]`` = vertex ``source``,
            ``points[-1]`` = vertex ``target``; every point lies on a mesh edge or vertex, and
            its length equals the exact distance (to the solver's rounding).

        Raises:
            IndexOutOfRangeError: an index outside ``[0, N)``; InputError: the two vertices
            lie on different connected components; ComputationError: the solver failed.
        """
        ends = parse_indices(np.array([source, target]), self.n_points, "path end")
        self.prepare()
        assert self._solver is not None
        welded = self.topology.welds[ends]  # a seam copy: from its first copy (same position)
        try:
            return self._solver.path(int(welded[0]), int(welded[1]))
        except LiteGEError:
            raise
        except _FOREIGN_ERRORS as exc:
            raise wrap_foreign(self.method, exc) from exc

    def _rows(self, sources: NDArray) -> NDArray:
        todo = sources.tolist()
        if self._n_workers > 1 and len(todo) > 1:
            return self._pool_rows(todo)
        self.prepare()
        assert self._solver is not None
        return _solve_rows(self._solver, todo)

    def _pool_rows(self, todo: list[int]) -> NDArray:
        n_workers = min(self._n_workers, len(todo))
        n_chunks = min(len(todo), 4 * n_workers)
        chunks = [chunk.tolist() for chunk in np.array_split(np.asarray(todo), n_chunks)]
        try:
            with ProcessPoolExecutor(
                max_workers=n_workers,
                mp_context=multiprocessing.get_context("spawn"),
                initializer=_init_worker,
                initargs=self._worker_args(),
            ) as pool:
                return np.concatenate(list(pool.map(_worker_rows, chunks)))
        except BrokenProcessPool as exc:
            raise ComputationError(
                "an exact-geodesic worker process died (the C++ solver may have crashed on "
                "this mesh)",
                method="exact",
            ) from exc


__all__ = [
    "DEFAULT_EXACT_BACKEND",
    "EXACT_BACKENDS",
    "ExactGeodesicEngine",
]
