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
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from litege_core.errors import ComputationError
from litege_core.geodesics import compute_distances
from litege_core.metrics import geodesic_error
from litege_core.sampling import farthest_point_sampling, sample_surface
from litege_core.shape import Shape
from litege_core.variants import add_noise, cut_by_planes

SETTINGS = ("mesh", "cloud_2000", "cloud_300", "noise_0.01", "cut_10", "cut_15")
KNN_NEIGHBOURS = 10


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


def synthetic_eval_shapes(dataset_dir: str | Path, limit: int, split: str = "test") -> list:
    """Shapes of a dataset split with their stored exact rows, at unit area."""
    from litege_core.datasets import GeodesicDataset

    dataset = GeodesicDataset(dataset_dir)
    table = dataset.load_split(split)
    shapes = []
    for i in range(min(limit, table["vertices"].shape[0])):
        vertices, scale = unit_area(table["vertices"][i].astype(np.float64), dataset.faces)
        family = dataset.spec.families[int(table["family"][i])]
        shapes.append(
            EvalShape(
                name=f"{family}-{int(table['seed'][i])}",
                group="synthetic (held-out seeds)",
                vertices=vertices,
                faces=dataset.faces,
                sources=table["sources"][i].astype(np.int64),
                gt=table["distances"][i].astype(np.float64) * scale,
            )
        )
    return shapes


def real_eval_shapes(paths: Iterable[Path], group: str, n_sources: int) -> list[EvalShape]:
    """Real meshes with exact rows from ``n_sources`` farthest-point sources, at unit area."""
    from litege_core.io import load_shape

    shapes = []
    for path in paths:
        loaded = load_shape(path)
        vertices, _ = unit_area(loaded.vertices, loaded.faces)
        shape = Shape.from_arrays(vertices, loaded.faces)
        sources = farthest_point_sampling(vertices, n_sources)
        gt = compute_distances(shape, sources, method="exact").distances
        shapes.append(EvalShape(Path(path).stem, group, vertices, shape.faces, sources, gt))
    return shapes


def make_input(shape: EvalShape, setting: str, seed: int) -> EvalInput:
    """The input of ``setting`` for ``shape`` (deterministic per seed)."""
    if setting == "mesh":
        return EvalInput(Shape.from_arrays(shape.vertices, shape.faces), shape.sources, shape.gt)
    n_points = 300 if setting == "cloud_300" else 2000
    n_sources = shape.sources.size
    samples = sample_surface(shape.vertices, shape.faces, n_points - n_sources, seed)
    corner_gt = shape.gt[:, shape.faces[samples.face_index]]  # (R, n, 3)
    sample_gt = np.einsum("rnk,nk->rn", corner_gt, samples.barycentric)
    points = np.concatenate([shape.vertices[shape.sources], samples.points])
    gt = np.concatenate([shape.gt[:, shape.sources], sample_gt], axis=1)
    if setting == "noise_0.01":
        points = add_noise(points, 0.01, seed)  # unit-area units; ground truth stays clean
    kept = np.ones(points.shape[0], dtype=bool)
    if setting.startswith("cut_"):
        kept = cut_by_planes(points, int(setting[4:]) / 100.0, seed)
    source_rows = np.flatnonzero(kept[:n_sources])
    new_index = np.cumsum(kept) - 1
    return EvalInput(
        Shape.from_arrays(points[kept]), new_index[source_rows], gt[np.ix_(source_rows, kept)]
    )


Method = Callable[[EvalInput], NDArray]


def litege_method(predictor) -> Method:
    """LiteGE through a :class:`~litege_core.predictor.Predictor`."""

    def run(item: EvalInput) -> NDArray:
        state = predictor.register(item.shape)
        return predictor.distances(state, item.source_index)

    return run


def baseline_method(name: str, **options) -> Method:
    def run(item: EvalInput) -> NDArray:
        return compute_distances(item.shape, item.source_index, method=name, **options).distances

    return run


def methods_for(setting: str, predictor) -> dict[str, Method]:
    methods = {"LiteGE": litege_method(predictor)}
    if setting == "mesh":
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


def evaluate(
    shapes: Sequence[EvalShape], predictor, settings: Sequence[str] = SETTINGS, seed: int = 0
) -> list[SettingResult]:
    """Run every method on every (shape, setting); pooled errors per (group, setting, method)."""
    results = []
    groups = sorted({s.group for s in shapes})
    for group in groups:
        members = [s for s in shapes if s.group == group]
        for setting in settings:
            inputs = [make_input(s, setting, seed + i) for i, s in enumerate(members)]
            for name, method in methods_for(setting, predictor).items():
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
                keep = gt > 0
                pred, gt = pred[keep], gt[keep]
                finite = np.isfinite(pred)
                # Unreachable pairs (disconnected kNN graph) count as the largest finite guess.
                pred = np.where(finite, pred, np.nanmax(np.where(finite, pred, np.nan)))
                report = geodesic_error(pred, gt)
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
                    )
                )
    return results


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
