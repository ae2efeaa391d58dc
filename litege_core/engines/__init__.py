"""Reference geodesic engines behind one interface (ground truth and baselines).

::

    engine = make_engine(shape, "exact")            # or ExactGeodesicEngine(shape)
    rows = engine.distances([0, 17]).distances      # (2, N) float64, shape units
    once = compute_distances(shape, [0], method="heat", t_coef=1.0)

========================  ===============  =====================================================
method                    shapes           what
========================  ===============  =====================================================
``"exact"``               mesh             exact polyhedral geodesic (MMP; pygeodesic or gdist)
``"heat"``                mesh             heat method, potpourri3d (approximate, fast)
``"pointcloud_heat"``     mesh or cloud    point-cloud heat method, potpourri3d
``"knn_graph"``           mesh or cloud    Dijkstra on the symmetric k-NN graph (k=8)
``"edge_dijkstra"``       mesh             Dijkstra along mesh edges (upper bound of exact)
``"euclidean"``           mesh or cloud    straight-line distance (lower bound)
========================  ===============  =====================================================

Every engine returns a :class:`GeodesicResult` with ``(S, N)`` rows, ``+inf`` where a source
cannot reach. Exact distances between arbitrary surface points:
:func:`surface_point_distances`.

The service's and the CLI's ``method`` switch (``heat``, ``exact``, ``graph``; ``learned`` is
the Predictor's) is :class:`ClassicalSolver`: indices or xyz queries, ``(S, T)`` float32
distances and surface paths, with the engine that ran::

    solver = ClassicalSolver(shape, "heat")     # "exact" is bounded by max_exact_vertices
    d = solver.distances(sources, targets)      # (S, T) float32, shape units
    path = solver.path(source, target)          # ClassicalPath (points (L, 3), engine, ...)
"""

from __future__ import annotations

from collections.abc import Mapping
from types import MappingProxyType
from typing import Any

from numpy.typing import ArrayLike

from litege_core.engines.base import (
    GeodesicEngine,
    GeodesicResult,
    MeshGeodesicEngine,
)
from litege_core.engines.exact import EXACT_BACKENDS, ExactGeodesicEngine
from litege_core.engines.graph import KnnGraphEngine
from litege_core.engines.heat import HeatGeodesicEngine, PointCloudHeatEngine
from litege_core.engines.reference import EdgeDijkstraEngine, EuclideanEngine
from litege_core.engines.solver import (
    CLASSICAL_METHODS,
    DEFAULT_MAX_EXACT_VERTICES,
    ClassicalPath,
    ClassicalSolver,
)
from litege_core.engines.surface_points import (
    RefinedMesh,
    SurfacePointDistances,
    insert_surface_points,
    surface_point_distances,
)
from litege_core.errors import InputError
from litege_core.shape import Shape

ENGINES: Mapping[str, type[GeodesicEngine]] = MappingProxyType(
    {
        engine.method: engine
        for engine in (
            ExactGeodesicEngine,
            HeatGeodesicEngine,
            PointCloudHeatEngine,
            KnnGraphEngine,
            EdgeDijkstraEngine,
            EuclideanEngine,
        )
    }
)


def make_engine(shape: Shape, method: str = "exact", **options: Any) -> GeodesicEngine:
    """Build the engine named ``method`` for ``shape`` (see the table in the module docstring).

    Args:
        shape: the mesh or point cloud.
        method: a key of :data:`ENGINES`.
        **options: engine options (``backend``, ``n_workers`` for exact; ``t_coef``,
            ``use_robust`` for heat; ``t_coef`` for pointcloud_heat; ``k`` for knn_graph).

    Raises:
        InputError: unknown method, unknown or bad option, or a shape the method cannot use.
    """
    try:
        engine_class = ENGINES[method]
    except (KeyError, TypeError):
        raise InputError(
            f"unknown geodesic method {method!r}; expected one of {sorted(ENGINES)}"
        ) from None
    try:
        return engine_class(shape, **options)
    except TypeError as exc:
        raise InputError(f"bad option for geodesic method {method!r}: {exc}") from exc


def compute_distances(
    shape: Shape, sources: ArrayLike, method: str = "exact", **options: Any
) -> GeodesicResult:
    """One-off: distances ``(S, N)`` from ``sources`` to all vertices/points of ``shape``.

    Builds the engine, answers, and drops it; keep an engine from :func:`make_engine` for
    repeated queries on the same shape.
    """
    return make_engine(shape, method, **options).distances(sources)


__all__ = [  # noqa: RUF022 - plain sorted() order, as test_engines_api checks
    "CLASSICAL_METHODS",
    "ClassicalPath",
    "ClassicalSolver",
    "DEFAULT_MAX_EXACT_VERTICES",
    "ENGINES",
    "EXACT_BACKENDS",
    "EdgeDijkstraEngine",
    "EuclideanEngine",
    "ExactGeodesicEngine",
    "GeodesicEngine",
    "GeodesicResult",
    "HeatGeodesicEngine",
    "KnnGraphEngine",
    "MeshGeodesicEngine",
    "PointCloudHeatEngine",
    "RefinedMesh",
    "SurfacePointDistances",
    "compute_distances",
    "insert_surface_points",
    "make_engine",
    "surface_point_distances",
]
