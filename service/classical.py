"""Live classical solvers (``method`` heat / exact / graph) of registered shapes.

A :class:`~litege_core.engines.ClassicalSolver` is built from the shape's own geometry
(:meth:`ShapeRepository.shape`: the live state's shape, else the stored geometry; no model
involved) and kept per ``(shape_id, method)`` in a :class:`~service.store.ByteLRU` bounded by
``LITEGE_SOLVER_CACHE_BYTES``. Its engines build lazily on the first query (heat: one
factorisation; exact: the MMP mesh; graph: the k-NN graph) and keep native memory that
:func:`~service.store.footprint` cannot see, so an entry weighs its arrays plus
:data:`NATIVE_BYTES_PER_VERTEX` per vertex (measured with ``/proc`` RSS on 2.5K-10K-vertex
icospheres, an xyz query's refined copy of the mesh included).

Used from the runtime's compute thread only.
"""

from __future__ import annotations

from dataclasses import replace

from litege_core.engines import CLASSICAL_METHODS, ClassicalSolver
from service.metrics import ServiceMetrics
from service.repository import ShapeRepository
from service.store import ByteLRU, Footprint, footprint

METHODS: tuple[str, ...] = ("learned", *CLASSICAL_METHODS)
"""Every ``method`` a geodesic or path request takes; ``learned`` is the default."""

NATIVE_BYTES_PER_VERTEX = {"heat": 8 * 1024, "exact": 8 * 1024, "graph": 512}
"""Native memory of a solver per vertex, on top of its numpy arrays (measured: heat ~4 KiB
per vertex for the base factorisation, ~8 KiB with the refined copy an xyz query builds;
exact ~4 / ~9 KiB; graph ~0.3 / 0.8 KiB, mostly arrays the footprint sees)."""


def _solver_footprint(solver: ClassicalSolver) -> Footprint:
    measured = footprint(solver)
    native = NATIVE_BYTES_PER_VERTEX[solver.method] * solver.shape.n_points
    return replace(measured, nbytes=measured.nbytes + native)


class SolverCache:
    """Classical solvers per ``(shape_id, method)``, bounded by ``cache_bytes``.

    Args:
        repository: where the shapes' geometry is found.
        cache_bytes: budget of the live solvers.
        max_exact_vertices: the largest mesh ``exact`` runs on.
        metrics: the process's metrics (cache ``solver`` in ``litege_cache_*``).
    """

    def __init__(
        self,
        repository: ShapeRepository,
        *,
        cache_bytes: int,
        max_exact_vertices: int,
        metrics: ServiceMetrics,
    ) -> None:
        self.repository = repository
        self.max_exact_vertices = int(max_exact_vertices)
        self.metrics = metrics
        self._lru: ByteLRU[tuple[str, str], ClassicalSolver] = ByteLRU(
            cache_bytes, sizeof=_solver_footprint
        )
        metrics.watch_cache("solver", self._lru.usage)

    def get(self, shape_id: str, method: str) -> ClassicalSolver:
        """The live solver of a registered shape, built now if needed.

        Raises:
            ShapeNotFoundError: the shape is not registered.
            MethodNotApplicableError: ``exact`` on a point cloud.
            MethodSizeLimitError: ``exact`` on a mesh above ``max_exact_vertices``.
        """
        key = (shape_id, method)
        solver = self._lru.get(key)
        if solver is not None:
            self.metrics.cache.labels("solver", "hit").inc()
            return solver
        self.metrics.cache.labels("solver", "miss").inc()
        shape = self.repository.shape(shape_id)
        solver = ClassicalSolver(shape, method, max_exact_vertices=self.max_exact_vertices)
        self._lru.put(key, solver)  # not kept when larger than the whole budget
        return solver

    def delete(self, shape_id: str) -> bool:
        """Drop the shape's solvers; whether there were any."""
        return any([self._lru.pop((shape_id, m)) is not None for m in CLASSICAL_METHODS])

    def clear(self) -> None:
        self._lru.clear()

    def __len__(self) -> int:
        return len(self._lru)
