"""Mesh clean-up shared by the mesh geodesic engines.

The C++ solvers behind the engines are fragile on some inputs that :mod:`litege_core.validate`
accepts (measured with pygeodesic 0.1.11, tvb-gdist 2.9.2 and potpourri3d 1.4.0):

* a face with a repeated corner (``[1, 1, 3]``) makes both exact backends **segfault** and
  the heat method raise a non-finite-matrix error;
* an edge shared by more than two faces (a non-manifold edge, including the one produced by a
  duplicated face next to a neighbour) makes both exact backends **segfault**;
* a duplicated face silently changes the heat method's Laplacian (20 duplicated faces on a
  642-vertex unit icosphere move distances by up to 0.022);
* an unreferenced vertex makes pygeodesic refuse the mesh (it prints and returns ``None``);
* a disconnected mesh gives finite garbage values with the heat method on the components that
  do not hold the source;
* a mesh stored with its seams split (a triangle soup, an OBJ split along its UV seams) is one
  component per piece to every solver.

:class:`MeshTopology` is computed once per engine: it welds seams
(:func:`~litege_core.seams.seam_welds`), drops faces with a repeated corner and duplicated faces
(same corner set, first one kept), renumbers the referenced vertices compactly, lists
non-manifold edges and labels connected components. Engines run on the compact mesh and scatter
the rows back with :meth:`MeshTopology.scatter_rows`, which puts ``+inf`` on every vertex the
source cannot reach; a seam copy takes its first copy's values
(:meth:`~litege_core.engines.base.MeshGeodesicEngine._solved_rows`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray
from scipy.sparse.csgraph import connected_components

from litege_core.arrays import frozen
from litege_core.seams import seam_welds, unique_edges


@dataclass(frozen=True, eq=False)
class MeshTopology:
    """A triangle mesh prepared for the C++ geodesic solvers.

    Attributes:
        vertices: ``(M, 3)`` float64, the referenced vertices in original order.
        faces: ``(F', 3)`` int64 into ``vertices``: faces without repeated corners,
            duplicates removed, original order kept.
        to_original: ``(M,)`` int64, original index of each compact vertex.
        to_compact: ``(N,)`` int64, compact index of each original vertex, ``-1`` when no
            kept face references it; a seam copy (:func:`~litege_core.seams.seam_welds`)
            shares its first copy's.
        component: ``(N,)`` int64 connected-component label of each original vertex (an
            unreferenced vertex is a component of its own).
        edges: ``(E, 2)`` int64 undirected edges in original indices (of welded faces).
        nonmanifold_edges: ``(K, 2)`` int64 edges with more than two incident faces.
        n_dropped_faces: faces removed (repeated corner or duplicate).
        welded: ``(C,)`` int64 seam copies (:func:`~litege_core.seams.seam_welds`), each at
            the position of the earlier vertex ``welded_to`` ``(C,)`` names; faces use that
            one instead.

    All arrays are read-only.
    """

    vertices: NDArray
    faces: NDArray
    to_original: NDArray
    to_compact: NDArray
    component: NDArray
    edges: NDArray
    nonmanifold_edges: NDArray
    n_dropped_faces: int
    welded: NDArray
    welded_to: NDArray

    @classmethod
    def from_arrays(cls, vertices: NDArray, faces: NDArray) -> MeshTopology:
        """Clean ``faces`` of the ``(N, 3)`` mesh ``vertices`` (see the module docstring)."""
        n = int(vertices.shape[0])
        weld = seam_welds(np.asarray(vertices, np.float64), np.asarray(faces, dtype=np.int64))
        welded = np.flatnonzero(weld != np.arange(n))
        faces = weld[np.asarray(faces, dtype=np.int64)]  # seam copies: their first copy
        distinct = (
            (faces[:, 0] != faces[:, 1])
            & (faces[:, 1] != faces[:, 2])
            & (faces[:, 2] != faces[:, 0])
        )
        kept = faces[distinct]
        _, first = np.unique(np.sort(kept, axis=1), axis=0, return_index=True)
        kept = kept[np.sort(first)]
        n_dropped = int(faces.shape[0] - kept.shape[0])

        used = np.zeros(n, dtype=bool)
        used[kept.ravel()] = True
        to_original = np.flatnonzero(used).astype(np.int64)
        to_compact = np.full(n, -1, dtype=np.int64)
        to_compact[to_original] = np.arange(to_original.size, dtype=np.int64)
        to_compact[welded] = to_compact[weld[welded]]

        edges, counts = unique_edges(kept)  # kept is non-empty: a validated mesh has area > 0
        adjacency = sp.coo_matrix(
            (np.ones(edges.shape[0]), (edges[:, 0], edges[:, 1])), shape=(n, n)
        )
        _, labels = connected_components(adjacency, directed=False)
        labels[welded] = labels[weld[welded]]
        return cls(
            vertices=frozen(vertices[to_original]),
            faces=frozen(to_compact[kept]),
            to_original=frozen(to_original),
            to_compact=frozen(to_compact),
            component=frozen(labels.astype(np.int64)),
            edges=frozen(edges),
            nonmanifold_edges=frozen(edges[counts > 2]),
            n_dropped_faces=n_dropped,
            welded=frozen(welded),
            welded_to=frozen(weld[welded]),
        )

    @property
    def welds(self) -> NDArray:
        """``(N,)`` int64: each original vertex's welded index (its first copy for a seam
        copy, else itself)."""
        welds = np.arange(self.n_vertices, dtype=np.int64)
        welds[self.welded] = self.welded_to
        return welds

    @property
    def n_vertices(self) -> int:
        """Number of original vertices ``N``."""
        return int(self.to_compact.shape[0])

    def scatter_rows(self, sources: NDArray, compact_rows: dict[int, NDArray]) -> NDArray:
        """Assemble full ``(S, N)`` rows from rows computed on the compact mesh.

        Args:
            sources: ``(S,)`` int64 original source indices.
            compact_rows: compact source index → ``(M,)`` float64 distances on the compact
                mesh, for every referenced source.

        Returns:
            ``(S, N)`` float64: ``+inf`` wherever the source's connected component does not
            reach (unreferenced vertices included), ``0`` at the source itself.
        """
        rows = np.full((sources.size, self.n_vertices), np.inf)
        for i, source in enumerate(sources.tolist()):
            compact = int(self.to_compact[source])
            if compact >= 0:
                rows[i, self.to_original] = compact_rows[compact]
        rows[self.component[None, :] != self.component[sources][:, None]] = np.inf
        rows[np.arange(sources.size), sources] = 0.0
        return rows
