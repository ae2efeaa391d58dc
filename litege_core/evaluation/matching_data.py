"""Pair sets of the matching evaluation: shapes, queries, ground truth and exact geodesic rows.

Every evaluation shape is an :class:`EvalShape`: the input the methods see (a mesh or a point
cloud, randomly rotated), its *anchors* (one candidate point per anchor id; an anchor id means
the same body point on every shape of a set) and a lazily computed, memoized table of exact
geodesic rows on the shape scaled to unit area. A :class:`MatchPair` takes the query anchors
on X and their ground truth on Y; the error of a match is ``Y.rows(truth)[predicted]``.

**Synthetic pairs** (:func:`synthetic_pairs`): held-out shapes of the test split (seeds
``SPLIT_SEED_OFFSETS["test"] + k``, family ``families[k % n]``), ordered pairs of *different*
families. All shapes of a category share the template triangulation, so template vertex ``i``
is the same body point on every shape. The anchors are ``Q`` template vertices drawn at random
and closed under the template's exact left-right symmetry (so the mirrored ground truth of
every anchor is another anchor and costs no extra geodesic row). Settings, each applied to
both shapes of a pair:

===============  ===================================================  =======================
setting          input                                                geodesic rows on
===============  ===================================================  =======================
``template``     the template-topology mesh (≈3.9K vertices)          the mesh, exact
``remesh5k``     isotropic remesh, ≈5K vertices (pymeshlab)           the intact mesh (below)
``aniso10k``     anisotropic remesh (3:1), ≈10K vertices (pymeshlab)  the intact mesh (below)
``broken40``     40 % of the faces removed at random, unreferenced    the intact mesh, exact
                 vertices dropped
``cloud8k``      8000 area-weighted surface samples                   the intact mesh (below)
``cloud500``     500 area-weighted surface samples                    the intact mesh (below)
===============  ===================================================  =======================

The anchor of template vertex ``i`` on a variant is the variant point nearest to vertex ``i``
with both located on the *rest template* (each variant point's surface location on the
template triangulation, :mod:`litege_core.variants`): an intrinsic identification that a pose
bringing two body parts into contact cannot confuse. It is vertex ``i`` itself where ``i`` is
a candidate (``template``; ``broken40`` unless all faces of ``i`` were removed).

Remeshed and point-cloud variants are measured on the intact (template-topology) mesh they
were made from, on which every variant point has a known location: one surface for every
setting, and exact rows on a ≈4K-vertex mesh cost a fraction of those on a 10K remesh. The
ground-truth points are inserted into the intact mesh as vertices
(:func:`~litege_core.engines.insert_surface_points`), exact rows are computed from them, and
the distance to any other variant point interpolates the rows at the point's triangle. Where
that value is below ``NEAR_FIELD_EDGES`` mean edge lengths (the source's own neighbourhood,
where linear interpolation of a distance cone overestimates) the Euclidean distance is used
instead. Against inserting every cloud point (exact everywhere) this differs by 0.00025 on
average (0.025 on the ×100 scale) and 0.013 at worst (measured on 500- and 8000-point clouds).

**Real pairs** (from ``../shared/eval-data``, read at run time only — research-only licences;
:func:`eval_data_pairs` returns nothing when the folder is absent):

* ``tosca``: TOSCA ``tosca_5k`` poses within one animal class; ``corres/NAME.vts`` maps row
  ``k`` to a vertex (1-based) of every shape of the class; anchors are ``Q`` random rows.
  Mirrored ground truth from ``NAME.sym.vts`` where present; otherwise *derived* from the
  class's rest pose ``CLASS0`` (:func:`derived_mirror_rows`: TOSCA's rest poses are mirror
  symmetric across the plane ``x = mean x`` of their file frame to within 0.2 mean edge
  lengths; row ``k``'s mirror is the row whose rest-pose vertex is nearest to the reflection
  of row ``k``'s), carried to every pose of the class by ``corres``. No mirror (flip rate "—")
  when the rest pose is missing or not symmetric within ``SYMMETRY_TOLERANCE`` edges.
* ``tosca-landmarks``: the original high-resolution TOSCA ``cat0``, ``dog0``, ``horse0``,
  ``wolf0`` with 21 landmarks of the same meaning in every class (cross-species, non-isometric);
  the mirrored landmark comes from ``CLASS.sym.info`` (pairs swapped, the rest self-symmetric).
* ``faust``: the 20 remeshed FAUST test humans (``faust_5k``), dense ``corres/NAME.vts``.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from itertools import permutations
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from litege_core.errors import InputError
from litege_core.shape import Shape
from litege_core.validate import triangle_areas

if TYPE_CHECKING:
    from litege_core.engines import GeodesicEngine
from litege_core.variants import SurfaceLocation, random_rotation, rotate

SYNTHETIC_SETTINGS = ("template", "remesh5k", "aniso10k", "broken40", "cloud8k", "cloud500")
REMESH_SETTINGS = ("remesh5k", "aniso10k")
REAL_SETS = ("tosca", "tosca-landmarks", "faust")
#: Category of the shapes of each real set (which matching model answers them).
REAL_CATEGORY = {"tosca": "quadruped", "tosca-landmarks": "quadruped", "faust": "biped"}
NEAR_FIELD_EDGES = 3.0
SYMMETRY_TOLERANCE = 0.5
"""Mean distance (in mean edge lengths) between a rest pose's reflected vertices and the pose
above which :func:`derived_mirror_rows` declines to derive a mirror map."""
BROKEN_FRACTION = 0.4
TOSCA_CLASSES = ("cat", "dog", "horse", "wolf")
_SETTING_CODE = {name: i for i, name in enumerate((*SYNTHETIC_SETTINGS, *REAL_SETS))}


def unit_area_scale(vertices: NDArray, faces: NDArray) -> float:
    """``1 / √area``: multiplies lengths of the mesh into unit-area units."""
    return float(1.0 / np.sqrt(triangle_areas(vertices, faces).sum()))


def _rng(seed: int, *keys: int) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence([int(seed), *map(int, keys)]))


class ExactRows:
    """Memoized exact rows from vertices of one mesh to all its vertices, in unit-area units."""

    def __init__(self, vertices: NDArray, faces: NDArray, workers: int = 1) -> None:
        self.vertices = np.asarray(vertices, dtype=np.float64)
        self.faces = np.asarray(faces, dtype=np.int64)
        self.scale = unit_area_scale(self.vertices, self.faces)
        self.workers = workers
        self._engine: GeodesicEngine | None = None
        self._memo: dict[int, NDArray] = {}

    def __call__(self, sources: NDArray) -> NDArray:
        sources = np.asarray(sources, dtype=np.int64)
        missing = np.unique([s for s in sources.tolist() if s not in self._memo])
        if missing.size:
            if self._engine is None:
                from litege_core.engines import make_engine

                mesh = Shape.from_arrays(self.vertices, self.faces)
                self._engine = make_engine(mesh, "exact", n_workers=self.workers)
            rows = self._engine.distances(missing).distances * self.scale
            self._memo.update(zip(missing.tolist(), rows, strict=True))
        return np.stack([self._memo[s] for s in sources.tolist()])


class SurfacePointRows:
    """Rows between points located on a mesh (a point cloud's samples), on that mesh.

    The requested sources are inserted into the mesh as vertices, exact rows run from them to
    every original vertex, and the value at each point interpolates its triangle's corners;
    below ``NEAR_FIELD_EDGES`` mean edges the Euclidean distance replaces it (module doc).
    """

    def __init__(
        self, vertices: NDArray, faces: NDArray, location: SurfaceLocation, workers: int = 1
    ) -> None:
        self.vertices = np.asarray(vertices, dtype=np.float64)
        self.faces = np.asarray(faces, dtype=np.int64)
        self.location = location
        self.scale = unit_area_scale(self.vertices, self.faces)
        self.points = location.points(self.vertices, self.faces)
        edges = self.vertices[self.faces] - self.vertices[np.roll(self.faces, 1, axis=1)]
        self.near_field = NEAR_FIELD_EDGES * float(np.linalg.norm(edges, axis=2).mean())
        self.workers = workers
        self._memo: dict[int, NDArray] = {}

    def __call__(self, sources: NDArray) -> NDArray:
        from litege_core.engines import insert_surface_points, make_engine

        sources = np.asarray(sources, dtype=np.int64)
        missing = np.unique([s for s in sources.tolist() if s not in self._memo])
        if missing.size:
            refined = insert_surface_points(
                self.vertices,
                self.faces,
                self.location.face_index[missing],
                self.location.barycentric[missing],
            )
            mesh = Shape.from_arrays(refined.vertices, refined.faces)
            engine = make_engine(mesh, "exact", n_workers=self.workers)
            to_vertices = engine.distances(refined.point_vertex).distances[:, : len(self.vertices)]
            corners = to_vertices[:, self.faces[self.location.face_index]]  # (S, P, 3)
            rows = np.einsum("spk,pk->sp", corners, self.location.barycentric)
            for source, row in zip(missing.tolist(), rows, strict=True):
                euclid = np.linalg.norm(self.points - self.points[source], axis=1)
                near = row < self.near_field
                row[near] = euclid[near]
                row[source] = 0.0
                self._memo[source] = row * self.scale
        return np.stack([self._memo[s] for s in sources.tolist()])


@dataclass(eq=False)
class EvalShape:
    """One evaluation shape.

    Attributes:
        name: readable id (``dog-2000001``, ``cat3``).
        shape: the input every method sees (already randomly rotated).
        anchors: ``(K,)`` candidate index of each anchor id of the set.
        rows: ``sources (S,) → (S, P)`` exact unit-area geodesics from candidate points to every
            candidate point (memoized; only called for shapes used as targets).
        mirror: ``(K,)`` candidate index of each anchor's mirrored ground truth, or ``None``.
        category: ``"quadruped"`` or ``"biped"``.
    """

    name: str
    shape: Shape
    anchors: NDArray
    rows: Callable[[NDArray], NDArray] = field(repr=False)
    mirror: NDArray | None = None
    category: str = "quadruped"


@dataclass(frozen=True, eq=False)
class MatchPair:
    """Queries on X with their ground truth on Y (candidate indices of each input)."""

    setting: str
    x: EvalShape
    y: EvalShape
    queries: NDArray
    truth: NDArray
    mirror: NDArray | None

    @property
    def name(self) -> str:
        return f"{self.x.name}→{self.y.name}"

    def errors(self, predicted: NDArray) -> tuple[NDArray, NDArray | None]:
        """Unit-area geodesic errors of ``predicted`` (candidates of Y) under the ground truth
        and under the mirrored ground truth (``None`` without one)."""
        return match_errors(self.y.rows, self.truth, predicted), (
            None if self.mirror is None else match_errors(self.y.rows, self.mirror, predicted)
        )


def match_errors(rows: Callable[[NDArray], NDArray], truth: NDArray, predicted: NDArray) -> NDArray:
    """``rows(truth)[k, predicted[k]]`` with one row per distinct ground-truth point."""
    truth = np.asarray(truth, dtype=np.int64)
    predicted = np.asarray(predicted, dtype=np.int64)
    unique, inverse = np.unique(truth, return_inverse=True)
    table = rows(unique)
    return table[inverse.reshape(-1), predicted].astype(np.float64)


# ----------------------------------------------------------------------------- synthetic


def template_anchors(category: str, n_anchors: int, seed: int) -> tuple[NDArray, NDArray]:
    """``n_anchors`` template vertices closed under left-right symmetry, and the anchor-id
    permutation of the mirror (``anchors[mirror[a]] == symmetry[anchors[a]]``)."""
    from litege_core.synth import template

    tmpl = template(category)
    symmetry = np.asarray(tmpl.symmetry, dtype=np.int64)
    order = _rng(seed, 7).permutation(symmetry.size)
    chosen: dict[int, None] = {}
    for v in order.tolist():
        if len(chosen) >= n_anchors:
            break
        if v in chosen:
            continue
        chosen[v] = None
        chosen[int(symmetry[v])] = None
    anchors = np.fromiter(chosen, dtype=np.int64)
    position = {v: a for a, v in enumerate(anchors.tolist())}
    mirror = np.array([position[int(symmetry[v])] for v in anchors.tolist()], dtype=np.int64)
    return anchors, mirror


def synthetic_pool(category: str, n_pairs: int, seed: int) -> tuple[list, list]:
    """Test-split shape keys ``(family, seed)`` and ``n_pairs`` ordered pairs of different
    families among them (the smallest pool that has enough pairs)."""
    from litege_core.datasets.spec import SPLIT_SEED_OFFSETS
    from litege_core.synth import families

    names = families(category)
    size = 2
    while True:
        keys = [(names[k % len(names)], SPLIT_SEED_OFFSETS["test"] + k) for k in range(size)]
        candidates = [(a, b) for a, b in permutations(range(size), 2) if keys[a][0] != keys[b][0]]
        if len(candidates) >= n_pairs:
            break
        size += 1
    chosen = _rng(seed, 11).choice(len(candidates), size=n_pairs, replace=False)
    pairs = [candidates[i] for i in sorted(chosen.tolist())]
    used = sorted({i for pair in pairs for i in pair})
    return [keys[i] for i in used], [(used.index(a), used.index(b)) for a, b in pairs]


def _nearest_candidates(rest_points: NDArray, rest_targets: NDArray) -> NDArray:
    return cKDTree(rest_points).query(rest_targets)[1].astype(np.int64)


def synthetic_shape(
    generated,
    setting: str,
    anchors: NDArray,
    anchor_mirror: NDArray,
    seed: int,
    index: int,
    intact_rows: ExactRows,
    rotate_input: bool = True,
    workers: int = 1,
) -> EvalShape:
    """The :class:`EvalShape` of ``setting`` for one generated shape (module doc)."""
    from litege_core.synth import template
    from litege_core.variants import anisotropic_remesh, isotropic_remesh, point_cloud

    tmpl = template(generated.category)
    vertices = np.asarray(generated.vertices, dtype=np.float64)
    faces = np.asarray(generated.faces, dtype=np.int64)
    code = _SETTING_CODE[setting]
    rows: Callable[[NDArray], NDArray]
    if setting == "template":
        points, point_faces, anchor_idx, rows = vertices, faces, anchors, intact_rows
    elif setting in REMESH_SETTINGS:
        remesh = isotropic_remesh if setting == "remesh5k" else anisotropic_remesh
        target = 5000 if setting == "remesh5k" else 10000
        variant = remesh(vertices, faces, target_vertices=target)
        points, point_faces = variant.vertices, variant.faces
        rest = variant.source_location.points(tmpl.vertices, faces)
        anchor_idx = _nearest_candidates(rest, tmpl.vertices[anchors])
        rows = SurfacePointRows(vertices, faces, variant.source_location, workers)
    elif setting == "broken40":
        from litege_core.variants import broken_mesh

        kept_faces = faces[broken_mesh(faces, BROKEN_FRACTION, _rng(seed, code, index))]
        kept = np.unique(kept_faces)  # original ids of the vertices still referenced
        new_index = np.full(len(vertices), -1, dtype=np.int64)
        new_index[kept] = np.arange(kept.size)
        points, point_faces = vertices[kept], new_index[kept_faces]
        anchor_idx = new_index[anchors]
        lost = anchor_idx < 0
        if lost.any():
            anchor_idx[lost] = _nearest_candidates(
                tmpl.vertices[kept], tmpl.vertices[anchors[lost]]
            )

        def rows(sources: NDArray) -> NDArray:
            return intact_rows(kept[np.asarray(sources, dtype=np.int64)])[:, kept]

    elif setting in ("cloud8k", "cloud500"):
        n_points = 8000 if setting == "cloud8k" else 500
        cloud = point_cloud(vertices, faces, n_points, _rng(seed, code, index))
        points, point_faces = cloud.points, None
        rest = cloud.source_location.points(tmpl.vertices, faces)
        anchor_idx = _nearest_candidates(rest, tmpl.vertices[anchors])
        rows = SurfacePointRows(vertices, faces, cloud.source_location, workers)
    else:
        raise InputError(f"unknown synthetic setting {setting!r}; expected {SYNTHETIC_SETTINGS}")
    if rotate_input:
        points = rotate(points, random_rotation(_rng(seed, code, index, 1)))
    shape = Shape.from_arrays(points, point_faces)
    return EvalShape(
        name=f"{generated.family}-{generated.seed}",
        shape=shape,
        anchors=np.asarray(anchor_idx, dtype=np.int64),
        rows=rows,
        mirror=np.asarray(anchor_idx, dtype=np.int64)[anchor_mirror],
        category=generated.category,
    )


class SyntheticPool:
    """Held-out shapes, their pairs and anchors, shared by every synthetic setting (the intact
    meshes' exact rows are computed once for ``template`` and ``broken40``)."""

    def __init__(
        self,
        category: str,
        n_pairs: int,
        n_queries: int,
        seed: int = 0,
        rotate_input: bool = True,
        workers: int = 1,
    ) -> None:
        from litege_core.synth import generate_shape

        self.seed, self.rotate_input, self.workers = seed, rotate_input, workers
        keys, self.index_pairs = synthetic_pool(category, n_pairs, seed)
        self.anchors, self.anchor_mirror = template_anchors(category, n_queries, seed)
        self.generated = [generate_shape(category, family, s) for family, s in keys]
        self.intact = [ExactRows(g.vertices, g.faces, workers) for g in self.generated]

    def pairs(self, setting: str) -> list[MatchPair]:
        """The pairs of one setting (variants built now; remeshing needs ``pymeshlab``)."""
        if setting not in SYNTHETIC_SETTINGS:
            raise InputError(f"unknown setting {setting!r}; expected one of {SYNTHETIC_SETTINGS}")
        shapes = [
            synthetic_shape(
                g,
                setting,
                self.anchors,
                self.anchor_mirror,
                self.seed,
                k,
                self.intact[k],
                self.rotate_input,
                self.workers,
            )
            for k, g in enumerate(self.generated)
        ]
        ids = np.arange(self.anchors.size)
        return [_anchor_pair(setting, shapes[a], shapes[b], ids) for a, b in self.index_pairs]


def synthetic_pairs(
    category: str,
    settings: Sequence[str],
    n_pairs: int,
    n_queries: int,
    seed: int = 0,
    rotate_input: bool = True,
    workers: int = 1,
) -> dict[str, list[MatchPair]]:
    """Held-out pairs of different families for each setting (see the module doc): the same
    shapes, pairs and anchor template vertices in every setting."""
    pool = SyntheticPool(category, n_pairs, n_queries, seed, rotate_input, workers)
    return {setting: pool.pairs(setting) for setting in settings}


def _anchor_pair(setting: str, x: EvalShape, y: EvalShape, ids: NDArray) -> MatchPair:
    return MatchPair(
        setting=setting,
        x=x,
        y=y,
        queries=x.anchors[ids],
        truth=y.anchors[ids],
        mirror=None if y.mirror is None else y.mirror[ids],
    )


# ----------------------------------------------------------------------------- real shapes


def read_vts(path: Path) -> NDArray:
    """A ``.vts`` correspondence file: one 1-based vertex id per line → 0-based ids."""
    values = np.loadtxt(path, dtype=np.int64, ndmin=1)
    return values.reshape(-1) - 1


def read_pid(path: Path) -> NDArray:
    """A TOSCA ``.pid`` landmark file: lines ``vid 0 0 0`` with 0-based ``vid``."""
    return np.loadtxt(path, dtype=np.int64, ndmin=2)[:, 0]


def read_sym_info(path: Path, n_landmarks: int) -> NDArray:
    """Landmark mirror permutation from a ``.sym.info`` file (pairs ``a b`` swap; landmarks
    listed alone, or not at all, map to themselves)."""
    mirror = np.arange(n_landmarks, dtype=np.int64)
    for line in path.read_text().splitlines():
        fields = line.split()
        if len(fields) == 2:
            a, b = int(fields[0]), int(fields[1])
            mirror[a], mirror[b] = b, a
    return mirror


def _load_real(path: Path, seed: int, code: int, index: int, rotate_input: bool, workers: int):
    from litege_core.io import load_shape

    loaded = load_shape(path)
    if loaded.faces is None:
        raise InputError(f"{path}: the real evaluation sets are meshes, got a point cloud")
    rows = ExactRows(loaded.vertices, loaded.faces, workers)
    vertices = loaded.vertices
    if rotate_input:
        vertices = rotate(vertices, random_rotation(_rng(seed, code, index, 1)))
    return Shape.from_arrays(vertices, loaded.faces), rows


def derived_mirror_rows(
    vertices: NDArray, faces: NDArray, rows: NDArray, tolerance: float = SYMMETRY_TOLERANCE
) -> NDArray | None:
    """Mirror of each row of a dense correspondence, from a mirror-symmetric rest pose.

    Args:
        vertices, faces: the rest pose in its file frame (symmetric across ``x = mean x``).
        rows: ``(K,)`` rest-pose vertex of each correspondence row.
        tolerance: largest accepted mean asymmetry, in mean edge lengths.

    Returns:
        ``(K,)`` the mirrored row of each row, or ``None`` when the pose is not symmetric.
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    edge = float(np.linalg.norm(vertices[faces] - vertices[np.roll(faces, 1, 1)], axis=2).mean())
    centre = vertices[:, 0].mean()

    def reflect(points: NDArray) -> NDArray:
        out = points.copy()
        out[:, 0] = 2.0 * centre - out[:, 0]
        return out

    asymmetry = cKDTree(vertices).query(reflect(vertices))[0].mean() / edge
    if not asymmetry <= tolerance:
        return None
    points = vertices[np.asarray(rows, dtype=np.int64)]
    return cKDTree(points).query(reflect(points))[1].astype(np.int64)


def _dense_pairs(
    setting: str,
    folder: Path,
    groups: dict[str, list[str]],
    n_pairs: int,
    n_queries: int,
    seed: int,
    rotate_input: bool,
    workers: int,
    category: str,
    rest: dict[str, str] | None = None,
) -> list[MatchPair]:
    """Ordered pairs within each group of a folder with dense ``corres/NAME.vts`` maps.

    ``rest`` names each group's rest pose, from which a mirror map is derived for members
    without a ``NAME.sym.vts`` (:func:`derived_mirror_rows`)."""
    code = _SETTING_CODE[setting]
    candidates = [
        (a, b) for members in groups.values() for a, b in permutations(sorted(members), 2)
    ]
    if not candidates:
        return []
    rng = _rng(seed, code, 3)
    chosen = rng.choice(len(candidates), size=min(n_pairs, len(candidates)), replace=False)
    pairs = [candidates[i] for i in sorted(chosen.tolist())]
    names = sorted({n for pair in pairs for n in pair})
    maps = {n: read_vts(folder / "corres" / f"{n}.vts") for n in names}
    n_rows = min(m.size for m in maps.values())
    ids = np.sort(rng.choice(n_rows, size=min(n_queries, n_rows), replace=False))
    group_of = {n: g for g, members in groups.items() for n in members}
    derived: dict[str, NDArray | None] = {}
    shapes = {}
    for index, name in enumerate(names):
        shape, rows = _load_real(folder / f"{name}.off", seed, code, index, rotate_input, workers)
        sym_path = folder / "corres" / f"{name}.sym.vts"
        mirror = read_vts(sym_path)[:n_rows] if sym_path.exists() else None
        group = group_of[name]
        if mirror is None and rest and group in rest:
            if group not in derived:
                derived[group] = _group_mirror(folder, rest[group], n_rows)
            row_mirror = derived[group]
            if row_mirror is not None:
                mirror = maps[name][:n_rows][row_mirror]
        shapes[name] = EvalShape(name, shape, maps[name][:n_rows], rows, mirror, category)
    return [_anchor_pair(setting, shapes[a], shapes[b], ids) for a, b in pairs]


def _group_mirror(folder: Path, rest_name: str, n_rows: int) -> NDArray | None:
    """Row mirror of a group from its rest pose's file (``None`` when absent or asymmetric)."""
    from litege_core.io import load_shape

    path, corres = folder / f"{rest_name}.off", folder / "corres" / f"{rest_name}.vts"
    if not (path.exists() and corres.exists()):
        return None
    loaded = load_shape(path)
    rows = read_vts(corres)[:n_rows]
    if rows.size < n_rows or loaded.faces is None:
        return None
    return derived_mirror_rows(loaded.vertices, loaded.faces, rows)


def tosca_pairs(
    root: Path, n_pairs: int, n_queries: int, seed: int = 0, rotate_input=True, workers=1
) -> list[MatchPair]:
    """TOSCA same-class pairs (``tosca_5k``), dense ground truth."""
    folder = Path(root) / "tosca_5k"
    groups: dict[str, list[str]] = {}
    for path in sorted(folder.glob("*.off")):
        if (folder / "corres" / f"{path.stem}.vts").exists():
            groups.setdefault(re.sub(r"\d+$", "", path.stem), []).append(path.stem)
    rest = {group: f"{group}0" for group in groups}
    return _dense_pairs(
        "tosca", folder, groups, n_pairs, n_queries, seed, rotate_input, workers, "quadruped", rest
    )


def faust_pairs(
    root: Path, n_pairs: int, n_queries: int, seed: int = 0, rotate_input=True, workers=1
) -> list[MatchPair]:
    """FAUST test humans (``faust_5k``), dense ground truth."""
    folder = Path(root) / "faust_5k"
    members = [
        p.stem
        for p in sorted(folder.glob("*.off"))
        if (folder / "corres" / f"{p.stem}.vts").exists()
    ]
    return _dense_pairs(
        "faust",
        folder,
        {"faust": members},
        n_pairs,
        n_queries,
        seed,
        rotate_input,
        workers,
        "biped",
    )


def tosca_landmark_pairs(
    root: Path, n_pairs: int, seed: int = 0, rotate_input=True, workers=1
) -> list[MatchPair]:
    """Cross-species TOSCA pairs (cat, dog, horse, wolf) on 21 shared landmarks."""
    folder = Path(root) / "tosca_landmarks"
    code = _SETTING_CODE["tosca-landmarks"]
    classes = [
        c
        for c in TOSCA_CLASSES
        if (folder / "meshes" / f"{c}0.off").exists() and (folder / "corrs" / f"{c}.pid").exists()
    ]
    candidates = list(permutations(classes, 2))
    if not candidates:
        return []
    chosen = _rng(seed, code, 3).choice(
        len(candidates), size=min(n_pairs, len(candidates)), replace=False
    )
    pairs = [candidates[i] for i in sorted(chosen.tolist())]
    shapes = {}
    for index, cls in enumerate(sorted({c for pair in pairs for c in pair})):
        shape, rows = _load_real(
            folder / "meshes" / f"{cls}0.off", seed, code, index, rotate_input, workers
        )
        landmarks = read_pid(folder / "corrs" / f"{cls}.pid")
        sym_path = folder / "corrs" / f"{cls}.sym.info"
        mirror = None
        if sym_path.exists():
            mirror = landmarks[read_sym_info(sym_path, landmarks.size)]
        shapes[cls] = EvalShape(f"{cls}0", shape, landmarks, rows, mirror, "quadruped")
    n_landmarks = min(s.anchors.size for s in shapes.values())
    ids = np.arange(n_landmarks)
    return [_anchor_pair("tosca-landmarks", shapes[a], shapes[b], ids) for a, b in pairs]


def eval_data_pairs(
    name: str,
    root: str | Path,
    n_pairs: int,
    n_queries: int,
    seed: int = 0,
    rotate_input: bool = True,
    workers: int = 1,
) -> list[MatchPair]:
    """Pairs of a real set, or ``[]`` when its folder is absent (a user's machine)."""
    root = Path(root)
    folder = {"tosca": "tosca_5k", "tosca-landmarks": "tosca_landmarks", "faust": "faust_5k"}
    if name not in folder:
        raise InputError(f"unknown real set {name!r}; expected one of {REAL_SETS}")
    if not (root / folder[name]).is_dir():
        return []
    if name == "tosca":
        return tosca_pairs(root, n_pairs, n_queries, seed, rotate_input, workers)
    if name == "faust":
        return faust_pairs(root, n_pairs, n_queries, seed, rotate_input, workers)
    return tosca_landmark_pairs(root, n_pairs, seed, rotate_input, workers)


__all__ = [
    "BROKEN_FRACTION",
    "NEAR_FIELD_EDGES",
    "REAL_CATEGORY",
    "REAL_SETS",
    "REMESH_SETTINGS",
    "SYMMETRY_TOLERANCE",
    "SYNTHETIC_SETTINGS",
    "TOSCA_CLASSES",
    "EvalShape",
    "ExactRows",
    "MatchPair",
    "SurfacePointRows",
    "SyntheticPool",
    "derived_mirror_rows",
    "eval_data_pairs",
    "faust_pairs",
    "match_errors",
    "read_pid",
    "read_sym_info",
    "read_vts",
    "synthetic_pairs",
    "synthetic_pool",
    "synthetic_shape",
    "template_anchors",
    "tosca_landmark_pairs",
    "tosca_pairs",
    "unit_area_scale",
]
