"""Isotropic remeshing of a half body (boundary on ``x = 0``) and mirroring to a whole body.

The remesher is the incremental scheme of Botsch and Kobbelt (2004): split edges longer than
4/3·e, collapse edges shorter than 4/5·e, flip edges towards valence 6, relax tangentially and
project back onto the implicit surface. It works on the half ``x ≥ 0`` of a closed body whose
cut boundary lies on the symmetry plane; boundary vertices stay on the plane (they slide along
the cut curve) and no interior edge may join two boundary vertices, so mirroring the half and
gluing it along the boundary gives a closed, manifold, exactly symmetric mesh.

Topology edits are sequential Python (a half body has ~2K vertices, so a pass is milliseconds
to a second); relaxation and projection are vectorized.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray
from scipy import sparse

from litege_core.errors import ComputationError

ProjectFn = Callable[[NDArray], NDArray]
NormalFn = Callable[[NDArray], NDArray]


class _HalfMesh:
    """Mutable triangle mesh with vertex→face incidence, for local edits."""

    def __init__(self, vertices: NDArray, faces: NDArray, boundary: NDArray) -> None:
        capacity = 4 * len(vertices) + 16
        self.P = np.zeros((capacity, 3))
        self.P[: len(vertices)] = vertices
        self.n = len(vertices)
        self.faces: list[list[int] | None] = [list(f) for f in faces.tolist()]
        self.vf: list[set[int]] = [set() for _ in range(capacity)]
        for fi, face in enumerate(faces.tolist()):
            for v in face:
                self.vf[v].add(fi)
        self.bnd = np.zeros(capacity, dtype=bool)
        self.bnd[: len(vertices)] = boundary

    # -- queries ---------------------------------------------------------------------------
    def edge_faces(self, a: int, b: int) -> set[int]:
        return self.vf[a] & self.vf[b]

    def neighbors(self, a: int) -> set[int]:
        out: set[int] = set()
        for fi in self.vf[a]:
            out.update(self.faces[fi])  # type: ignore[arg-type]
        out.discard(a)
        return out

    def alive_faces(self) -> NDArray:
        return np.array([f for f in self.faces if f is not None], dtype=np.int64).reshape(-1, 3)

    def edges(self) -> NDArray:
        f = self.alive_faces()
        e = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
        return np.unique(e, axis=0)

    def valence_deviation(self, v: int, delta: int) -> int:
        target = 4 if self.bnd[v] else 6
        valence = len(self.vf[v]) + (1 if self.bnd[v] else 0) + delta
        return abs(valence - target)

    def _normal(self, face: list[int]) -> NDArray:
        p = self.P[face]
        return _cross((p[1] - p[0])[None], (p[2] - p[0])[None])[0]

    # -- edits -----------------------------------------------------------------------------
    def _grow(self) -> None:
        extra = len(self.P)
        self.P = np.concatenate([self.P, np.zeros((extra, 3))])
        self.bnd = np.concatenate([self.bnd, np.zeros(extra, dtype=bool)])
        self.vf.extend(set() for _ in range(extra))

    def split(self, a: int, b: int) -> None:
        shared = self.edge_faces(a, b)
        if self.n == len(self.P):
            self._grow()
        m = self.n
        self.n += 1
        self.P[m] = 0.5 * (self.P[a] + self.P[b])
        self.bnd[m] = bool(self.bnd[a] and self.bnd[b] and len(shared) == 1)
        for fi in shared:
            face = self.faces[fi]
            assert face is not None
            r = next(i for i in range(3) if face[(i + 2) % 3] not in (a, b))
            u, v, c = face[r], face[(r + 1) % 3], face[(r + 2) % 3]
            self.faces[fi] = [u, m, c]
            new = len(self.faces)
            self.faces.append([m, v, c])
            self.vf[v].discard(fi)
            self.vf[v].add(new)
            self.vf[c].add(new)
            self.vf[m].update((fi, new))

    def try_collapse(self, a: int, b: int, e_max: float) -> bool:
        """Collapse edge ``(a, b)`` if that keeps the mesh valid and no edge gets too long."""
        shared = self.edge_faces(a, b)
        if not shared:
            return False
        ba, bb = bool(self.bnd[a]), bool(self.bnd[b])
        if ba and bb:
            if len(shared) != 1:
                return False
            keep, drop, target = a, b, 0.5 * (self.P[a] + self.P[b])
        elif ba:
            keep, drop, target = a, b, self.P[a].copy()
        elif bb:
            keep, drop, target = b, a, self.P[b].copy()
        else:
            keep, drop, target = a, b, 0.5 * (self.P[a] + self.P[b])
        opposite: set[int] = set()
        for fi in shared:
            opposite.update(self.faces[fi] or ())
        opposite -= {a, b}
        na, nb = self.neighbors(a), self.neighbors(b)
        if (na & nb) != opposite:
            return False
        for c in opposite:
            if len(self.neighbors(c)) <= (2 if self.bnd[c] else 3):
                return False
        ring = (na | nb) - {a, b}
        if len(ring) < 3:
            return False
        if np.any(np.linalg.norm(self.P[list(ring)] - target, axis=1) > e_max):
            return False
        survivors = sorted((self.vf[a] | self.vf[b]) - shared)
        old_faces = np.array([self.faces[fi] for fi in survivors], dtype=np.int64)
        replaced = np.where(old_faces == drop, keep, old_faces)
        if self.bnd[replaced].all(axis=1).any():
            return False
        old_p = self.P[old_faces]
        new_p = self.P[replaced]
        new_p[replaced == keep] = target
        n_old = _cross(old_p[:, 1] - old_p[:, 0], old_p[:, 2] - old_p[:, 0])
        n_new = _cross(new_p[:, 1] - new_p[:, 0], new_p[:, 2] - new_p[:, 0])
        len_old = np.linalg.norm(n_old, axis=1)
        len_new = np.linalg.norm(n_new, axis=1)
        dots = np.einsum("ij,ij->i", n_old, n_new)
        if np.any(len_new < 1e-14) or np.any(dots < 0.5 * len_old * len_new):
            return False
        new_faces = dict(zip(survivors, replaced.tolist(), strict=True))
        if self.bnd[keep]:
            # Every edge from the kept boundary vertex to a boundary vertex must stay a
            # boundary edge (one face), or mirroring would make it non-manifold.
            for c in ring:
                if self.bnd[c]:
                    count = sum(1 for f in new_faces.values() if c in f)
                    if count > 1:
                        return False
        for fi in shared:
            for v in self.faces[fi]:  # type: ignore[union-attr]
                self.vf[v].discard(fi)
            self.faces[fi] = None
        for fi, new_face in new_faces.items():
            self.faces[fi] = new_face
            self.vf[keep].add(fi)
        self.vf[drop] = set()
        self.P[keep] = target
        return True

    def _flip_candidate(self, a: int, b: int) -> tuple | None:
        """``(f1, f2, face1, face2, c, d)`` for a flippable interior edge ``(a, b)``, with
        ``face1`` holding the directed edge a→b and ``c``, ``d`` the opposite corners; ``None``
        when the edge is on a boundary or the flip would create a duplicate edge."""
        shared = self.edge_faces(a, b)
        if len(shared) != 2:
            return None
        f1, f2 = sorted(shared)
        face1, face2 = self.faces[f1], self.faces[f2]
        assert face1 is not None and face2 is not None
        r = face1.index(a)
        if face1[(r + 1) % 3] != b:
            f1, f2, face1, face2 = f2, f1, face2, face1
        c = next(v for v in face1 if v not in (a, b))
        d = next(v for v in face2 if v not in (a, b))
        if c == d or (self.bnd[c] and self.bnd[d]) or d in self.neighbors(c):
            return None
        return f1, f2, face1, face2, c, d

    def _apply_flip(self, f1: int, f2: int, a: int, b: int, c: int, d: int) -> None:
        """Flip edge (a, b): faces ``f1 = (a, b, c)``, ``f2 = (b, a, d)`` become
        ``(c, a, d)``, ``(d, b, c)``."""
        self.faces[f1], self.faces[f2] = [c, a, d], [d, b, c]
        self.vf[a].discard(f2)
        self.vf[b].discard(f1)
        self.vf[c].add(f2)
        self.vf[d].add(f1)

    def try_flip(self, a: int, b: int) -> bool:
        """Flip interior edge ``(a, b)`` if that lowers the valence deviation."""
        candidate = self._flip_candidate(a, b)
        if candidate is None:
            return False
        f1, f2, face1, face2, c, d = candidate
        before = sum(self.valence_deviation(v, 0) for v in (a, b, c, d))
        after = (
            self.valence_deviation(a, -1)
            + self.valence_deviation(b, -1)
            + self.valence_deviation(c, 1)
            + self.valence_deviation(d, 1)
        )
        if after >= before:
            return False
        new1, new2 = [c, a, d], [d, b, c]
        n_ref = self._normal(face1) + self._normal(face2)
        n1, n2 = self._normal(new1), self._normal(new2)
        for n in (n1, n2):
            if float(n @ n_ref) <= 0.2 * np.linalg.norm(n) * np.linalg.norm(n_ref):
                return False
        if float(n1 @ n2) <= 0.2 * np.linalg.norm(n1) * np.linalg.norm(n2):
            return False
        self._apply_flip(f1, f2, a, b, c, d)
        return True

    def try_quality_flip(self, a: int, b: int, gain_deg: float = 5.0) -> bool:
        """Flip interior edge ``(a, b)`` if that raises the smallest angle of its two faces."""
        candidate = self._flip_candidate(a, b)
        if candidate is None:
            return False
        f1, f2, face1, face2, c, d = candidate
        new1, new2 = [c, a, d], [d, b, c]
        before = min(_min_angle(self.P[face1]), _min_angle(self.P[face2]))
        after = min(_min_angle(self.P[new1]), _min_angle(self.P[new2]))
        if after < before + gain_deg:
            return False
        n_ref = self._normal(face1) + self._normal(face2)
        for n in (self._normal(new1), self._normal(new2)):
            if float(n @ n_ref) <= 0.5 * np.linalg.norm(n) * np.linalg.norm(n_ref):
                return False
        self._apply_flip(f1, f2, a, b, c, d)
        return True

    def compact(self) -> tuple[NDArray, NDArray, NDArray]:
        faces = self.alive_faces()
        used = np.unique(faces)
        remap = -np.ones(self.n, dtype=np.int64)
        remap[used] = np.arange(len(used))
        return self.P[used].copy(), remap[faces], self.bnd[used].copy()


def remesh_half(
    vertices: NDArray,
    faces: NDArray,
    boundary: NDArray,
    edge_length: float,
    project: ProjectFn,
    normals: NormalFn,
    iterations: int = 12,
) -> tuple[NDArray, NDArray, NDArray]:
    """Isotropically remesh a half body whose boundary lies on the plane ``x = 0``.

    Args:
        vertices: ``(V, 3)`` float64; ``faces``: ``(F, 3)`` int64 oriented triangles.
        boundary: ``(V,)`` bool, the vertices on the cut (``x == 0``).
        edge_length: target edge length e (template units).
        project: maps ``(N, 3)`` points onto the surface.
        normals: ``(N, 3)`` unit outward normals of the surface at points near it.
        iterations: split/collapse/flip/relax rounds (the last third only flips and relaxes).

    Returns:
        ``vertices``, ``faces`` and boundary mask of the remeshed half.
    """
    mesh = _HalfMesh(vertices, faces, boundary)
    e_max, e_min = 4.0 / 3.0 * edge_length, 4.0 / 5.0 * edge_length
    for it in range(iterations):
        topology = it < (2 * iterations) // 3
        if topology:
            _split_pass(mesh, e_max)
            _collapse_pass(mesh, e_min, e_max)
        _flip_pass(mesh)
        _relax(mesh, project, normals)
    for _ in range(3):
        _cleanup_pass(mesh, edge_length)
        _relax(mesh, project, normals)
    v, f, b = mesh.compact()
    _check_half(f, b)
    return v, f, b


def _cross(u: NDArray, v: NDArray) -> NDArray:
    """Row-wise cross product of ``(N, 3)`` arrays (faster than ``np.cross`` for small N)."""
    return np.stack(
        [
            u[:, 1] * v[:, 2] - u[:, 2] * v[:, 1],
            u[:, 2] * v[:, 0] - u[:, 0] * v[:, 2],
            u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0],
        ],
        axis=1,
    )


def _min_angle(p: NDArray) -> float:
    """Smallest interior angle (degrees) of the triangle with corners ``p (3, 3)``."""
    out = 180.0
    for i in range(3):
        u = p[(i + 1) % 3] - p[i]
        w = p[(i + 2) % 3] - p[i]
        cos = float(u @ w) / max(float(np.linalg.norm(u) * np.linalg.norm(w)), 1e-300)
        out = min(out, float(np.degrees(np.arccos(min(1.0, max(-1.0, cos))))))
    return out


def _cleanup_pass(mesh: _HalfMesh, edge_length: float, min_angle: float = 25.0) -> None:
    """Fix the few bad triangles left: collapse their short edge, or flip their long one."""
    faces = mesh.alive_faces()
    p = mesh.P[faces]
    lengths = np.stack([np.linalg.norm(p[:, (i + 1) % 3] - p[:, i], axis=1) for i in range(3)], 1)
    cos = []
    for i in range(3):
        u = p[:, (i + 1) % 3] - p[:, i]
        w = p[:, (i + 2) % 3] - p[:, i]
        cos.append(
            np.einsum("ij,ij->i", u, w) / (np.linalg.norm(u, axis=1) * np.linalg.norm(w, axis=1))
        )
    worst = np.degrees(np.arccos(np.clip(np.stack(cos, 1), -1, 1))).min(axis=1)
    for k in np.argsort(worst)[: int(np.sum(worst < min_angle))].tolist():
        face = faces[k].tolist()
        if (
            not all(mesh.vf[v] for v in face)
            or not mesh.vf[face[0]] & mesh.vf[face[1]] & mesh.vf[face[2]]
        ):
            continue
        order = np.argsort(lengths[k])
        shortest, longest = int(order[0]), int(order[2])
        a, b = face[shortest], face[(shortest + 1) % 3]
        if lengths[k, shortest] < 0.6 * edge_length and mesh.try_collapse(a, b, 2.0 * edge_length):
            continue
        a, b = face[longest], face[(longest + 1) % 3]
        mesh.try_quality_flip(a, b)


def _lengths(mesh: _HalfMesh, edges: NDArray) -> NDArray:
    return np.linalg.norm(mesh.P[edges[:, 0]] - mesh.P[edges[:, 1]], axis=1)


def _split_pass(mesh: _HalfMesh, e_max: float) -> None:
    for _ in range(8):
        edges = mesh.edges()
        lengths = _lengths(mesh, edges)
        long = np.argsort(-lengths)[: int(np.sum(lengths > e_max))]
        if len(long) == 0:
            return
        for a, b in edges[long].tolist():
            if np.linalg.norm(mesh.P[a] - mesh.P[b]) > e_max and mesh.edge_faces(a, b):
                mesh.split(a, b)


def _collapse_pass(mesh: _HalfMesh, e_min: float, e_max: float) -> None:
    for _ in range(4):
        edges = mesh.edges()
        lengths = _lengths(mesh, edges)
        short = np.argsort(lengths)[: int(np.sum(lengths < e_min))]
        done = 0
        for a, b in edges[short].tolist():
            if (
                mesh.vf[a]
                and mesh.vf[b]
                and np.linalg.norm(mesh.P[a] - mesh.P[b]) < e_min
                and mesh.try_collapse(a, b, e_max)
            ):
                done += 1
        if done == 0:
            return


def _flip_pass(mesh: _HalfMesh) -> None:
    for a, b in mesh.edges().tolist():
        mesh.try_flip(a, b)


def _relax(mesh: _HalfMesh, project: ProjectFn, normals: NormalFn) -> None:
    faces = mesh.alive_faces()
    n = mesh.n
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    adj = sparse.coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n)).tocsr()
    adj = ((adj + adj.T) > 0).astype(np.float64)
    # Boundary edges: those with exactly one incident face; count faces per undirected edge.
    und = np.sort(e, axis=1)
    keys, counts = np.unique(und, axis=0, return_counts=True)
    bedges = keys[counts == 1]
    badj = sparse.coo_matrix(
        (np.ones(2 * len(bedges)), (bedges.ravel(), bedges[:, ::-1].ravel())), shape=(n, n)
    ).tocsr()
    alive = np.asarray(adj.sum(axis=1)).ravel() > 0
    P = mesh.P[:n]
    deg = np.maximum(np.asarray(adj.sum(axis=1)).ravel(), 1.0)
    centroid = (adj @ P) / deg[:, None]
    bdeg = np.maximum(np.asarray(badj.sum(axis=1)).ravel(), 1.0)
    bcentroid = (badj @ P) / bdeg[:, None]
    interior = alive & ~mesh.bnd[:n]
    on_cut = alive & mesh.bnd[:n]
    new = P.copy()
    nrm = normals(P[interior])
    step = centroid[interior] - P[interior]
    step -= np.einsum("ij,ij->i", step, nrm)[:, None] * nrm
    new[interior] = P[interior] + step
    new[on_cut] = bcentroid[on_cut]
    new[alive] = project(new[alive])
    new[on_cut, 0] = 0.0
    mesh.P[:n] = new


def _check_half(faces: NDArray, boundary: NDArray) -> None:
    e = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    keys, counts = np.unique(e, axis=0, return_counts=True)
    if counts.max() > 2:
        raise ComputationError("remeshed half is not manifold")
    open_edges = keys[counts == 1]
    if not np.all(boundary[open_edges]):
        raise ComputationError("remeshed half has an open edge off the symmetry plane")
    inner = keys[counts == 2]
    if np.any(boundary[inner[:, 0]] & boundary[inner[:, 1]]):
        raise ComputationError("an interior edge joins two symmetry-plane vertices")


def mirror_half(
    vertices: NDArray, faces: NDArray, boundary: NDArray
) -> tuple[NDArray, NDArray, NDArray]:
    """Glue a half body and its mirror image along the boundary on ``x = 0``.

    Returns:
        ``vertices (V, 3)``, ``faces (F, 3)`` and the symmetry map ``(V,)`` int64 with
        ``vertices[sym] == vertices * (-1, 1, 1)`` exactly. Vertices are ordered: the
        half's vertices first (same order), then the mirrored copies of its interior ones.
    """
    n = len(vertices)
    interior = np.flatnonzero(~boundary)
    mirror_index = np.arange(n)
    mirror_index[interior] = n + np.arange(len(interior))
    mirrored = vertices[interior] * np.array([-1.0, 1.0, 1.0])
    all_vertices = np.concatenate([vertices, mirrored])
    all_vertices[np.flatnonzero(boundary), 0] = 0.0
    mirror_faces = mirror_index[faces][:, ::-1]
    sym = np.concatenate([mirror_index, interior])
    return all_vertices, np.concatenate([faces, mirror_faces]), sym


__all__ = [
    "NormalFn",
    "ProjectFn",
    "mirror_half",
    "remesh_half",
]
