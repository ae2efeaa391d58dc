"""Matching evaluation: LiteGE against nearest neighbour after alignment and ZoomOut.

Protocol (reference-spec §5.4 and §7.3, pair sets in :mod:`litege_core.evaluation.matching_data`):

* **Error of a match**: the exact geodesic distance, on the target Y scaled to unit area,
  between the predicted point and the ground-truth point; reported as the mean ×100 over the
  pooled matches of a setting.
* **AUC** ×100: recall ``P(error ≤ t)`` at ``linspace(0, T, 40)``, trapezoid rule, divided by
  ``T``; ``T = 0.1`` for ``template`` and ``0.2`` for every other setting (paper).
* **Flip rate**: a match is a left-right flip when its error under the *mirrored* ground truth
  is below ``FLIP_RATIO`` × its error under the true one and at least ``FLIP_MARGIN`` smaller
  (points near the symmetry plane, whose mirror is themselves, never count). Reported
  separately, only where a mirror map exists (synthetic shapes: the template's exact symmetry;
  TOSCA landmarks: ``sym.info``; TOSCA dense: ``NAME.sym.vts`` when present).
* **Time**: seconds per pair end to end, preprocessing of both shapes included. A shape used in
  several pairs is preprocessed once and its measured preprocessing time is charged to every
  pair it takes part in, so the per-pair figure is what a pair costs from scratch.

Methods:

* ``litege``: :meth:`MatchingModel.prepare` both shapes, :meth:`MatchingModel.match` the queries.
  Ablation rows (issue 15) are :class:`LiteGEVariant` objects, named ``litege[TOKENS]``:
  ``tnet`` / ``judged`` (the frames of ``prepare``; default ``auto``), ``mirror-vote``
  (``match(side="network")``: also match on Y's mirror image and keep the lower mean predicted
  distance), ``zoomout`` (``match(refine="zoomout")``, meshes only) and ``zoomout-hybrid``
  (``match(refine="zoomout-hybrid")``); each mesh's spectrum (and heat solver) is computed in
  ``prepare``, so its time counts like the preparation's.
* ``nn``: the same :meth:`MatchingModel.prepare` (``prepared.aligned``: the model's own alignment
  into the unit-area frame), then the nearest Y point of each query (a KD-tree); one row per
  frames mode of the LiteGE variants (``nn[tnet]``, ``nn[judged]``; ``nn`` for ``auto``). Its time
  includes the whole ``prepare`` (descriptor and NN cache too, which NN alone would not need);
  LiteGE's also includes the per-point network features (memoized per shape).
* ``zoomout``: functional maps with ``pyFM`` (PyPI ``pyfmaps``, extra ``litege[eval]``): unit-area
  centred shapes, 100 Laplace–Beltrami eigenpairs (cotangent Laplacian on meshes, robust
  "tufted" Laplacian on point clouds and broken meshes), 100 WKS descriptors (every 2nd kept),
  an initial ``30 × 30`` map (descriptor preservation + commutativity, Laplacian commutativity,
  orientation term on meshes), ZoomOut ``30 → 100`` in steps of 5 on 1000 farthest-point
  samples of each shape, then the pointwise map of the queries in the ``100``-dim basis.
"""

from __future__ import annotations

import datetime
import math
import os
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any, Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import cKDTree

from litege_core.errors import MissingDependencyError
from litege_core.evaluation.matching_data import MatchPair
from litege_core.metrics import auc
from litege_core.seams import boundary_edge_fraction
from litege_core.shape import Shape

N_THRESHOLDS = 40
FLIP_RATIO = 0.5
FLIP_MARGIN = 0.05  # unit-area units (5 on the ×100 scale)
METHODS = ("litege", "nn", "zoomout")
ROBUST_BOUNDARY = 0.02  # meshes with more boundary edges (broken scans) use the tufted Laplacian
METHOD_LABELS = {"litege": "LiteGE", "nn": "NN (aligned)", "zoomout": "ZoomOut (pyFM)"}


# ----------------------------------------------------------------------------- metrics


def auc_threshold(setting: str) -> float:
    """AUC upper threshold: 0.1 for same-topology (``template``) pairs, 0.2 otherwise."""
    return 0.1 if setting == "template" else 0.2


def mean_error_x100(errors: ArrayLike) -> float:
    """Mean unit-area geodesic error ×100 (NaN for no matches)."""
    errors = np.asarray(errors, dtype=np.float64)
    return float(100.0 * errors.mean()) if errors.size else float("nan")


def auc_x100(errors: ArrayLike, threshold: float, n_thresholds: int = N_THRESHOLDS) -> float:
    """Area under the recall curve ``P(error ≤ t)``, ``t ∈ linspace(0, T, n)``, trapezoid rule,
    divided by ``T``, ×100 (100 = every error is 0)."""
    errors = np.asarray(errors, dtype=np.float64).reshape(-1)
    return auc(errors, threshold, n_thresholds) if errors.size else float("nan")


def flips(
    errors: ArrayLike,
    mirror_errors: ArrayLike,
    ratio: float = FLIP_RATIO,
    margin: float = FLIP_MARGIN,
) -> NDArray:
    """Boolean mask of left-right flipped matches (see the module doc)."""
    errors = np.asarray(errors, dtype=np.float64)
    mirror_errors = np.asarray(mirror_errors, dtype=np.float64)
    return (mirror_errors < ratio * errors) & (errors - mirror_errors >= margin)


# ----------------------------------------------------------------------------- methods


@dataclass
class Timed:
    """A prepared shape and the seconds its preparation took."""

    value: Any
    seconds: float


class MatchMethod(Protocol):
    """A matching method: ``prepare`` each shape once, then ``match`` queries of X on Y.

    ``name`` labels the method in results; ``prep_key`` names the preparation: methods with the
    same key share prepared shapes (and their measured time).
    """

    name: str
    prep_key: str

    def prepare(self, shape: Shape) -> Any:
        """The per-shape preparation (timed once per ``prep_key`` and shape)."""
        ...

    def match(self, x: Any, y: Any, queries: NDArray) -> NDArray:
        """``(Q,)`` int64 indices into Y of the matches of X's ``queries``."""
        ...


VARIANT_FRAMES = ("auto", "tnet", "judged", "intrinsic")
VARIANT_OPTIONS = (
    "mirror-vote",
    "zoomout",
    "zoomout-hybrid",
    "unsmoothed",
    "unregistered",
    "unchecked",
)


@dataclass(frozen=True)
class LiteGEVariant:
    """One LiteGE row of the ablation (issue 15).

    Attributes:
        frames: ``prepare(frames=…)``: ``auto``, ``tnet``, ``judged`` or ``intrinsic``.
        side: ``match(side=…)``: ``frame``, or ``network`` (token ``mirror-vote``).
        refine: ``match(refine=…)``: ``none``, ``zoomout`` or ``zoomout-hybrid`` (meshes only).
        smoothed: the refined map's smooth displacement fit (token ``unsmoothed`` turns it off:
            ``ZoomOutSettings(smoothing=0)``).
        registered: the fit's registration to Y's surface (token ``unregistered`` turns it
            off: ``ZoomOutSettings(registration_rounds=0)``).
        checked: the hybrid's distortion check of the smoothed map, where the model's
            category has one (token ``unchecked`` turns it off:
            ``ZoomOutSettings(distortion_tolerance=inf)``).
    """

    frames: str = "auto"
    side: str = "frame"
    refine: str = "none"
    smoothed: bool = True
    registered: bool = True
    checked: bool = True

    @classmethod
    def parse(cls, text: str) -> LiteGEVariant:
        """``"judged+zoomout"``-style text: one frames token (default ``auto``), optionally
        ``mirror-vote``, one of ``zoomout``, ``zoomout-hybrid`` and, with one of them,
        ``unsmoothed`` or ``unregistered`` and ``unchecked``, joined by ``+``."""
        from litege_core.errors import InputError

        tokens = [t.strip() for t in text.split("+") if t.strip()]
        frames = [t for t in tokens if t in VARIANT_FRAMES]
        refine = [t for t in tokens if t.startswith("zoomout")]
        unknown = [t for t in tokens if t not in VARIANT_FRAMES + VARIANT_OPTIONS]
        unsmoothed = "unsmoothed" in tokens
        unregistered = "unregistered" in tokens
        unchecked = "unchecked" in tokens
        if (
            unknown
            or len(frames) > 1
            or len(refine) > 1
            or ((unsmoothed or unregistered or unchecked) and not refine)
            or (unsmoothed and (unregistered or unchecked))
        ):
            raise InputError(
                f"bad LiteGE variant {text!r}: one of {list(VARIANT_FRAMES)} and any of "
                f"{list(VARIANT_OPTIONS)} (unsmoothed, or unregistered and unchecked, with a "
                "refinement), joined by '+'"
            )
        return cls(
            frames=frames[0] if frames else "auto",
            side="network" if "mirror-vote" in tokens else "frame",
            refine=refine[0] if refine else "none",
            smoothed=not unsmoothed,
            registered=not unregistered,
            checked=not unchecked,
        )

    @property
    def tokens(self) -> list[str]:
        out = [] if self.frames == "auto" else [self.frames]
        if self.side == "network":
            out.append("mirror-vote")
        if self.refine != "none":
            out.append(self.refine)
            if not self.smoothed:
                out.append("unsmoothed")
            else:
                if not self.registered:
                    out.append("unregistered")
                if not self.checked:
                    out.append("unchecked")
        return out

    @property
    def name(self) -> str:
        """``litege`` for the default, else ``litege[tokens]``."""
        return f"litege[{'+'.join(self.tokens)}]" if self.tokens else "litege"


def method_label(name: str) -> str:
    """Table label of a method name (``litege[judged+zoomout]`` → ``LiteGE [judged+zoomout]``)."""
    if name in METHOD_LABELS:
        return METHOD_LABELS[name]
    base, _, rest = name.partition("[")
    if rest and base in METHOD_LABELS:
        return f"{METHOD_LABELS[base]} [{rest.rstrip(']')}]"
    return name


class LiteGEMethod:
    """:meth:`MatchingModel.prepare` both shapes, :meth:`MatchingModel.match` the queries, with
    the options of a :class:`LiteGEVariant`. A refined variant computes each mesh's spectrum in
    ``prepare`` (memoized per shape, so its time is charged like the preparation's)."""

    def __init__(self, model, seed: int = 0, variant: LiteGEVariant | None = None) -> None:
        self.model = model
        self.seed = seed
        self.variant = variant or LiteGEVariant()
        self.name = self.variant.name
        refined = "" if self.variant.refine == "none" else f":{self.variant.refine}"
        self.prep_key = f"litege:{model.content_hash}:{seed}:{self.variant.frames}{refined}"

    def prepare(self, shape: Shape):
        prepared = self.model.prepare(shape, seed=self.seed, frames=self.variant.frames)
        self.model.features(prepared)  # memoized per shape: charge it to the preparation
        if self.variant.refine != "none" and prepared.faces is not None:
            from litege_core.matching.refine import ZoomOutSettings as RefineSettings
            from litege_core.matching.refine import heat_engine, spectrum

            spectrum(prepared, RefineSettings())
            if self.variant.refine == "zoomout-hybrid":
                heat_engine(prepared).prepare()
        return prepared

    def match(self, x, y, queries: NDArray) -> NDArray:
        from litege_core.matching.refine import ZoomOutSettings as RefineSettings

        overrides: dict[str, Any] = {}
        if not self.variant.smoothed:
            overrides["smoothing"] = 0.0
        if not self.variant.registered:
            overrides["registration_rounds"] = 0
        if not self.variant.checked:
            overrides["distortion_tolerance"] = math.inf
        settings = RefineSettings(**overrides)
        return self.model.match(
            x, y, queries, side=self.variant.side, refine=self.variant.refine, zoomout=settings
        ).indices


class NearestNeighbourMethod:
    """Nearest Y point of each query in the model's aligned unit-area frame."""

    def __init__(self, model, seed: int = 0, frames: str = "auto") -> None:
        self.model = model
        self.seed = seed
        self.frames = frames
        self.name = "nn" if frames == "auto" else f"nn[{frames}]"
        self.prep_key = f"nn:{model.content_hash}:{seed}:{frames}"

    def prepare(self, shape: Shape):
        return self.model.prepare(shape, seed=self.seed, frames=self.frames)

    def match(self, x, y, queries: NDArray) -> NDArray:
        tree = cKDTree(np.asarray(y.aligned, dtype=np.float64))
        return tree.query(np.asarray(x.aligned, dtype=np.float64)[queries])[1].astype(np.int64)


@dataclass(frozen=True)
class ZoomOutSettings:
    """The functional-map baseline's settings (module doc)."""

    n_eigen: int = 100
    n_descriptors: int = 100
    descriptor_step: int = 2
    k_init: int = 30
    zoomout_step: int = 5
    n_samples: int = 1000
    w_descr: float = 1.0
    w_lap: float = 0.1
    w_dcomm: float = 1.0
    w_orient: float = 1.0

    @property
    def n_iterations(self) -> int:
        return (self.n_eigen - self.k_init) // self.zoomout_step


def _import_pyfm():
    try:
        from pyFM.functional import FunctionalMapping
        from pyFM.mesh import TriMesh
    except ImportError as exc:
        raise MissingDependencyError(
            "the ZoomOut baseline needs pyFM: pip install 'litege[eval]' (PyPI pyfmaps)"
        ) from exc
    return TriMesh, FunctionalMapping


class ZoomOutMethod:
    """Functional maps + ZoomOut with pyFM (needs ``pyfmaps``)."""

    name = "zoomout"

    def __init__(self, settings: ZoomOutSettings = ZoomOutSettings()) -> None:
        _import_pyfm()
        self.settings = settings
        self.prep_key = f"zoomout:{settings}"

    def prepare(self, shape: Shape):
        from pyFM.signatures import mesh_WKS

        from litege_core.sampling import farthest_point_sampling

        TriMesh, _ = _import_pyfm()
        s = self.settings
        mesh = TriMesh(
            np.asarray(shape.vertices, dtype=np.float64),
            None if shape.faces is None else np.asarray(shape.faces),
            normalize=shape.is_mesh,
        )
        # its own faces: pyFM reads the mesh as it is stored (a soup needs the robust one)
        robust = shape.faces is None or boundary_edge_fraction(shape.faces) > ROBUST_BOUNDARY
        mesh.process(k=s.n_eigen, robust=robust)
        if not shape.is_mesh:  # unit area as the point-cloud Laplacian's mass measures it
            mesh.scale(1.0 / np.sqrt(float(mesh.A.sum())))
        descriptors = mesh_WKS(mesh, s.n_descriptors, k=s.n_eigen)[:, :: s.descriptor_step]
        samples = farthest_point_sampling(mesh.vertices, min(s.n_samples, mesh.n_vertices))
        return {"mesh": mesh, "wks": descriptors, "samples": samples, "orient": shape.is_mesh}

    def match(self, x, y, queries: NDArray) -> NDArray:
        from pyFM.refine.zoomout import mesh_zoomout_refine
        from pyFM.spectral import FM_to_p2p

        _, FunctionalMapping = _import_pyfm()
        s = self.settings
        # mesh1 = Y, mesh2 = X: the pointwise map p2p_21 sends X points to Y points.
        # Both spectra were computed by prepare (fit would recompute them only if missing).
        model = FunctionalMapping(y["mesh"], x["mesh"])
        model.add_descriptors(y["wks"], x["wks"], normalize=True)
        orient = s.w_orient if (x["orient"] and y["orient"]) else 0.0
        model.fit(
            K=(s.k_init, s.k_init),
            w_descr=s.w_descr,
            w_lap=s.w_lap,
            w_dcomm=s.w_dcomm,
            w_orient=orient,
        )
        fmap = mesh_zoomout_refine(
            model.FM_12,
            model.mesh1,
            model.mesh2,
            nit=s.n_iterations,
            step=s.zoomout_step,
            subsample=(y["samples"], x["samples"]),
        )
        k2, k1 = fmap.shape
        return np.asarray(
            FM_to_p2p(
                fmap, model.mesh1.eigenvectors[:, :k1], model.mesh2.eigenvectors[queries, :k2]
            ),
            dtype=np.int64,
        )


# ----------------------------------------------------------------------------- runner


@dataclass
class SettingResult:
    """Pooled result of one method on one setting."""

    setting: str
    method: str
    pairs: int = 0
    matches: int = 0
    mean_error: float = float("nan")
    auc: float = float("nan")
    flip_rate: float | None = None
    seconds_per_pair: float = float("nan")
    failed: int = 0
    note: str = ""
    errors: list[float] = field(default_factory=list, repr=False)

    def to_dict(self) -> dict[str, Any]:
        data = asdict(self)
        data.pop("errors")
        return data


class _PrepCache:
    def __init__(self) -> None:
        self._store: dict[tuple[str, str], Timed] = {}

    def get(self, method: MatchMethod, shape: Shape) -> Timed:
        key = (method.prep_key, shape.content_hash)
        if key not in self._store:
            start = time.perf_counter()
            value = method.prepare(shape)
            self._store[key] = Timed(value, time.perf_counter() - start)
        return self._store[key]


def evaluate_pairs(
    setting: str,
    pairs: Sequence[MatchPair],
    methods: Sequence[MatchMethod],
    notes: dict[str, str] | None = None,
    log: Callable[[str], None] | None = None,
) -> list[SettingResult]:
    """Run every method on every pair of one setting; pooled metrics per method.

    ``notes`` maps a method name to a reason it was not run (a row with that note is kept).
    """
    cache = _PrepCache()
    results = []
    for method in methods:
        result = SettingResult(setting, method.name)
        errors, mirror_errors, seconds = [], [], []
        for pair in pairs:
            try:
                px, py = cache.get(method, pair.x.shape), cache.get(method, pair.y.shape)
                start = time.perf_counter()
                predicted = method.match(px.value, py.value, pair.queries)
                elapsed = time.perf_counter() - start + px.seconds + py.seconds
            except Exception as exc:  # a baseline failing on a pair is a result, not a crash
                result.failed += 1
                if log is not None:
                    log(f"{method.name} failed on {setting} {pair.name}: {exc!r}")
                continue
            err, mirrored = pair.errors(predicted)
            errors.append(err)
            seconds.append(elapsed)
            if mirrored is not None:
                mirror_errors.append(flips(err, mirrored))
        _summarize(result, errors, mirror_errors, seconds, len(pairs))
        results.append(result)
    for name, note in (notes or {}).items():
        results.append(SettingResult(setting, name, note=note))
    return results


def _summarize(result: SettingResult, errors, flip_masks, seconds, n_pairs) -> None:
    pooled = np.concatenate(errors) if errors else np.zeros(0)
    result.pairs = len(errors)
    result.matches = int(pooled.size)
    result.errors = pooled.tolist()
    if pooled.size:
        result.mean_error = mean_error_x100(pooled)
        result.auc = auc_x100(pooled, auc_threshold(result.setting))
        result.seconds_per_pair = float(np.mean(seconds))
    if flip_masks and len(flip_masks) == len(errors):
        result.flip_rate = float(100.0 * np.concatenate(flip_masks).mean())
    if result.failed:
        result.note = f"{result.failed} of {n_pairs} pairs failed"


def _fmt(value: float | None, digits: int = 2) -> str:
    if value is None or not np.isfinite(value):
        return "—"
    return f"{value:.{digits}f}"


def machine_header(extra: dict[str, str] | None = None) -> str:
    """One markdown line: date, machine, Python/torch, threads, plus ``extra`` items."""
    import torch

    from litege_core.evaluation.speed import cpu_name

    items = {
        "date": datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M UTC"),
        "machine": cpu_name(),
        "cpus": str(os.cpu_count()),
        "torch threads": str(torch.get_num_threads()),
        "python": sys.version.split()[0],
        "torch": torch.__version__,
    }
    if torch.cuda.is_available():
        items["gpu"] = torch.cuda.get_device_name()
    items.update(extra or {})
    return " · ".join(f"{k}: {v}" for k, v in items.items())


def results_table(results: Sequence[SettingResult], header: str | None = None) -> str:
    """The markdown table (one row per setting × method)."""
    lines = [header, ""] if header else []
    lines += [
        "| setting | method | pairs | matches | mean error ×100 | AUC | flip % | s / pair | note |",
        "|---|---|---:|---:|---:|---:|---:|---:|---|",
    ]
    for r in results:
        label = method_label(r.method)
        auc = f"{_fmt(r.auc, 1)} @{auc_threshold(r.setting):g}" if np.isfinite(r.auc) else "—"
        seconds = _fmt(r.seconds_per_pair, 3 if r.seconds_per_pair < 1 else 2)
        lines.append(
            f"| {r.setting} | {label} | {r.pairs} | {r.matches} | {_fmt(r.mean_error)} | "
            f"{auc} | {_fmt(r.flip_rate, 1)} | {seconds} | {r.note} |"
        )
    return "\n".join(lines)


# ----------------------------------------------------------------------------- driver

SHIPPED_FOR_CATEGORY = {"quadruped": "quadrupeds", "biped": "humans"}
CATEGORY_NOUN = {"quadruped": "quadrupeds", "biped": "humans"}


def load_matching_model(name_or_path: str, device: str = "cpu", precision: str = "float32"):
    """:meth:`MatchingModel.load` (a seam for tests)."""
    from litege_core.matching import MatchingModel

    return MatchingModel.load(name_or_path, device, precision)


class ModelChooser:
    """The matching model for each shape category: the given model where its category fits
    (a model of another category, e.g. a test model, answers every category), else the
    shipped model of that category, else none (the reason is reported in the table)."""

    def __init__(self, model, device: str = "cpu") -> None:
        self.model = model
        self.device = device
        self._other: dict[str, Any] = {}

    @property
    def synthetic_category(self) -> str:
        from litege_core.synth import CATEGORIES

        return self.model.category if self.model.category in CATEGORIES else "quadruped"

    def for_category(self, category: str):
        """``(model, None)`` or ``(None, reason)``."""
        from litege_core.errors import LiteGEError
        from litege_core.synth import CATEGORIES

        if self.model.category == category or self.model.category not in CATEGORIES:
            return self.model, None
        if category not in self._other:
            try:
                self._other[category] = load_matching_model(  # the given model's arithmetic
                    SHIPPED_FOR_CATEGORY[category], self.device, self.model.precision
                )
            except LiteGEError:
                self._other[category] = None
        found = self._other[category]
        return (
            (found, None)
            if found is not None
            else (
                None,
                f"no {CATEGORY_NOUN[category]} matching model",
            )
        )


def build_methods(
    model,
    baselines: Sequence[str],
    seed: int,
    variants: Sequence[LiteGEVariant] = (LiteGEVariant(),),
) -> list[MatchMethod]:
    """LiteGE (one method per variant), NN (one per frames mode of the variants), ZoomOut."""
    methods: list[MatchMethod] = []
    if model is not None:
        methods += [LiteGEMethod(model, seed, v) for v in variants]
        if "nn" in baselines:
            modes = dict.fromkeys(v.frames for v in variants)
            methods += [NearestNeighbourMethod(model, seed, mode) for mode in modes]
    if "zoomout" in baselines:
        methods.append(ZoomOutMethod())
    return methods


def run_matching_evaluation(
    model,
    *,
    settings: Sequence[str],
    real: Sequence[str],
    eval_data: str,
    n_pairs: int,
    n_queries: int,
    baselines: Sequence[str],
    seed: int = 0,
    device: str = "cpu",
    rotate_input: bool = True,
    workers: int = 1,
    log: Callable[[str], None] | None = None,
    variants: Sequence[str | LiteGEVariant] = ("auto",),
) -> list[SettingResult]:
    """Every requested synthetic setting and real set, every method; see the module doc.

    ``variants``: the LiteGE rows (:meth:`LiteGEVariant.parse` text or variants); a refined
    variant is not run on point-cloud settings (a row with a note says so)."""
    from litege_core.errors import InputError, LiteGEError
    from litege_core.evaluation import matching_data as data

    unknown = [b for b in baselines if b not in ("nn", "zoomout")]
    if unknown:
        raise InputError(f"unknown baselines {unknown}; expected a subset of ['nn', 'zoomout']")
    if n_pairs < 1 or n_queries < 1:
        raise InputError("--pairs and --queries must be at least 1")
    say = log or (lambda _message: None)
    chooser = ModelChooser(model, device)
    results: list[SettingResult] = []

    parsed = [v if isinstance(v, LiteGEVariant) else LiteGEVariant.parse(v) for v in variants]
    if not parsed:
        raise InputError("give at least one LiteGE variant")

    def run_set(setting: str, pairs: list[MatchPair], category: str) -> None:
        chosen, reason = chooser.for_category(category)
        notes = {}
        meshes = all(p.x.shape.is_mesh and p.y.shape.is_mesh for p in pairs)
        kept = [v for v in parsed if meshes or v.refine == "none"]
        if chosen is None:
            notes = {v.name: reason for v in parsed}
            if "nn" in baselines:
                notes["nn"] = f"{reason} (NN uses its alignment)"
        else:
            notes = {v.name: "refinement needs meshes" for v in parsed if v not in kept}
        methods = build_methods(chosen, baselines, seed, kept)
        say(f"{setting}: {len(pairs)} pairs, methods {[m.name for m in methods]}")
        results.extend(evaluate_pairs(setting, pairs, methods, notes, log=say))

    category = chooser.synthetic_category
    pool = None
    if settings:
        pool = data.SyntheticPool(category, n_pairs, n_queries, seed, rotate_input, workers)
    for setting in settings:
        assert pool is not None  # made above whenever there are settings
        try:
            pairs = pool.pairs(setting)
        except MissingDependencyError as exc:
            say(f"{setting}: skipped ({exc})")
            results.append(SettingResult(setting, "litege", note=f"skipped: {exc}"))
            continue
        run_set(setting, pairs, category)
    for name in real:
        if name not in data.REAL_SETS:
            raise InputError(f"unknown real set {name!r}; expected one of {data.REAL_SETS}")
        try:
            pairs = data.eval_data_pairs(
                name, eval_data, n_pairs, n_queries, seed, rotate_input, workers
            )
        except LiteGEError as exc:
            say(f"{name}: skipped ({exc})")
            continue
        if not pairs:
            say(f"{name}: no evaluation data under {eval_data}; skipped")
            continue
        run_set(name, pairs, data.REAL_CATEGORY[name])
    return results


__all__ = [
    "CATEGORY_NOUN",
    "FLIP_MARGIN",
    "FLIP_RATIO",
    "METHODS",
    "METHOD_LABELS",
    "N_THRESHOLDS",
    "ROBUST_BOUNDARY",
    "SHIPPED_FOR_CATEGORY",
    "VARIANT_FRAMES",
    "VARIANT_OPTIONS",
    "LiteGEMethod",
    "LiteGEVariant",
    "MatchMethod",
    "ModelChooser",
    "NearestNeighbourMethod",
    "SettingResult",
    "Timed",
    "ZoomOutMethod",
    "ZoomOutSettings",
    "auc_threshold",
    "auc_x100",
    "build_methods",
    "evaluate_pairs",
    "flips",
    "load_matching_model",
    "machine_header",
    "mean_error_x100",
    "method_label",
    "results_table",
    "run_matching_evaluation",
]
