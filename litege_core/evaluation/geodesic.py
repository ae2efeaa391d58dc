"""Geodesic-regression evaluation: LiteGE side by side with the classical baselines.

Protocol (paper §7.1, with the reference code's bugs fixed, reference-spec §7 and §10):

* Every evaluation shape is scaled to unit surface area, with exact (MMP) ground-truth rows from
  ``R`` source vertices to all vertices. Synthetic shapes come from a dataset's *test* split
  (seeds never trained on); real shapes are computed on the fly from the evaluation data.
* Settings: ``mesh`` (queries at mesh vertices; the model describes 2000 surface samples),
  clouds of 2000 and 300 points, Gaussian noise σ = 0.01 on the 2000-point cloud, and 10 % /
  15 % of the cloud cut away by two parallel planes. Corruptions are applied before
  canonicalization and before the UDF (the reference code's test did not).
* A cloud holds the ``R`` source vertices followed by area-weighted samples, so every method
  answers the same question: distances from the source points to every cloud point. Ground
  truth at the sampled points interpolates the exact vertex rows barycentrically (triangles are
  small against the distances, so the interpolation error is far below the errors measured).
* Error: |prediction − ground truth| with the ground truth rescaled to mean 100 over the pooled
  pairs of a setting (mean and median), pairs at distance 0 (a source with itself) excluded.
* Baselines on the same inputs: kNN-graph Dijkstra and point-cloud heat on clouds; the mesh heat
  method and kNN Dijkstra on the mesh vertices for the mesh setting.
* Frame selection (issue 14): ``evaluate(..., frames=("signs",))`` adds a LiteGE row per
  candidate set of :mod:`litege_core.learned.frame` (the lowest-residual candidate frame
  instead of the plain PCA sign rule), registered through :func:`register_in_frame`.
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from litege_core.engines import compute_distances
from litege_core.errors import ComputationError, InputError
from litege_core.metrics import geodesic_error
from litege_core.sampling import SurfaceSamples, farthest_point_sampling, sample_surface
from litege_core.shape import Shape
from litege_core.variants import (
    add_noise,
    add_outliers,
    cut_by_planes,
    decimated_mesh,
    repeated_points,
    small_rotation,
)

SETTINGS = ("mesh", "cloud_2000", "cloud_300", "noise_0.01", "cut_10", "cut_15")
KNN_NEIGHBOURS = 10
HELD_OUT_SEED_OFFSET = 2_000_000
"""First seed of the procedural test split (never trained on), as in ``datasets.spec``."""


@dataclass(frozen=True)
class RealSet:
    """A folder of real evaluation shapes under the eval-data root."""

    key: str
    folder: str
    pattern: str
    group: str
    model: str  # the shipped geodesic model of that category
    category: str


REAL_SETS = {
    "tosca": RealSet(
        "tosca", "tosca_5k", "*.off", "TOSCA animals (real)", "quadrupeds", "quadruped"
    ),
    "faust": RealSet("faust", "faust_5k", "*.off", "FAUST humans (real)", "humans", "biped"),
    "leopard": RealSet("leopard", "leopard", "*.obj", "leopard (real)", "quadrupeds", "quadruped"),
}
"""Real sets of the research-only evaluation data (``../shared/eval-data``); the leopard is a
single 50K-vertex mesh (CC BY 4.0)."""


def real_shape_paths(eval_root: str | Path, key: str, limit: int | None = None) -> list[Path]:
    """Sorted shape files of one real set; ``[]`` when the folder is absent (users' machines
    do not have the research-only evaluation data)."""
    if key not in REAL_SETS:
        raise InputError(f"unknown real set {key!r}; expected one of {sorted(REAL_SETS)}")
    real = REAL_SETS[key]
    folder = Path(eval_root) / real.folder
    if not folder.is_dir():
        return []
    paths = sorted(folder.glob(real.pattern))
    return paths if limit is None else paths[:limit]


@dataclass(frozen=True)
class EvalShape:
    """A unit-area mesh with exact rows ``gt (R, V)`` from ``sources (R,)`` to all vertices."""

    name: str
    group: str
    vertices: NDArray
    faces: NDArray
    sources: NDArray
    gt: NDArray


@dataclass(frozen=True)
class EvalInput:
    """What a method sees for one (shape, setting): an input shape and query rows."""

    shape: Shape
    source_index: NDArray  # (R',) indices into the input's points
    gt: NDArray  # (R', P) ground truth from each source to every input point


def unit_area(vertices: NDArray, faces: NDArray) -> tuple[NDArray, float]:
    """Vertices centred and scaled to unit area, and the scale factor used."""
    corners = vertices[faces]
    area = (
        0.5
        * np.linalg.norm(
            np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1
        ).sum()
    )
    scale = 1.0 / np.sqrt(area)
    return (vertices - vertices.mean(axis=0)) * scale, float(scale)


def synthetic_eval_shapes(
    dataset_dir: str | Path,
    limit: int | None,
    split: str = "test",
    group: str = "synthetic (held-out seeds)",
) -> list:
    """The first ``limit`` shapes (``None``: all) of a template dataset's split with their
    stored exact rows, at unit area; ``group`` names them in the results."""
    from litege_core.datasets import GeodesicDataset

    dataset = GeodesicDataset(dataset_dir)
    if dataset.faces is None:
        raise InputError(f"{dataset_dir}: synthetic evaluation needs a template dataset")
    table = dataset.load_split(split)
    shapes = []
    count = table["vertices"].shape[0]
    for i in range(count if limit is None else min(limit, count)):
        vertices, scale = unit_area(table["vertices"][i].astype(np.float64), dataset.faces)
        family = dataset.spec.families[int(table["family"][i])]
        shapes.append(
            EvalShape(
                name=f"{family}-{int(table['seed'][i])}",
                group=group,
                vertices=vertices,
                faces=dataset.faces,
                sources=table["sources"][i].astype(np.int64),
                gt=table["distances"][i].astype(np.float64) * scale,
            )
        )
    return shapes


def real_eval_shapes(
    paths: Iterable[Path], group: str, n_sources: int, cache_dir: str | Path | None = None
) -> list[EvalShape]:
    """Real meshes with exact rows from ``n_sources`` farthest-point sources, at unit area.

    With ``cache_dir``, the exact rows are stored there (``GROUP-NAME-SOURCES.npz``, keyed by
    the mesh's content hash) and reused; keep the cache out of the repository (it holds
    derived data of research-only meshes)."""
    from litege_core.io import load_shape

    shapes = []
    for path in paths:
        loaded = load_shape(path)
        if loaded.faces is None:
            raise InputError(f"{path}: real evaluation shapes are meshes, got a point cloud")
        vertices, _ = unit_area(loaded.vertices, loaded.faces)
        shape = Shape.from_arrays(vertices, loaded.faces)
        sources = farthest_point_sampling(vertices, n_sources)
        gt = _cached_rows(shape, sources, cache_dir, f"{Path(path).parent.name}-{Path(path).stem}")
        shapes.append(EvalShape(Path(path).stem, group, vertices, loaded.faces, sources, gt))
    return shapes


def _cached_rows(shape: Shape, sources: NDArray, cache_dir, name: str) -> NDArray:
    if cache_dir is None:
        return compute_distances(shape, sources, method="exact").distances
    cache = Path(cache_dir) / f"{name}-{sources.size}.npz"
    if cache.exists():
        with np.load(cache) as stored:
            if str(stored["hash"]) == shape.content_hash and np.array_equal(
                stored["sources"], sources
            ):
                return stored["gt"]
    gt = compute_distances(shape, sources, method="exact").distances
    cache.parent.mkdir(parents=True, exist_ok=True)
    partial = cache.with_name(f"{cache.stem}.{os.getpid()}.partial.npz")
    np.savez(partial, hash=shape.content_hash, sources=sources, gt=gt)
    os.replace(partial, cache)  # atomic: a job reading the cache beside this one sees all or none
    return gt


def generated_eval_shapes(
    category: str,
    n_shapes: int,
    n_sources: int,
    *,
    seed_offset: int = HELD_OUT_SEED_OFFSET,
    cache_dir: str | Path | None = None,
) -> list[EvalShape]:
    """Held-out procedural shapes generated on the fly (no dataset needed): shape ``k`` is
    family ``families[k % F]`` with seed ``seed_offset + k`` (the test split's seeds, never
    trained on), at unit area, with exact rows from ``n_sources`` farthest-point sources."""
    from litege_core import synth

    families = synth.families(category)
    faces = np.asarray(synth.template(category).faces)
    shapes = []
    for k in range(n_shapes):
        family, seed = families[k % len(families)], seed_offset + k
        generated = synth.generate_shape(category, family, seed)
        vertices, _ = unit_area(np.asarray(generated.vertices, np.float64), faces)
        shape = Shape.from_arrays(vertices, faces)
        sources = farthest_point_sampling(vertices, n_sources)
        gt = _cached_rows(shape, sources, cache_dir, f"{category}-{family}-{seed}")
        shapes.append(
            EvalShape(
                f"{family}-{seed}",
                f"synthetic {category}s (held-out seeds)",
                vertices,
                faces,
                sources,
                gt,
            )
        )
    return shapes


SETTING_FORMS = (
    "mesh, cloud_N (N ≥ 1 points), noise_S (std S ≥ 0), cut_P (0 ≤ P < 100 %), outliers_P "
    "(P ≥ 0 %), repeats_P (0 ≤ P ≤ 100 %), twins_S (std S ≥ 0), uneven_A (A ≥ 0), "
    "decimated_N (N ≥ 4 vertices) or meshnoise_S (std S ≥ 0)"
)
UNEVEN_CANDIDATES = 4
"""An ``uneven_A`` cloud is drawn from this many × its count of area-weighted samples."""


def parse_setting(setting: str) -> tuple[str, float]:
    """``(kind, value)`` of a setting name (see :func:`make_input`): ``"mesh"`` →
    ``("mesh", 0)``, ``"cloud_300"`` → ``("cloud", 300)``, ``"noise_0.01"`` →
    ``("noise", 0.01)``, ``"cut_10"`` → ``("cut", 10)``, ``"outliers_5"`` → ``("outliers", 5)``,
    ``"repeats_100"`` → ``("repeats", 100)``, ``"twins_0.001"`` → ``("twins", 0.001)``,
    ``"uneven_3"`` → ``("uneven", 3)``, ``"decimated_1000"`` → ``("decimated", 1000)``,
    ``"meshnoise_0.002"`` → ``("meshnoise", 0.002)``.

    Raises:
        InputError: any other name; the message lists the valid forms.
    """
    from litege_core.datasets.spec import is_count  # the datasets package: on first use

    kind, _, value = str(setting).partition("_")
    if setting == "mesh":
        return "mesh", 0.0
    if kind in ("cloud", "cut", "outliers", "repeats", "decimated") and is_count(value):
        number = int(value)
        if (kind == "cloud" and number >= 1) or (kind == "cut" and number < 100):
            return kind, float(number)
        if kind == "decimated" and number >= 4:
            return kind, float(number)
        if kind == "outliers" or (kind == "repeats" and number <= 100):
            return kind, float(number)
    elif kind in ("noise", "uneven", "twins", "meshnoise"):
        try:
            amount = float(value)
        except ValueError:
            amount = math.nan
        if math.isfinite(amount) and amount >= 0:
            return kind, amount
    raise InputError(
        f"unknown evaluation setting {setting!r}: expected {SETTING_FORMS} "
        f"(default {','.join(SETTINGS)})"
    )


def is_mesh_setting(setting: str) -> bool:
    """Whether the inputs of ``setting`` are meshes (``mesh``, ``decimated_N``,
    ``meshnoise_S``), not clouds."""
    return parse_setting(setting)[0] in ("mesh", "decimated", "meshnoise")


def parse_settings(text: str | None) -> list[str]:
    """``--settings``: comma-separated names, each checked by :func:`parse_setting`;
    ``None`` or ``""``: :data:`SETTINGS`.

    Raises:
        InputError: a bad name, or a list without names (``","``).
    """
    if not text:
        return list(SETTINGS)
    settings = [item.strip() for item in text.split(",") if item.strip()]
    if not settings:
        raise InputError(f"--settings names no setting, got {text!r}: give some of {SETTING_FORMS}")
    for setting in settings:
        parse_setting(setting)
    return settings


def make_input(shape: EvalShape, setting: str, seed: int) -> EvalInput:
    """The input of ``setting`` for ``shape`` (deterministic per seed): ``"mesh"``, a cloud of
    ``N`` surface samples ``"cloud_N"`` (the sources included), or a 2000-point cloud with
    Gaussian noise of that std (``"noise_0.01"``, unit-area units), cut by planes
    (``"cut_10"``: 10 %) or followed by stray points (``"outliers_5"``: 5 % of its count,
    uniform in its bounding box grown by 10 % per side; their ground truth is 0, so no pair
    that ends on one is scored), followed by exact copies of some of its points
    (``"repeats_100"``: every point sent twice, as a scan merged with itself; scored as their
    originals), followed by a copy of every point moved by Gaussian noise of that std
    (``"twins_0.001"``, unit-area units: a scan merged with a slightly moved copy of itself)
    or sampled unevenly (``"uneven_3"``: the density grows as
    ``exp(3 t)`` along the mesh's x axis, ``t`` from 0 to 1, so one end is e³ ≈ 20 times denser
    than the other, as a scan taken from one side; drawn from :data:`UNEVEN_CANDIDATES` × as
    many area-weighted samples), or the mesh simplified to about N vertices
    (``"decimated_1000"``: quadric edge collapse, :func:`~litege_core.variants.decimated_mesh`,
    as a low-poly asset; a new surface, so its ground truth is its own exact geodesics from as
    many farthest-point sources, rescaled to unit area: not cached, seconds per shape at a few
    thousand vertices), or the mesh with Gaussian noise of that std added to its vertices
    (``"meshnoise_0.002"``, unit-area units: a raw scan's mesh; its ground truth stays the
    clean surface's, vertex by vertex).

    Raises:
        InputError: a bad setting (see :func:`parse_setting`), or a cloud of fewer points
            than ``shape`` has sources.
    """
    kind, value = parse_setting(setting)
    if kind == "mesh":
        return EvalInput(Shape.from_arrays(shape.vertices, shape.faces), shape.sources, shape.gt)
    if kind == "meshnoise":  # the same vertices, moved; scored against the clean surface
        noisy = Shape.from_arrays(add_noise(shape.vertices, value, seed), shape.faces)
        return EvalInput(noisy, shape.sources, shape.gt)
    if kind == "decimated":
        vertices, faces = decimated_mesh(shape.vertices, shape.faces, int(value))
        vertices, _ = unit_area(vertices, faces)
        decimated = Shape.from_arrays(vertices, faces)
        sources = farthest_point_sampling(vertices, min(shape.sources.size, vertices.shape[0]))
        exact = compute_distances(decimated, sources, method="exact").distances
        return EvalInput(decimated, sources, exact)
    n_points = int(value) if kind == "cloud" else 2000
    n_sources = shape.sources.size
    if n_points < n_sources:
        raise InputError(
            f"setting {setting!r} has fewer points than the {n_sources} sources of {shape.name}"
        )
    if kind == "uneven":
        samples = _uneven_samples(shape, n_points - n_sources, value, seed)
    else:
        samples = sample_surface(shape.vertices, shape.faces, n_points - n_sources, seed)
    corner_gt = shape.gt[:, shape.faces[samples.face_index]]  # (R, n, 3)
    sample_gt = np.einsum("rnk,nk->rn", corner_gt, samples.barycentric)
    points = np.concatenate([shape.vertices[shape.sources], samples.points])
    gt = np.concatenate([shape.gt[:, shape.sources], sample_gt], axis=1)
    if kind == "noise":
        points = add_noise(points, value, seed)  # ground truth stays clean
    if kind == "outliers":  # appended after the surface points; 0: not scored
        points = add_outliers(points, value / 100.0, seed)
        gt = np.pad(gt, ((0, 0), (0, points.shape[0] - gt.shape[1])))
    if kind == "repeats":  # exact copies appended after the cloud, scored as their originals
        again = repeated_points(points.shape[0], value / 100.0, seed)
        points, gt = np.concatenate([points, points[again]]), np.concatenate([gt, gt[:, again]], 1)
    if kind == "twins":  # every point again, moved by noise; scored as their originals
        points = np.concatenate([points, add_noise(points, value, seed)])
        gt = np.concatenate([gt, gt], axis=1)
    kept = np.ones(points.shape[0], dtype=bool)
    if kind == "cut":
        kept = cut_by_planes(points, value / 100.0, seed)
    source_rows = np.flatnonzero(kept[:n_sources])
    new_index = np.cumsum(kept) - 1
    return EvalInput(
        Shape.from_arrays(points[kept]), new_index[source_rows], gt[np.ix_(source_rows, kept)]
    )


def _uneven_samples(shape: EvalShape, count: int, steepness: float, seed: int) -> SurfaceSamples:
    """``count`` surface samples of ``shape`` whose density grows as ``exp(steepness · t)``
    along its x axis (``t`` from 0 to 1), without replacement from
    :data:`UNEVEN_CANDIDATES` × ``count`` area-weighted samples (seeded)."""
    pool = sample_surface(shape.vertices, shape.faces, UNEVEN_CANDIDATES * count, seed)
    x = pool.points[:, 0]
    weights = np.exp(steepness * (x - x.min()) / max(float(np.ptp(x)), 1e-12))
    rng = np.random.default_rng(seed)
    pick = np.sort(rng.choice(len(x), count, replace=False, p=weights / weights.sum()))
    return SurfaceSamples(pool.points[pick], pool.face_index[pick], pool.barycentric[pick])


Method = Callable[[EvalInput], NDArray]


def register_in_frame(
    predictor, shape: Shape, candidates: str = "signs", *, margin: float = 0.0, seed: int = 0
):
    """Register ``shape`` in the frame :func:`~litege_core.learned.frame.select_frame` picks.

    Stand-in for ``Predictor.register`` with frame selection (until the predictor has it):
    the chosen transform, descriptor and residual go into a
    :class:`~litege_core.learned.state.ShapeRecord` that :meth:`Predictor.restore` embeds.
    ``candidates="pca"`` gives exactly ``predictor.register(shape, seed=seed)``.

    Returns:
        ``(state, choice)``: the :class:`ShapeState` and the :class:`FrameChoice`.
    """
    from litege_core.learned.describe import shape_samples
    from litege_core.learned.frame import select_frame

    points = shape_samples(shape, predictor.n_mesh_samples, seed)
    choice = select_frame(
        points, predictor.bundle.basis, predictor.device, candidates, margin=margin
    )
    return predictor.restore(shape, predictor.frame_record(shape, choice, seed=seed)), choice


def frame_turns(count: int, max_degrees: float, seed: int = 0) -> NDArray:
    """``(count + 1, 3, 3)``: the identity, then ``count`` rotations about random axes by
    angles uniform in ``[0, max_degrees]`` (the same draws as training's frame jitter)."""
    rng = np.random.default_rng([seed, count])
    turns = [small_rotation(np.radians(max_degrees), rng) for _ in range(count)]
    return np.stack([np.eye(3), *turns])


def litege_method(
    predictor, frame: str = "pca", margin: float = 0.0, turns: NDArray | None = None
) -> Method:
    """LiteGE through a :class:`~litege_core.learned.predictor.Predictor`; ``frame`` other
    than ``"pca"`` selects the canonical frame among those candidates (see
    :func:`register_in_frame`); ``turns`` ``(C, 3, 3)`` (:func:`frame_turns`) instead averages
    the distances predicted in the PCA frame turned by each (test-time augmentation)."""

    def run(item: EvalInput) -> NDArray:
        if turns is not None:
            states = predictor.register_turned(item.shape, turns)
            fields = predictor.distances_many(states, [item.source_index] * len(states))
            return np.mean(fields, axis=0)
        if frame == "pca":
            state = predictor.register(item.shape)
        else:
            state, _ = register_in_frame(predictor, item.shape, frame, margin=margin)
        return predictor.distances(state, item.source_index)

    return run


def baseline_method(name: str, **options) -> Method:
    def run(item: EvalInput) -> NDArray:
        return compute_distances(item.shape, item.source_index, method=name, **options).distances

    return run


def methods_for(setting: str, predictor, frames: Sequence[str] = ()) -> dict[str, Method]:
    methods = {"LiteGE": litege_method(predictor)}
    for frame in frames:
        methods[f"LiteGE (frame: {frame})"] = litege_method(predictor, frame)
    if is_mesh_setting(setting):
        methods["heat (mesh)"] = baseline_method("heat")
    else:
        methods["point-cloud heat"] = baseline_method("pointcloud_heat")
    methods[f"kNN Dijkstra (k={KNN_NEIGHBOURS})"] = baseline_method("knn_graph", k=KNN_NEIGHBOURS)
    return methods


@dataclass(frozen=True)
class SettingResult:
    group: str
    setting: str
    method: str
    mean: float
    median: float
    n_pairs: int
    unreachable: float  # fraction of pairs a graph method could not reach
    seconds: float
    per_shape: tuple[tuple[str, float], ...] = ()  # (shape name, its mean error), input order


def evaluate(
    shapes: Sequence[EvalShape],
    predictor,
    settings: Sequence[str] = SETTINGS,
    seed: int = 0,
    frames: Sequence[str] = (),
) -> list[SettingResult]:
    """Run every method on every (shape, setting); pooled errors per (group, setting, method).

    ``frames``: extra LiteGE rows with frame selection among these candidate sets
    (:data:`~litege_core.learned.frame.FRAME_CANDIDATES`, ``"pca"`` excluded)."""
    return evaluate_methods(
        shapes, lambda setting: methods_for(setting, predictor, frames), settings, seed
    )


def results_table(results: Sequence[SettingResult]) -> str:
    """Markdown table: error mean / median (GT mean 100), pairs, unreachable, seconds."""
    lines = [
        "| shapes | setting | method | mean error | median error | pairs | unreachable | time s |",
        "|---|---|---|---:|---:|---:|---:|---:|",
    ]
    for r in results:
        lines.append(
            f"| {r.group} | {r.setting} | {r.method} | {r.mean:.2f} | {r.median:.2f} | "
            f"{r.n_pairs} | {100 * r.unreachable:.1f} % | {r.seconds:.1f} |"
        )
    return "\n".join(lines)


# --------------------------------------------------------------------------- model comparison


def dataset_eval_shapes(
    dataset_dir: str | Path, split: str = "test", limit: int | None = None, group: str | None = None
) -> list[EvalShape]:
    """Shapes of one split of any geodesic dataset with their stored exact rows, at unit area:
    :func:`collection_eval_shapes` of a collection, :func:`synthetic_eval_shapes` of a
    template dataset (e.g. procedural quadrupeds in steep poses). ``group`` names them in the
    results (default: the dataset name and split)."""
    from litege_core.datasets import GeodesicDataset

    dataset = GeodesicDataset(dataset_dir)
    label = group or f"{dataset.spec.name} ({split})"
    if dataset.is_collection:
        return collection_eval_shapes(dataset_dir, split, limit, label)
    return synthetic_eval_shapes(dataset_dir, limit, split, label)


@dataclass(frozen=True)
class NamedEvalSet:
    """The shapes of one ``--sets`` entry of the fusion diagnoses (:func:`named_eval_set`), the
    shipped model of their category and the group label of the results."""

    shapes: list[EvalShape]
    model: str
    group: str


def named_eval_set(
    key: str,
    eval_root: str | Path,
    n_sources: int,
    cache_dir: str | Path | None,
    limit: int | None = None,
) -> NamedEvalSet:
    """A real dev set by its key (:data:`REAL_SETS`: exact rows from ``n_sources`` FPS
    sources, cached in ``cache_dir``) or ``DIR@MODEL``: the test split of a calibration dataset
    we build, answered by model ``MODEL`` (its stored rows and sources)."""
    if "@" in key:
        directory, model = key.split("@", 1)
        group = f"{Path(directory).name} (test, calibration data)"
        return NamedEvalSet(dataset_eval_shapes(directory, "test", limit), model, group)
    if key not in REAL_SETS:
        raise InputError(f"unknown set {key!r}; expected one of {sorted(REAL_SETS)} or DIR@MODEL")
    real = REAL_SETS[key]
    paths = real_shape_paths(eval_root, key, limit)
    return NamedEvalSet(
        real_eval_shapes(paths, real.group, n_sources, cache_dir), real.model, real.group
    )


def collection_eval_shapes(
    dataset_dir: str | Path,
    split: str = "test",
    limit: int | None = None,
    group: str | None = None,
) -> list[EvalShape]:
    """Shapes of one split of a collection dataset (each its own triangulation, e.g. the
    held-out files of ``litege train geodesic --meshes``) with their stored exact rows, at
    unit area. ``group`` names them in the results (default: the dataset name and split)."""
    from litege_core.datasets import GeodesicDataset, shape_mesh

    dataset = GeodesicDataset(dataset_dir)
    if not dataset.is_collection:
        raise InputError(f"{dataset_dir} is a template dataset: use synthetic_eval_shapes")
    table = dataset.load_split(split)
    label = group or f"{dataset.spec.name} ({split})"
    shapes = []
    count = table["seed"].shape[0] if limit is None else min(limit, table["seed"].shape[0])
    for i in range(count):
        raw_vertices, faces = shape_mesh(table, i)
        vertices, scale = unit_area(raw_vertices, faces)
        family = dataset.spec.families[int(table["family"][i])]
        shapes.append(
            EvalShape(
                name=f"{family}-{int(table['seed'][i])}",
                group=label,
                vertices=vertices,
                faces=faces,
                sources=table["sources"][i].astype(np.int64),
                gt=table["distances"][i][:, : vertices.shape[0]].astype(np.float64) * scale,
            )
        )
    return shapes


HEAT = "heat"
KNN = f"kNN Dijkstra (k={KNN_NEIGHBOURS})"


def comparison_methods(
    predictors: dict[str, object],
    baselines: bool = True,
    turns: dict[str, NDArray] | None = None,
) -> Callable[[str], dict[str, Method]]:
    """``setting → {name: method}`` for :func:`evaluate_methods`: one LiteGE row per named
    predictor (averaged over the frames ``turns[name]`` where given, :func:`litege_method`)
    and, with ``baselines``, the heat method (mesh heat on meshes, point-cloud heat on clouds,
    one name: :data:`HEAT`) and kNN-graph Dijkstra (:data:`KNN`)."""
    turns = turns or {}

    def methods(setting: str) -> dict[str, Method]:
        found = {
            name: litege_method(predictor, turns=turns.get(name))
            for name, predictor in predictors.items()
        }
        if baselines:
            heat = "heat" if is_mesh_setting(setting) else "pointcloud_heat"
            found[HEAT] = baseline_method(heat)
            found[KNN] = baseline_method("knn_graph", k=KNN_NEIGHBOURS)
        return found

    return methods


def evaluate_methods(
    shapes: Sequence[EvalShape],
    methods: Callable[[str], dict[str, Method]],
    settings: Sequence[str] = SETTINGS,
    seed: int = 0,
) -> list[SettingResult]:
    """:func:`evaluate` with any methods (e.g. :func:`comparison_methods`): pooled errors per
    (group, setting, method) on the same inputs (``make_input(shape, setting, seed + i)``), so
    results of separate calls with the same shapes, settings and seed are comparable.

    Raises:
        InputError: a bad setting name (checked before any work, see :func:`parse_setting`).
    """
    for setting in settings:
        parse_setting(setting)
    results = []
    for group in sorted({s.group for s in shapes}):
        members = [s for s in shapes if s.group == group]
        for setting in settings:
            inputs = [make_input(s, setting, seed + i) for i, s in enumerate(members)]
            for name, method in methods(setting).items():
                start = time.perf_counter()
                predicted, truth = [], []
                for item in inputs:
                    rows = np.asarray(method(item), dtype=np.float64)
                    if rows.shape != item.gt.shape:
                        raise ComputationError(f"{name} returned {rows.shape}, not {item.gt.shape}")
                    predicted.append(rows.ravel())
                    truth.append(item.gt.ravel())
                seconds = time.perf_counter() - start
                pred, gt = np.concatenate(predicted), np.concatenate(truth)
                owner = np.repeat(np.arange(len(inputs)), [t.size for t in truth])
                keep = gt > 0
                pred, gt, owner = pred[keep], gt[keep], owner[keep]
                finite = np.isfinite(pred)
                # Unreachable pairs (disconnected kNN graph) count as the largest finite guess.
                pred = np.where(finite, pred, np.nanmax(np.where(finite, pred, np.nan)))
                report = geodesic_error(pred, gt)
                per_shape = tuple(
                    (shape.name, geodesic_error(pred[owner == i], gt[owner == i]).mean)
                    for i, shape in enumerate(members)
                    if np.any(owner == i)
                )
                results.append(
                    SettingResult(
                        group,
                        setting,
                        name,
                        report.mean,
                        report.median,
                        report.n_pairs,
                        float(1 - finite.mean()),
                        seconds,
                        per_shape,
                    )
                )
    return results


def spread_table(results: Sequence[SettingResult]) -> str:
    """Markdown table of the per-shape spread of each (group, setting, method) row: the median
    and 90th percentile of the shapes' mean errors and the worst shape (GT mean = 100), so a
    pooled mean that hides a few failing shapes shows them."""
    lines = [
        "| shapes | setting | method | shapes | per-shape median | p90 | worst shape |",
        "|---|---|---|---:|---:|---:|---|",
    ]
    for r in results:
        if not r.per_shape:
            continue
        names = [name for name, _ in r.per_shape]
        errors = np.array([error for _, error in r.per_shape])
        worst = int(np.argmax(errors))
        lines.append(
            f"| {r.group} | {r.setting} | {r.method} | {errors.size} | "
            f"{np.median(errors):.2f} | {np.quantile(errors, 0.9):.2f} | "
            f"{names[worst]} {errors[worst]:.2f} |"
        )
    return "\n".join(lines)


def mean_by_method(results: Sequence[SettingResult]) -> dict[str, float]:
    """The mean error of each method averaged over its (group, setting) rows."""
    by_method: dict[str, list[float]] = {}
    for r in results:
        by_method.setdefault(r.method, []).append(r.mean)
    return {name: float(np.mean(values)) for name, values in by_method.items()}


def comparison_table(results: Sequence[SettingResult], methods: Sequence[str] = ()) -> str:
    """Markdown table, one row per (group, setting) and one column per method: mean error
    (median in parentheses), GT mean = 100, then a row of the means over the settings.
    ``methods`` orders the columns (default: first appearance)."""
    order = list(methods) or list(dict.fromkeys(r.method for r in results))
    cells = {(r.group, r.setting, r.method): r for r in results}
    rows = list(dict.fromkeys((r.group, r.setting) for r in results))
    lines = [
        "| shapes | setting | " + " | ".join(order) + " |",
        "|---|---|" + "---:|" * len(order),
    ]
    for group, setting in rows:
        values = []
        for name in order:
            r = cells.get((group, setting, name))
            values.append("–" if r is None else f"{r.mean:.2f} ({r.median:.2f})")
        lines.append(f"| {group} | {setting} | " + " | ".join(values) + " |")
    means = mean_by_method(results)
    average = " | ".join(f"**{means[name]:.2f}**" if name in means else "–" for name in order)
    lines.append("| all | mean over settings | " + average + " |")
    return "\n".join(lines)


__all__ = [
    "HEAT",
    "HELD_OUT_SEED_OFFSET",
    "KNN",
    "KNN_NEIGHBOURS",
    "REAL_SETS",
    "SETTINGS",
    "EvalInput",
    "EvalShape",
    "Method",
    "NamedEvalSet",
    "RealSet",
    "SettingResult",
    "baseline_method",
    "collection_eval_shapes",
    "comparison_methods",
    "comparison_table",
    "dataset_eval_shapes",
    "evaluate",
    "evaluate_methods",
    "frame_turns",
    "generated_eval_shapes",
    "litege_method",
    "make_input",
    "mean_by_method",
    "methods_for",
    "named_eval_set",
    "parse_setting",
    "parse_settings",
    "real_eval_shapes",
    "real_shape_paths",
    "register_in_frame",
    "results_table",
    "spread_table",
    "synthetic_eval_shapes",
    "unit_area",
]
