"""Building ground-truth geodesic datasets: exact distances, parallel, resumable.

For every shape: generate it from (family, seed), pick the shared sources plus
``n_extra_sources`` random ones, compute exact geodesic rows source → all vertices, and append
to the current shard. Shapes are computed in a process pool (one shape per task, results
consumed in order), shards are written atomically and recorded in the manifest with their
SHA-256, so a build that is interrupted resumes where it stopped and a finished build is
verifiable.
"""

from __future__ import annotations

import math
import multiprocessing
import platform
import time
from collections.abc import Callable, Iterator
from concurrent.futures import ProcessPoolExecutor
from datetime import UTC, datetime
from pathlib import Path
from typing import NamedTuple, Protocol

import numpy as np
from numpy.typing import NDArray

from litege_core.datasets.spec import FORMAT_VERSION, SPLIT_SEED_OFFSETS, SPLITS, DatasetSpec
from litege_core.datasets.storage import (
    MANIFEST,
    SHARD_KEYS,
    TEMPLATE,
    file_sha256,
    read_manifest,
    read_tensors,
    shard_name,
    write_json_atomic,
    write_tensors_atomic,
)
from litege_core.errors import ArtifactError, ComputationError, InputError

DistanceFn = Callable[[NDArray, NDArray, NDArray], NDArray]
FLOAT16_MAX = float(np.finfo(np.float16).max)


class ShapeFactory(Protocol):
    """Generates shapes of one category that all share the template's faces."""

    category: str
    version: str

    def template(self) -> tuple[NDArray, NDArray]:
        """``(vertices (V, 3), faces (F, 3))`` of the category's template."""

    def generate(self, family: str, seed: int) -> NDArray:
        """Vertices ``(V, 3)`` of the shape (family, seed), on the template's faces."""


def exact_distance_rows(vertices: NDArray, faces: NDArray, sources: NDArray) -> NDArray:
    """Exact (MMP) geodesic rows ``(R, V)`` from ``sources`` to every vertex."""
    from litege_core.geodesics import compute_distances
    from litege_core.shape import Shape

    return compute_distances(Shape.from_arrays(vertices, faces), sources, method="exact").distances


def heat_distance_rows(vertices: NDArray, faces: NDArray, sources: NDArray) -> NDArray:
    """Heat-method geodesic rows ``(R, V)`` (potpourri3d; ~2 % mean relative error vs exact,
    about 80× faster: see BENCHMARKS.md "geodesic-engines")."""
    from litege_core.geodesics import compute_distances
    from litege_core.shape import Shape

    return compute_distances(Shape.from_arrays(vertices, faces), sources, method="heat").distances


SOLVERS: dict[str, tuple[DistanceFn, str]] = {
    "exact": (exact_distance_rows, "exact MMP (litege_core.geodesics, method='exact')"),
    "heat": (
        heat_distance_rows,
        "heat method (litege_core.geodesics, method='heat'; ~2 % mean relative error vs exact)",
    ),
}
"""Ground-truth solvers a dataset can be built with: name → (row function, manifest text)."""


def shared_sources(template_vertices: NDArray, n_sources: int) -> NDArray:
    """``(n,)`` int64 farthest-point samples of the template, starting at vertex 0."""
    from litege_core.sampling import farthest_point_sampling

    return np.asarray(farthest_point_sampling(template_vertices, n_sources), dtype=np.int64)


def extra_sources(n_vertices: int, shared: NDArray, n_extra: int, seed: int) -> NDArray:
    """``(n_extra,)`` random vertices outside ``shared``, a pure function of ``seed``."""
    rng = np.random.default_rng([seed, 0x5EED])
    candidates = np.setdiff1d(np.arange(n_vertices), shared)
    return np.sort(rng.choice(candidates, size=n_extra, replace=False))


class ShapeRecord(NamedTuple):
    vertices: NDArray
    sources: NDArray
    distances: NDArray
    area: float
    seconds: float


_WORKER: dict = {}


def _init_worker(factory: ShapeFactory, distance_fn: DistanceFn, shared: NDArray, faces) -> None:
    _WORKER.update(factory=factory, distance_fn=distance_fn, shared=shared, faces=faces)


def _compute_shape(job: tuple[str, int, int]) -> ShapeRecord:
    family, seed, n_extra = job
    start = time.perf_counter()
    factory, faces, shared = _WORKER["factory"], _WORKER["faces"], _WORKER["shared"]
    vertices = np.asarray(factory.generate(family, seed), dtype=np.float64)
    sources = np.concatenate([shared, extra_sources(vertices.shape[0], shared, n_extra, seed)])
    distances = np.asarray(_WORKER["distance_fn"](vertices, faces, sources), dtype=np.float64)
    if distances.shape != (sources.size, vertices.shape[0]) or not np.isfinite(distances).all():
        raise ComputationError(f"bad geodesic rows for {family} seed {seed}")
    corners = vertices[faces]
    area = (
        0.5
        * np.linalg.norm(
            np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1
        ).sum()
    )
    return ShapeRecord(vertices, sources, distances, float(area), time.perf_counter() - start)


def _pool_map(jobs: list, workers: int, initargs: tuple) -> Iterator[ShapeRecord]:
    if workers <= 1:
        _init_worker(*initargs)
        yield from map(_compute_shape, jobs)
        return
    # fork keeps the factory importable in workers (no re-import of test or script modules).
    context = multiprocessing.get_context("fork")
    with ProcessPoolExecutor(workers, context, _init_worker, initargs) as pool:
        yield from pool.map(_compute_shape, jobs, chunksize=1)


def _stack_shard(records: list[ShapeRecord], keys: list[tuple[str, int]], spec, split) -> dict:
    distances = np.stack([r.distances for r in records])
    dtype = spec.distance_dtype(split)
    if dtype == "float16" and distances.max() > FLOAT16_MAX:
        raise ComputationError("distances overflow float16; store this split as float32")
    return {
        "vertices": np.stack([r.vertices for r in records]).astype(np.float32),
        "sources": np.stack([r.sources for r in records]).astype(np.int32),
        "distances": distances.astype(dtype),
        "area": np.array([r.area for r in records], dtype=np.float64),
        "seed": np.array([seed for _, seed in keys], dtype=np.int64),
        "family": np.array([spec.families.index(f) for f, _ in keys], dtype=np.int64),
    }


def _relative_storage_error(stored: NDArray, exact: NDArray) -> float:
    positive = exact > 0
    return float((np.abs(stored[positive] - exact[positive]) / exact[positive]).max())


def _new_manifest(spec: DatasetSpec, factory: ShapeFactory, solver: str) -> dict:
    return {
        "format_version": FORMAT_VERSION,
        "spec": json_spec(spec),
        "generator": {"category": factory.category, "version": factory.version},
        "distance_dtype": {split: spec.distance_dtype(split) for split in SPLITS},
        "seed_offsets": SPLIT_SEED_OFFSETS,
        "solver": solver,
        "units": "raw shape units; divide by sqrt(area) for unit-area units",
        "shards": {},
        "counts": {split: 0 for split in SPLITS},
        "compute_seconds": 0.0,
        "created": datetime.now(UTC).isoformat(timespec="seconds"),
    }


def json_spec(spec: DatasetSpec) -> dict:
    import json

    return json.loads(spec.to_json())


def build_dataset(
    spec: DatasetSpec,
    directory: str | Path,
    factory: ShapeFactory,
    *,
    workers: int = 1,
    distance_fn: DistanceFn | None = None,
    solver: str = "exact",
    progress: bool = True,
) -> dict:
    """Build (or resume) the dataset ``spec`` in ``directory``; returns the manifest.

    ``solver`` names one of :data:`SOLVERS` (recorded in the manifest); ``distance_fn``
    replaces it with a custom row function (tests).

    Raises:
        ArtifactError: ``directory`` holds a dataset of a different spec, generator or solver.
    """
    if distance_fn is None:
        if solver not in SOLVERS:
            raise InputError(f"unknown solver {solver!r}; expected one of {sorted(SOLVERS)}")
        distance_fn, description = SOLVERS[solver]
    else:
        description = f"custom ({getattr(distance_fn, '__name__', 'function')})"
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    if (directory / MANIFEST).exists():
        manifest = read_manifest(directory)
        fresh = _new_manifest(spec, factory, description)
        expected = {key: fresh[key] for key in ("spec", "generator", "solver")}
        for key, value in expected.items():
            if manifest.get(key) != value:
                raise ArtifactError(
                    f"{directory} holds a dataset with another {key}; use a new directory"
                )
    else:
        manifest = _new_manifest(spec, factory, description)

    template_vertices, faces = factory.template()
    faces = np.asarray(faces, dtype=np.int64)
    shared = shared_sources(np.asarray(template_vertices), spec.n_shared_sources)
    if not (directory / TEMPLATE).exists():
        write_tensors_atomic(
            directory / TEMPLATE,
            {
                "faces": faces,
                "shared_sources": shared,
                "template_vertices": np.asarray(template_vertices, dtype=np.float32),
            },
        )

    pending = _pending_shards(spec, directory, manifest)
    jobs = [
        (*spec.shape_key(split, index), spec.n_extra_sources)
        for split, shard, indices in pending
        for index in indices
    ]
    if not jobs:
        return manifest
    bar = _progress(len(jobs), f"{spec.name}: shapes", progress)
    results = _pool_map(jobs, workers, (factory, distance_fn, shared, faces))
    started = time.perf_counter()
    for split, shard, indices in pending:
        records = []
        for _ in indices:
            records.append(next(results))
            bar.update(1)
        keys = [spec.shape_key(split, index) for index in indices]
        tensors = _stack_shard(records, keys, spec, split)
        name = shard_name(split, shard)
        manifest["shards"][name] = {
            "split": split,
            "first_index": indices[0],
            "n_shapes": len(indices),
            "sha256": write_tensors_atomic(directory / name, tensors),
            "max_relative_storage_error": _relative_storage_error(
                tensors["distances"].astype(np.float64), np.stack([r.distances for r in records])
            ),
        }
        manifest["compute_seconds"] += sum(r.seconds for r in records)
        _update_counts(manifest)
        manifest["updated"] = datetime.now(UTC).isoformat(timespec="seconds")
        manifest["host"] = {
            "machine": platform.machine(),
            "cpus": multiprocessing.cpu_count(),
            "workers": workers,
        }
        manifest["wall_seconds_last_run"] = time.perf_counter() - started
        write_json_atomic(directory / MANIFEST, manifest)
    bar.close()
    write_json_atomic(directory / MANIFEST, manifest)
    return manifest


def _pending_shards(spec: DatasetSpec, directory: Path, manifest: dict) -> list:
    pending = []
    for split in SPLITS:
        total = spec.n_shapes.get(split, 0)
        for shard in range(math.ceil(total / spec.shard_size)):
            name = shard_name(split, shard)
            entry = manifest["shards"].get(name)
            path = directory / name
            if entry is not None and path.exists() and file_sha256(path) == entry["sha256"]:
                continue
            manifest["shards"].pop(name, None)
            first = shard * spec.shard_size
            pending.append((split, shard, list(range(first, min(first + spec.shard_size, total)))))
    return pending


def _update_counts(manifest: dict) -> None:
    counts = {split: 0 for split in SPLITS}
    for entry in manifest["shards"].values():
        counts[entry["split"]] += entry["n_shapes"]
    manifest["counts"] = counts


def _progress(total: int, description: str, enabled: bool):
    from tqdm.auto import tqdm

    return tqdm(total=total, desc=description, unit="shape", disable=not enabled)


def verify_dataset(directory: str | Path) -> dict:
    """Check every shard's hash, array shapes and values against the manifest.

    Returns ``{"shards": n, "counts": {...}}``; raises ArtifactError on any mismatch.
    """
    directory = Path(directory)
    manifest = read_manifest(directory)
    template = read_tensors(directory / TEMPLATE, ("faces", "shared_sources"))
    n_vertices = int(template["faces"].max()) + 1
    for name, entry in sorted(manifest["shards"].items()):
        path = directory / name
        if not path.exists():
            raise ArtifactError(f"shard {name} listed in the manifest is missing")
        if file_sha256(path) != entry["sha256"]:
            raise ArtifactError(f"shard {name} does not match its manifest hash")
        tensors = read_tensors(path, SHARD_KEYS)
        n_shapes, n_rows, width = tensors["distances"].shape
        if n_shapes != entry["n_shapes"] or width < n_vertices:
            raise ArtifactError(f"shard {name} has inconsistent array shapes")
        if not np.array_equal(
            tensors["sources"][:, : template["shared_sources"].size],
            np.broadcast_to(
                template["shared_sources"], (n_shapes, template["shared_sources"].size)
            ),
        ):
            raise ArtifactError(f"shard {name} does not start with the shared sources")
        if not np.isfinite(tensors["distances"]).all() or n_rows != tensors["sources"].shape[1]:
            raise ArtifactError(f"shard {name} has non-finite or misshapen distances")
    return {"shards": len(manifest["shards"]), "counts": manifest["counts"]}
