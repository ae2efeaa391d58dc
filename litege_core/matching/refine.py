"""ZoomOut refinement of LiteGE's matches on meshes (issue 15, step 5).

On near-isometric pairs (two poses of one animal) LiteGE's learned map is right at the scale of
body parts but coarse below it, while functional maps are precise once they start from a
globally right map. :func:`zoomout_refine` does the second starting from the first:

1. LiteGE matches ``n_samples`` farthest points of X on Y (the seed map);
2. the seed map gives a ``k_init × k_init`` functional map between the Laplace–Beltrami bases
   (least squares on the samples, pyFM's ``p2p_to_FM``);
3. ZoomOut (Melzi et al. 2019) grows it to ``n_eigen`` in steps of ``step`` on the farthest-point
   samples of both shapes;
4. the samples of X are mapped to the Y vertices nearest to them in the spectral embedding;
5. a smooth displacement of X is fitted to those matches, robustly
   (:mod:`litege_core.matching.deform`), then registered to Y's surface (non-rigid ICP,
   ``registration_rounds``), and each query maps to the Y vertex nearest its displaced
   position. The spectral map is right at the scale of parts but errs by a vertex or two
   independently at neighbouring points, and by a shared bias where two bodies differ in
   proportions (it is the most isometric map); the fit keeps the first and averages out the
   noise, the registration replaces the bias by the least-bent deformation onto Y
   (``smoothing=0`` skips both: each query maps by the spectral embedding).

Where LiteGE's map is wrong at the scale of the body (a real animal in a pose far from the
training poses), no refinement repairs it. ``refine="zoomout-hybrid"`` therefore also runs
ZoomOut from a map that owes nothing to LiteGE — the functional map fitted to wave-kernel
signatures (:func:`descriptor_map`, the settings of the ZoomOut baseline of
``litege eval matching``) — and keeps, per pair, the pointwise map that better preserves
geodesic distances (:func:`geodesic_distortion`: heat-method distances from ``n_sources``
farthest points of X to ``n_distortion_samples`` farthest points, against the same distances
between their images on Y; ties keep LiteGE's). On a near-isometric pair the right map has the
lower distortion; across species the WKS map is usually wrong at the body scale and LiteGE's
is kept. The same check then judges step 5 where the category asks for it
(:attr:`ZoomOutSettings.distortion_tolerance`): a smoothed map that distorts geodesics more than
the spectral map gives way to it (bipeds: near-isometric human pairs lose to the fit).

Both shapes must be meshes; their spectra (``n_eigen`` eigenpairs of the cotangent Laplacian in
the aligned unit-area frame, or the robust "tufted" Laplacian of a mesh prepared as broken) are
computed once per prepared shape and memoized on it. Needs ``pyFM`` (PyPI ``pyfmaps``, extra
``litege[eval]``): :class:`~litege_core.errors.MissingDependencyError` without it.
A refined map is a few seconds per pair on a CPU (the eigenpairs dominate), not milliseconds.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np
from numpy.typing import NDArray

from litege_core.errors import DegenerateShapeError, InputError, MissingDependencyError
from litege_core.matching.deform import register_displacement, smooth_displacement
from litege_core.sampling import farthest_point_sampling

if TYPE_CHECKING:  # scipy loads when a map is smoothed
    from scipy.spatial import cKDTree


class PreparedShape(Protocol):
    """What :func:`spectrum` reads of a :class:`~litege_core.matching.MatchingShape`."""

    @property
    def aligned(self) -> NDArray: ...

    @property
    def faces(self) -> NDArray | None: ...

    @property
    def scaling(self) -> str: ...

    @property
    def _lazy(self) -> dict[str, Any]: ...


REFINE_METHODS: tuple[str, ...] = ("none", "zoomout", "zoomout-hybrid")
"""``refine`` values of :meth:`~litege_core.matching.MatchingModel.match`."""

DISTORTION_TOLERANCE: dict[str, float] = {"biped": 1.1}
"""Category default of :attr:`ZoomOutSettings.distortion_tolerance` (categories not named:
``inf``, the smoothed map always). Chosen on generated pairs (``scripts/refine_gate.py``,
BENCHMARKS.md ``refine-gate``, 48 biped and 48 quadruped pairs): on near-isometric biped pairs
(one body in two poses, two bodies of one family) the smoothed map is worse than the spectral
one, and it distorts geodesics more; the check at 1.1 (the middle of the flat optimum 0.95–1.15)
takes the biped mean 2.54 → 2.36 (spectral 2.45). On quadruped pairs the smoothed map is better
even where it distorts more, and no tolerance helped (1.61 unchecked, 1.76 at 1.1)."""


@dataclass(frozen=True)
class ZoomOutSettings:
    """Settings of :func:`zoomout_refine`.

    Attributes:
        k_init: size of the functional map built from LiteGE's seed map.
        n_eigen: final size (eigenpairs computed per shape).
        step: basis growth per ZoomOut iteration.
        n_samples: farthest points of each mesh (seed queries on X, iteration samples).
        n_descriptors, descriptor_step, k_fit, w_descr, w_lap, w_dcomm, w_orient: the WKS
            functional map of ``zoomout-hybrid`` (``n_descriptors`` energies, every
            ``descriptor_step``-th kept, a ``k_fit × k_fit`` map, pyFM's energy weights).
        n_sources, n_distortion_samples: farthest points of X of the distortion check.
        smoothing: μ of the smooth displacement fitted to the refined map (unit-area frame,
            area² units; :func:`~litege_core.matching.deform.smooth_displacement`); 0 maps
            each query by the spectral embedding alone.
        smoothing_rounds: robust reweighting rounds of that fit.
        registration_rounds: closest-point rounds registering the fitted displacement to Y's
            surface (:func:`~litege_core.matching.deform.register_displacement`); 0 keeps the
            fit. Its smoothness weight falls geometrically from ``smoothing`` to
            ``registration_smoothing``.
        registration_smoothing: μ of the last registration round (area² units).
        registration_anchor: weight of the registration's tie to the refined map's matches,
            relative to its surface term (0: none; the tie keeps near-isometric pairs on the
            refined map).
        distortion_tolerance: ``zoomout-hybrid`` keeps the smoothed (fitted and registered)
            map only where its geodesic distortion is at most this multiple of the spectral
            map's, else the spectral map (``math.inf``: always the smoothed map). ``None``:
            the matching model's category default (:data:`DISTORTION_TOLERANCE`,
            :meth:`for_category`); the functions of this module read ``None`` as ``inf``.
    """

    k_init: int = 20
    n_eigen: int = 100
    step: int = 5
    n_samples: int = 1000
    n_descriptors: int = 100
    descriptor_step: int = 2
    k_fit: int = 30
    w_descr: float = 1.0
    w_lap: float = 0.1
    w_dcomm: float = 1.0
    w_orient: float = 1.0
    n_sources: int = 12
    n_distortion_samples: int = 300
    smoothing: float = 3e-6
    smoothing_rounds: int = 4
    registration_rounds: int = 8
    registration_smoothing: float = 1e-7
    registration_anchor: float = 0.01
    distortion_tolerance: float | None = None

    def __post_init__(self) -> None:
        if not 1 <= self.k_init <= self.n_eigen:
            raise InputError(f"need 1 <= k_init <= n_eigen, got {self.k_init}, {self.n_eigen}")
        if self.step < 1 or self.n_samples < 1:
            raise InputError("step and n_samples must be positive")
        if not 1 <= self.k_fit <= self.n_eigen:
            raise InputError(f"need 1 <= k_fit <= n_eigen, got {self.k_fit}, {self.n_eigen}")
        if min(self.n_sources, self.n_distortion_samples, self.n_descriptors) < 1:
            raise InputError("n_sources, n_distortion_samples and n_descriptors must be positive")
        # ``not (x >= 0)`` style checks: NaN fails every comparison and must not slip through
        if not (0 <= self.smoothing < math.inf) or self.smoothing_rounds < 1:
            raise InputError(
                "smoothing must be finite and >= 0 and smoothing_rounds positive, "
                f"got {self.smoothing}, {self.smoothing_rounds}"
            )
        if self.registration_rounds < 0 or not (0 <= self.registration_anchor < math.inf):
            raise InputError("registration_rounds and registration_anchor must be finite and >= 0")
        if not (0 < self.registration_smoothing < math.inf):
            raise InputError(
                f"registration_smoothing must be finite and positive, got "
                f"{self.registration_smoothing}"
            )
        if self.distortion_tolerance is not None and not self.distortion_tolerance > 0:
            raise InputError("distortion_tolerance must be positive (inf: no check) or None")

    def for_category(self, category: str) -> ZoomOutSettings:
        """These settings with an unset ``distortion_tolerance`` set to ``category`` 's
        default (:data:`DISTORTION_TOLERANCE`; ``inf`` for a category without one)."""
        if self.distortion_tolerance is not None:
            return self
        return replace(self, distortion_tolerance=DISTORTION_TOLERANCE.get(category, math.inf))

    @property
    def n_iterations(self) -> int:
        return (self.n_eigen - self.k_init) // self.step


def import_pyfm() -> Any:
    """The ``pyFM`` modules used here, or :class:`MissingDependencyError`."""
    try:
        from pyFM import spectral
        from pyFM.mesh import TriMesh
        from pyFM.refine import zoomout
    except (ImportError, TypeError) as exc:  # TypeError: a module set to None
        raise MissingDependencyError(
            "refine='zoomout' needs pyFM: pip install 'litege[eval]' (PyPI pyfmaps)"
        ) from exc
    return TriMesh, spectral, zoomout


@dataclass(frozen=True)
class Spectrum:
    """Laplace–Beltrami eigenvectors ``(V, k)`` of a prepared mesh and its FPS samples.

    ``mesh`` is the processed pyFM ``TriMesh``, ``vertices`` ``(V, 3)`` the mesh's aligned
    unit-area vertices and ``eigenvalues`` ``(k,)`` (``None`` where a caller built the spectrum
    itself; ``zoomout-hybrid`` and the smoothing of a refined map need them)."""

    eigenvectors: NDArray
    samples: NDArray
    mesh: Any = None
    vertices: NDArray | None = None
    eigenvalues: NDArray | None = None

    @property
    def nbytes(self) -> int:
        """Bytes of the eigenvectors, samples and vertices (the pyFM mesh shares its
        eigenvectors)."""
        vertices = 0 if self.vertices is None else self.vertices.nbytes
        return int(self.eigenvectors.nbytes + self.samples.nbytes + vertices)


def spectrum(prepared: PreparedShape, settings: ZoomOutSettings) -> Spectrum:
    """The (memoized) spectrum of a prepared mesh.

    Raises:
        InputError: a point cloud.
        MissingDependencyError: no pyFM.
    """
    if prepared.faces is None:
        raise InputError("refine='zoomout' needs meshes; got a point cloud")
    key = f"spectrum:{settings.n_eigen}:{settings.n_samples}"
    cached = prepared._lazy.get(key)
    if cached is None:
        vertices = np.asarray(prepared.aligned, dtype=np.float64)
        mesh = _laplacian_eigenpairs(
            vertices,
            np.asarray(prepared.faces),
            min(settings.n_eigen, vertices.shape[0] - 2),
            robust=prepared.scaling == "broken_mesh",
        )
        samples = farthest_point_sampling(vertices, min(settings.n_samples, vertices.shape[0]))
        cached = Spectrum(
            np.asarray(mesh.eigenvectors, dtype=np.float64),
            samples,
            mesh,
            vertices,
            np.asarray(mesh.eigenvalues, dtype=np.float64),
        )
        prepared._lazy[key] = cached
    return cached


def _laplacian_eigenpairs(vertices: NDArray, faces: NDArray, k: int, robust: bool) -> Any:
    """A pyFM mesh of ``vertices`` ``(N, 3)`` and ``faces`` ``(F, 3)`` with its first ``k``
    Laplace–Beltrami eigenpairs. Faces that repeat a vertex are dropped (they have no area);
    where the cotangent Laplacian's eigensolver fails (zero-area faces, isolated vertices) the
    robust Laplacian (intrinsic mollification) is tried before giving up.

    Raises:
        DegenerateShapeError: neither Laplacian gives finite eigenpairs.
    """
    TriMesh, _, _ = import_pyfm()
    faces = faces[(faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2])]
    faces = faces[faces[:, 0] != faces[:, 2]]
    for attempt in (True,) if robust else (False, True):
        mesh = TriMesh(vertices, faces)
        try:  # a third-party solver: any failure means these eigenpairs are unusable
            mesh.process(k=k, robust=attempt, verbose=False)
        except Exception:
            continue
        values, vectors = np.asarray(mesh.eigenvalues), np.asarray(mesh.eigenvectors)
        finite = np.isfinite(values).all() and np.isfinite(vectors).all()
        if finite and vectors.shape == (vertices.shape[0], k):
            return mesh
    raise DegenerateShapeError(
        "refine='zoomout' could not compute this mesh's Laplace-Beltrami spectrum (degenerate "
        "faces or isolated vertices); clean the mesh or match without refine"
    )


def _zoomout(fmap: NDArray, source: Spectrum, target: Spectrum, settings: ZoomOutSettings):
    """ZoomOut from ``fmap`` (``k2 × k1``, Y → X functions) up to the computed eigenpairs."""
    _, _, zoomout = import_pyfm()
    k2, k1 = fmap.shape
    k_max = min(source.eigenvectors.shape[1], target.eigenvectors.shape[1])
    n_iterations = max(0, (k_max - max(k1, k2)) // settings.step)
    if not n_iterations:
        return fmap
    return zoomout.zoomout_refine(
        fmap,
        target.eigenvectors,
        source.eigenvectors,
        nit=n_iterations,
        step=settings.step,
        subsample=(target.samples, source.samples),
        n_jobs=1,
    )


def pointwise_matches(fmap: NDArray, source: Spectrum, target: Spectrum, rows: NDArray) -> NDArray:
    """Y vertex of each X vertex in ``rows`` under the functional map (spectral nearest)."""
    _, spectral, _ = import_pyfm()
    k2, k1 = fmap.shape
    found = spectral.FM_to_p2p(
        fmap, target.eigenvectors[:, :k1], source.eigenvectors[np.asarray(rows), :k2], n_jobs=1
    )
    return np.asarray(found, dtype=np.int64)


def zoomout_map(
    seed_map: NDArray, source: Spectrum, target: Spectrum, settings: ZoomOutSettings
) -> NDArray:
    """The ZoomOut-refined functional map (``k2 × k1``, Y → X functions) started from the map
    fitted to ``seed_map``: ``(S,)`` the Y vertex of each of ``source.samples`` (LiteGE's
    matches). Query any X vertices with :func:`pointwise_matches`."""
    _, spectral, _ = import_pyfm()
    phi_x, phi_y = source.eigenvectors, target.eigenvectors
    k_init = min(settings.k_init, phi_x.shape[1], phi_y.shape[1])
    # pyFM's convention: mesh1 = Y, mesh2 = X, FM_12 (k2 × k1) maps functions on Y to X and
    # the pointwise map p2p_21 sends X points to Y points.
    fmap = spectral.p2p_to_FM(
        np.asarray(seed_map, dtype=np.int64), phi_y[:, :k_init], phi_x[source.samples, :k_init]
    )
    return _zoomout(fmap, source, target, settings)


def zoomout_refine(
    seed_map: NDArray,
    source: Spectrum,
    target: Spectrum,
    rows: NDArray,
    settings: ZoomOutSettings,
) -> NDArray:
    """Refined matches of the vertices ``rows`` of X.

    Args:
        seed_map: ``(S,)`` Y vertex of each of ``source.samples`` (LiteGE's matches).
        source, target: spectra of X and Y.
        rows: ``(N,)`` vertex indices of X to map.
        settings: sizes of the maps.

    Returns:
        ``(N,)`` int64 vertices of Y.
    """
    return pointwise_matches(zoomout_map(seed_map, source, target, settings), source, target, rows)


def descriptor_map(source: Spectrum, target: Spectrum, settings: ZoomOutSettings) -> NDArray:
    """ZoomOut-refined functional map (``k × k``, Y → X functions) started from the map fitted
    to wave-kernel signatures (no LiteGE involved; the ZoomOut baseline's settings)."""
    if source.mesh is None or target.mesh is None:
        raise InputError("a descriptor map needs spectra computed by spectrum()")
    from pyFM.functional import FunctionalMapping
    from pyFM.signatures import mesh_WKS

    k = min(source.eigenvectors.shape[1], target.eigenvectors.shape[1])
    k_fit = min(settings.k_fit, k)
    wks = [
        mesh_WKS(s.mesh, settings.n_descriptors, k=k)[:, :: settings.descriptor_step]
        for s in (target, source)
    ]
    model = FunctionalMapping(target.mesh, source.mesh)
    model.add_descriptors(wks[0], wks[1], normalize=True)
    model.fit(
        K=(k_fit, k_fit),
        w_descr=settings.w_descr,
        w_lap=settings.w_lap,
        w_dcomm=settings.w_dcomm,
        w_orient=settings.w_orient,
        verbose=False,
    )
    return _zoomout(np.asarray(model.FM_12), source, target, settings)


def heat_engine(prepared: PreparedShape) -> Any:
    """Heat-method geodesic engine of a prepared mesh in its aligned unit-area frame
    (memoized on it)."""
    cached = prepared._lazy.get("heat")
    if cached is None:
        from litege_core.engines import make_engine
        from litege_core.shape import Shape

        if prepared.faces is None:
            raise InputError("geodesic distortion needs meshes")
        mesh = Shape.from_arrays(np.asarray(prepared.aligned, dtype=np.float64), prepared.faces)
        cached = make_engine(mesh, "heat")
        prepared._lazy["heat"] = cached
    return cached


def geodesic_distortion(
    source_heat: Any,
    target_heat: Any,
    sources: NDArray,
    samples: NDArray,
    mapped_sources: NDArray,
    mapped_samples: NDArray,
) -> float:
    """Mean ``|d_X(s, v) − d_Y(m(s), m(v))|`` over ``sources × samples`` of X (unit-area units;
    0 for an isometry)."""
    on_x = source_heat.distances(np.asarray(sources)).distances[:, np.asarray(samples)]
    on_y = target_heat.distances(np.asarray(mapped_sources)).distances[:, mapped_samples]
    return float(np.abs(on_x - on_y).mean())


@dataclass(frozen=True)
class DistortionCheck:
    """The hybrid's distortion check of maps of X (:func:`geodesic_distortion`).

    Attributes:
        source_heat, target_heat: :func:`heat_engine` of X and Y.
        sources: ``(n_sources,)`` farthest points of X; samples: ``(n_distortion_samples,)``.
    """

    source_heat: Any
    target_heat: Any
    sources: NDArray
    samples: NDArray

    @classmethod
    def of(
        cls, source_heat: Any, target_heat: Any, source_points: NDArray, settings: ZoomOutSettings
    ) -> DistortionCheck:
        """The check on the farthest points of X's ``(V, 3)`` vertices that ``settings``
        name."""
        count = len(source_points)
        return cls(
            source_heat,
            target_heat,
            farthest_point_sampling(source_points, min(settings.n_sources, count)),
            farthest_point_sampling(source_points, min(settings.n_distortion_samples, count)),
        )

    @property
    def points(self) -> NDArray:
        """X's vertices a map must send to Y: the sources, then the samples."""
        return np.concatenate([self.sources, self.samples])

    def __call__(self, found: NDArray) -> float:
        """The distortion of the map that sends :attr:`points` to Y's vertices ``found``."""
        n = self.sources.size
        return geodesic_distortion(
            self.source_heat, self.target_heat, self.sources, self.samples, found[:n], found[n:]
        )


@dataclass(frozen=True)
class HybridResult:
    """Matches of ``zoomout-hybrid`` and how they were chosen.

    Attributes:
        indices: ``(N,)`` int64 Y vertices of the queries.
        seed: ``"litege"`` or ``"descriptors"``: the start of the kept map.
        distortion: ``{"litege": float, "descriptors": float}``, and ``"smoothed"`` where the
            smoothed map was checked (:attr:`ZoomOutSettings.distortion_tolerance`).
    """

    indices: NDArray
    seed: str
    distortion: dict[str, float]


@dataclass(frozen=True, eq=False)
class RefinedMap:
    """The refined map of one pair (X → Y), reusable for any queries of X: a correspondence
    stream computes it once and maps each batch with :meth:`matches`.

    Attributes:
        fmap: ``(k2, k1)`` functional map (Y → X functions, pyFM's convention).
        seed: ``zoomout-hybrid``'s start of the kept map, ``"litege"`` or ``"descriptors"``
            (``None`` for plain ZoomOut, which starts from LiteGE's matches).
        distortion: the hybrid's check ``{"litege": float, "descriptors": float}``, with
            ``"smoothed"`` where the smoothed map was checked (empty for
            plain ZoomOut).
        displacement: ``(K, 3)`` coefficients, in X's eigenbasis, of the smooth displacement
            fitted to the map (:func:`smoothed`), or ``None``: queries map by the spectral
            embedding.
        target_tree: k-d tree of Y's vertices (with ``displacement``).
    """

    fmap: NDArray
    seed: str | None = None
    distortion: dict[str, float] = field(default_factory=dict)
    displacement: NDArray | None = None
    target_tree: cKDTree | None = None

    @property
    def refinement(self) -> str:
        """``"zoomout"``, or ``"zoomout:litege"`` / ``"zoomout:descriptors"`` (hybrid)."""
        return "zoomout" if self.seed is None else f"zoomout:{self.seed}"

    @property
    def nbytes(self) -> int:
        total = self.fmap.nbytes
        if self.displacement is not None:
            total += self.displacement.nbytes
        if self.target_tree is not None:
            total += self.target_tree.data.nbytes + self.target_tree.indices.nbytes
        return int(total)

    def matches(self, source: Spectrum, target: Spectrum, rows: NDArray) -> NDArray:
        """``(N,)`` int64 Y vertices of the X vertices ``rows``."""
        if self.displacement is None or self.target_tree is None:
            return pointwise_matches(self.fmap, source, target, rows)
        if source.vertices is None:
            raise InputError("a smoothed map needs the source spectrum computed by spectrum()")
        rows = np.asarray(rows, dtype=np.int64)
        basis = source.eigenvectors[rows, : self.displacement.shape[0]]
        _, found = self.target_tree.query(source.vertices[rows] + basis @ self.displacement)
        return np.asarray(found, dtype=np.int64)


def smoothed(
    refined: RefinedMap, source: Spectrum, target: Spectrum, settings: ZoomOutSettings
) -> RefinedMap:
    """``refined`` with the smooth displacement of X fitted to its matches of X's samples and
    registered to Y's surface (``refined`` itself when ``settings.smoothing`` is 0).

    Raises:
        InputError: spectra not computed by :func:`spectrum` (no mesh, vertices or
            eigenvalues).
    """
    if settings.smoothing == 0:
        return refined
    if (
        source.mesh is None
        or source.vertices is None
        or source.eigenvalues is None
        or target.vertices is None
    ):
        raise InputError("smoothing a refined map needs spectra computed by spectrum()")
    from scipy.spatial import cKDTree

    samples = source.samples
    images = pointwise_matches(refined.fmap, source, target, samples)
    basis = source.eigenvectors[samples]
    eigenvalues = source.eigenvalues[: source.eigenvectors.shape[1]]
    area = float(source.mesh.mass.diagonal().sum())
    points = source.vertices[samples]
    offsets = target.vertices[images] - points
    displacement = smooth_displacement(
        basis,
        eigenvalues,
        offsets,
        area,
        settings.smoothing,
        settings.smoothing_rounds,
    )
    tree = cKDTree(target.vertices)
    if settings.registration_rounds:
        if target.mesh is None:
            raise InputError("registering a refined map needs spectra computed by spectrum()")
        displacement = register_displacement(
            basis,
            eigenvalues,
            points,
            offsets,
            displacement,
            target.vertices,
            np.asarray(target.mesh.vertex_normals, dtype=np.float64),
            area,
            (settings.smoothing, settings.registration_smoothing),
            settings.registration_rounds,
            settings.registration_anchor,
            target_tree=tree,
        )
    return replace(refined, displacement=displacement, target_tree=tree)


def refined_map(
    method: str,
    seed_map: NDArray,
    source: Spectrum,
    target: Spectrum,
    settings: ZoomOutSettings,
    source_heat: Any = None,
    target_heat: Any = None,
    source_points: NDArray | None = None,
) -> RefinedMap:
    """The refined map of a pair by ``method`` (``"zoomout"`` or ``"zoomout-hybrid"``).

    Args:
        method: one of :data:`REFINE_METHODS` other than ``"none"``.
        seed_map, source, target, settings: as :func:`zoomout_refine`.
        source_heat, target_heat: :func:`heat_engine` of X and Y (``zoomout-hybrid`` only).
        source_points: ``(V, 3)`` X's vertices, for the farthest points of the hybrid's
            distortion check (``zoomout-hybrid`` only).
    """
    if method == "zoomout":
        return smoothed(
            RefinedMap(zoomout_map(seed_map, source, target, settings)), source, target, settings
        )
    if method != "zoomout-hybrid":
        raise InputError(f"no refined map for refine={method!r}")
    if source_heat is None or target_heat is None or source_points is None:
        raise InputError("zoomout-hybrid needs both heat engines and the source's points")
    check = DistortionCheck.of(source_heat, target_heat, source_points, settings)
    maps = {
        "litege": zoomout_map(seed_map, source, target, settings),
        "descriptors": descriptor_map(source, target, settings),
    }
    distortion = {
        name: check(pointwise_matches(fmap, source, target, check.points))
        for name, fmap in maps.items()
    }
    seed = "litege" if distortion["litege"] <= distortion["descriptors"] else "descriptors"
    refined = smoothed(RefinedMap(maps[seed], seed, distortion), source, target, settings)
    tolerance = settings.distortion_tolerance
    if refined.displacement is None or tolerance is None or math.isinf(tolerance):
        return refined
    distortion = {**distortion, "smoothed": check(refined.matches(source, target, check.points))}
    if distortion["smoothed"] <= tolerance * distortion[seed]:
        return replace(refined, distortion=distortion)
    return RefinedMap(maps[seed], seed, distortion)


def hybrid_refine(
    seed_map: NDArray,
    source: Spectrum,
    target: Spectrum,
    rows: NDArray,
    settings: ZoomOutSettings,
    source_heat: Any,
    target_heat: Any,
    source_points: NDArray,
) -> HybridResult:
    """LiteGE-seeded and descriptor-seeded ZoomOut maps; the less distorting one is kept.

    Args:
        seed_map, source, target, rows, settings: as :func:`zoomout_refine`.
        source_heat, target_heat: :func:`heat_engine` of X and Y.
        source_points: ``(V, 3)`` X's vertices (for the farthest points of the check).
    """
    refined = refined_map(
        "zoomout-hybrid",
        seed_map,
        source,
        target,
        settings,
        source_heat,
        target_heat,
        source_points,
    )
    assert refined.seed is not None  # a hybrid map always names its start
    matches = refined.matches(source, target, np.asarray(rows, dtype=np.int64))
    return HybridResult(matches, refined.seed, refined.distortion)


__all__ = [
    "REFINE_METHODS",
    "DistortionCheck",
    "HybridResult",
    "PreparedShape",
    "RefinedMap",
    "Spectrum",
    "ZoomOutSettings",
    "descriptor_map",
    "geodesic_distortion",
    "heat_engine",
    "hybrid_refine",
    "import_pyfm",
    "pointwise_matches",
    "refined_map",
    "smoothed",
    "spectrum",
    "zoomout_map",
    "zoomout_refine",
]
