"""Building ground-truth geodesic datasets: exact distances, parallel, resumable.

For every shape: generate it from (family, seed), pick the shared sources plus
``n_extra_sources`` random ones, compute exact geodesic rows source → all vertices, and append
to the current shard. Collection datasets (``spec.kind == "collection"``) take shapes with
their own triangulations from a :class:`CollectionFactory`; their sources are
``n_shared_sources`` farthest-point samples of each shape (from its vertex 0) plus the random
extras, and shards pad shapes to a common size (see :mod:`litege_core.datasets.storage`).

Shapes are computed in a process pool (one shape per task, results consumed in order), shards
are written atomically and recorded in the manifest with their SHA-256, so a build that is
interrupted resumes where it stopped and a finished build is verifiable.

**Sharded builds** (past one machine). ``build_dataset(..., part=WorkShare(I, N))`` (``litege
data build --shard I/N``) builds only the shard files whose build-order ordinal ``k`` has
``k mod N == I`` and records them in its own partial manifest ``manifest.part-I-of-N.json``
(never in ``manifest.json``), writing through unique temporary names, so ``N`` workers share
one directory (a shared volume) without touching each other's files. Each worker is resumable
and idempotent like a single-process build: a rerun skips the files whose hash matches its
partial manifest (or ``manifest.json``) and redoes missing or damaged ones. Shard contents
depend only on (spec, factory, solver), so :func:`merge_dataset` (``litege data merge``)
assembles a ``manifest.json`` whose shard hashes equal those of a single-process build of the
same spec, and verifies the result.
"""

from __future__ import annotations

import json
import math
import multiprocessing
import os
import platform
import secrets
import time
from collections.abc import Callable, Iterator
from concurrent.futures import ProcessPoolExecutor
from datetime import UTC, datetime
from pathlib import Path
from typing import NamedTuple, Protocol

import numpy as np
from numpy.typing import NDArray

from litege_core.datasets.spec import SPLIT_SEED_OFFSETS, SPLITS, DatasetSpec, WorkShare
from litege_core.datasets.storage import (
    COLLECTION_KEYS,
    FACE_PAD,
    MANIFEST,
    SHARD_KEYS,
    TEMPLATE,
    pad_axis,
    read_manifest,
    shard_name,
)
from litege_core.errors import ArtifactError, ComputationError, InputError
from litege_core.files import (
    file_sha256,
    make_directory,
    read_tensors,
    write_json_atomic,
    write_tensors_atomic,
)

DistanceFn = Callable[[NDArray, NDArray, NDArray], NDArray]
FLOAT16_MAX = float(np.finfo(np.float16).max)


class ShapeFactory(Protocol):
    """Generates shapes of one category that all share the template's faces."""

    @property
    def category(self) -> str:
        """The category written into the dataset's manifest."""

    @property
    def version(self) -> str:
        """The generator version; a dataset built by another version is not resumed."""

    def template(self) -> tuple[NDArray, NDArray]:
        """``(vertices (V, 3), faces (F, 3))`` of the category's template."""

    def generate(self, family: str, seed: int) -> NDArray:
        """Vertices ``(V, 3)`` of the shape (family, seed), on the template's faces."""


class CollectionFactory(Protocol):
    """Generates shapes that each have their own triangulation (collection datasets)."""

    @property
    def category(self) -> str:
        """The category written into the dataset's manifest."""

    @property
    def version(self) -> str:
        """The generator version; a dataset built by another version is not resumed."""

    def generate_mesh(self, family: str, seed: int) -> tuple[NDArray, NDArray]:
        """``(vertices (V, 3), faces (F, 3))`` of the shape (family, seed): a closed (or at
        least edge-manifold) mesh on which the solver's geodesics are defined."""


def exact_distance_rows(vertices: NDArray, faces: NDArray, sources: NDArray) -> NDArray:
    """Exact (MMP) geodesic rows ``(R, V)`` from ``sources`` to every vertex."""
    from litege_core.engines import compute_distances
    from litege_core.shape import Shape

    return compute_distances(Shape.from_arrays(vertices, faces), sources, method="exact").distances


def heat_distance_rows(
    vertices: NDArray, faces: NDArray, sources: NDArray, t_coef: float = 1.0
) -> NDArray:
    """Heat-method geodesic rows ``(R, V)`` (potpourri3d, diffusion time ``t_coef`` × the squared
    mean edge length; ~2 % mean relative error vs exact at 1, about 40× faster: see
    BENCHMARKS.md "heat-targets")."""
    from litege_core.engines import compute_distances
    from litege_core.shape import Shape

    mesh = Shape.from_arrays(vertices, faces)
    return compute_distances(mesh, sources, method="heat", t_coef=t_coef).distances


FINE_HEAT_T_COEF = 0.35
"""Diffusion time of the ``heat-fine`` solver: on posed rigged animals and MakeHuman bodies it
halves the heat method's error against exact MMP (1.6 → 0.9 and 2.0 → 0.8, GT mean 100) and
its bias, at the same cost (BENCHMARKS.md "heat-targets"). Shapes with thin parts (legs, arms,
tails) gain; on a round sphere the default time is the better one."""


def fine_heat_distance_rows(vertices: NDArray, faces: NDArray, sources: NDArray) -> NDArray:
    """:func:`heat_distance_rows` at :data:`FINE_HEAT_T_COEF`."""
    return heat_distance_rows(vertices, faces, sources, FINE_HEAT_T_COEF)


SOLVERS: dict[str, tuple[DistanceFn, str]] = {
    "exact": (exact_distance_rows, "exact MMP (litege_core.engines, method='exact')"),
    "heat": (
        heat_distance_rows,
        "heat method (litege_core.engines, method='heat'; ~2 % mean relative error vs exact)",
    ),
    "heat-fine": (
        fine_heat_distance_rows,
        f"heat method (litege_core.engines, method='heat', t_coef={FINE_HEAT_T_COEF}; "
        "~0.9 % mean relative error vs exact)",
    ),
}
"""Ground-truth solvers a dataset can be built with: name → (row function, manifest text)."""

LEGACY_SOLVER_TEXT = {
    "exact MMP (litege_core.geodesics, method='exact')": SOLVERS["exact"][1],
    "heat method (litege_core.geodesics, method='heat'; ~2 % mean relative error vs exact)": (
        SOLVERS["heat"][1]
    ),
}
"""Manifest texts written before the engines package was renamed (same solvers): a dataset
started then resumes with the current code."""


def shared_sources(template_vertices: NDArray, n_sources: int) -> NDArray:
    """``(n,)`` int64 farthest-point samples of the template, starting at vertex 0."""
    from litege_core.sampling import farthest_point_sampling

    return np.asarray(farthest_point_sampling(template_vertices, n_sources), dtype=np.int64)


def extra_sources(n_vertices: int, shared: NDArray, n_extra: int, seed: int) -> NDArray:
    """``(n_extra,)`` random vertices outside ``shared``, a pure function of ``seed``."""
    rng = np.random.default_rng([seed, 0x5EED])
    candidates = np.setdiff1d(np.arange(n_vertices), shared)
    return np.sort(rng.choice(candidates, size=n_extra, replace=False))


def shape_sources(vertices: NDArray, n_fps: int, n_extra: int, seed: int) -> NDArray:
    """``(n_fps + n_extra,)`` int64 sources of a collection shape: farthest-point samples of
    its vertices from vertex 0, then ``n_extra`` seeded random other vertices."""
    from litege_core.sampling import farthest_point_sampling

    n_vertices = vertices.shape[0]
    if n_fps + n_extra > n_vertices:
        raise ComputationError(
            f"a shape of {n_vertices} vertices cannot have {n_fps + n_extra} sources"
        )
    fps = np.asarray(farthest_point_sampling(vertices, n_fps), dtype=np.int64)
    return np.concatenate([fps, extra_sources(n_vertices, fps, n_extra, seed)])


def surface_area(vertices: NDArray, faces: NDArray) -> float:
    """Total area of a triangle mesh (raw units²)."""
    corners = vertices[faces]
    return float(
        0.5
        * np.linalg.norm(
            np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1
        ).sum()
    )


class ShapeRecord(NamedTuple):
    vertices: NDArray
    sources: NDArray
    distances: NDArray
    area: float
    seconds: float
    faces: NDArray | None = None  # collection shapes only


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


def _init_collection_worker(factory: CollectionFactory, distance_fn: DistanceFn) -> None:
    _WORKER.update(factory=factory, distance_fn=distance_fn)


def _compute_collection_shape(job: tuple[str, int, int, int]) -> ShapeRecord:
    family, seed, n_fps, n_extra = job
    start = time.perf_counter()
    vertices, faces = _WORKER["factory"].generate_mesh(family, seed)
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    if faces.ndim != 2 or faces.shape[1] != 3 or faces.min() < 0 or faces.max() >= len(vertices):
        raise ComputationError(f"the factory returned a bad mesh for {family} seed {seed}")
    sources = shape_sources(vertices, n_fps, n_extra, seed)
    distances = np.asarray(_WORKER["distance_fn"](vertices, faces, sources), dtype=np.float64)
    if distances.shape != (sources.size, vertices.shape[0]) or not np.isfinite(distances).all():
        raise ComputationError(f"bad geodesic rows for {family} seed {seed}")
    area = surface_area(vertices, faces)
    return ShapeRecord(vertices, sources, distances, area, time.perf_counter() - start, faces)


def _pool_map(
    jobs: list, workers: int, initargs: tuple, collection: bool = False
) -> Iterator[ShapeRecord]:
    init = _init_collection_worker if collection else _init_worker
    compute = _compute_collection_shape if collection else _compute_shape
    if workers <= 1:
        init(*initargs)
        yield from map(compute, jobs)
        return
    # fork keeps the factory importable in workers (no re-import of test or script modules).
    context = multiprocessing.get_context("fork")
    with ProcessPoolExecutor(workers, context, init, initargs) as pool:
        yield from pool.map(compute, jobs, chunksize=1)


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


def _stack_collection_shard(records: list[ShapeRecord], keys, spec, split) -> dict:
    faces = [r.faces for r in records]
    if any(f is None for f in faces):
        raise ComputationError("a collection shape has no faces")
    n_v = max(r.vertices.shape[0] for r in records)
    n_f = max(f.shape[0] for f in faces if f is not None)
    distances = np.stack([pad_axis(r.distances, n_v, 1) for r in records])
    dtype = spec.distance_dtype(split)
    if dtype == "float16" and distances.max() > FLOAT16_MAX:
        raise ComputationError("distances overflow float16; store this split as float32")
    return {
        "vertices": np.stack([pad_axis(r.vertices, n_v, 0) for r in records]).astype(np.float32),
        "faces": np.stack([pad_axis(f, n_f, 0, FACE_PAD) for f in faces if f is not None]).astype(
            np.int32
        ),
        "n_vertices": np.array([r.vertices.shape[0] for r in records], dtype=np.int64),
        "n_faces": np.array([f.shape[0] for f in faces if f is not None], dtype=np.int64),
        "sources": np.stack([r.sources for r in records]).astype(np.int32),
        "distances": distances.astype(dtype),
        "area": np.array([r.area for r in records], dtype=np.float64),
        "seed": np.array([seed for _, seed in keys], dtype=np.int64),
        "family": np.array([spec.families.index(f) for f, _ in keys], dtype=np.int64),
    }


def _relative_storage_error(stored: NDArray, exact: NDArray) -> float:
    positive = exact > 0
    return float((np.abs(stored[positive] - exact[positive]) / exact[positive]).max())


def _new_manifest(spec: DatasetSpec, factory, solver: str) -> dict:
    manifest = {
        "format_version": spec.format_version,
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
    if spec.is_collection:
        manifest["kind"] = "collection"
        manifest["layout"] = "padded per shard; see litege_core.datasets.storage"
    return manifest


def json_spec(spec: DatasetSpec) -> dict:
    import json

    return json.loads(spec.to_json())


PART_MANIFEST_GLOB = "manifest.part-*-of-*.json"


def part_manifest_name(share: WorkShare) -> str:
    """``manifest.part-IIIII-of-NNNNN.json``: the partial manifest of one worker's share."""
    return f"manifest.part-{share.index:05d}-of-{share.count:05d}.json"


def _work_share(part: WorkShare | tuple[int, int] | str | None) -> WorkShare | None:
    if part is None or isinstance(part, WorkShare):
        return part
    if isinstance(part, str):
        return WorkShare.parse(part)
    index, count = part
    return WorkShare(index, count)


def _check_same_dataset(found: dict, expected: dict, directory: Path, what: str = "") -> None:
    """ArtifactError unless ``found`` (a manifest) has the spec, generator and solver of
    ``expected`` (solver texts of before the engines rename count as the current ones)."""
    found = dict(found)
    solver = found.get("solver")
    if isinstance(solver, str):
        found["solver"] = LEGACY_SOLVER_TEXT.get(solver, solver)
    for key in ("spec", "generator", "solver"):
        if found.get(key) != expected[key]:
            raise ArtifactError(
                f"{directory}{what} holds a dataset with another {key}; use a new directory"
            )


def _unique_temporary(path: Path) -> Path:
    return path.with_name(f"{path.name}.tmp-{os.getpid()}-{secrets.token_hex(4)}")


def _write_tensors_unique(path: Path, tensors: dict) -> str:
    """:func:`write_tensors_atomic` through a temporary name no other writer uses, so that
    processes writing the same file at once (identical bytes) never mix their writes."""
    from safetensors.numpy import save_file

    temporary = _unique_temporary(path)
    try:
        save_file({k: np.ascontiguousarray(v) for k, v in tensors.items()}, str(temporary))
        os.replace(temporary, path)
    finally:
        temporary.unlink(missing_ok=True)
    return file_sha256(path)


def _write_json_unique(path: Path, data: dict) -> None:
    """:func:`write_json_atomic` through a temporary name no other writer uses."""
    temporary = _unique_temporary(path)
    try:
        temporary.write_text(json.dumps(data, indent=2, sort_keys=True) + "\n")
        os.replace(temporary, path)
    finally:
        temporary.unlink(missing_ok=True)


def _read_json(path: Path) -> dict:
    try:
        data = json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise ArtifactError(f"{path} is not valid JSON: {exc}") from exc
    if not isinstance(data, dict):
        raise ArtifactError(f"{path} is not a manifest")
    return data


def _build_part(
    spec: DatasetSpec,
    directory: Path,
    factory,
    share: WorkShare,
    workers: int,
    distance_fn: DistanceFn,
    description: str,
    progress: bool,
) -> dict:
    """Worker ``share``'s part of a sharded build, recorded in its partial manifest."""
    fresh = _new_manifest(spec, factory, description)
    done: dict = {}
    if (directory / MANIFEST).exists():
        merged = read_manifest(directory)
        _check_same_dataset(merged, fresh, directory)
        done = merged.get("shards", {})
    path = directory / part_manifest_name(share)
    for other in sorted(directory.glob(PART_MANIFEST_GLOB)):  # the other workers' too
        _check_same_dataset(_read_json(other), fresh, directory, f" ({other.name})")
    manifest = _read_json(path) if path.exists() else fresh
    manifest["work_share"] = {"index": share.index, "count": share.count}
    output = _Output(manifest, path.name, share, done)
    return _build_shards(spec, directory, factory, output, workers, distance_fn, progress)


def build_dataset(
    spec: DatasetSpec,
    directory: str | Path,
    factory: ShapeFactory | CollectionFactory,
    *,
    workers: int = 1,
    distance_fn: DistanceFn | None = None,
    solver: str = "exact",
    progress: bool = True,
    part: WorkShare | tuple[int, int] | str | None = None,
) -> dict:
    """Build (or resume) the dataset ``spec`` in ``directory``; returns the manifest.

    ``solver`` names one of :data:`SOLVERS` (recorded in the manifest); ``distance_fn``
    replaces it with a custom row function (tests). A collection spec needs a
    :class:`CollectionFactory`, a template spec a :class:`ShapeFactory`.

    ``part`` (a :class:`WorkShare`, ``(I, N)`` or ``"I/N"``) builds only worker ``I``'s share
    of the shard files and returns its partial manifest (``manifest.part-I-of-N.json``);
    :func:`merge_dataset` assembles ``manifest.json`` once every share is built (see the
    module docstring). Shards already listed in ``manifest.json`` are not rebuilt.

    Raises:
        ArtifactError: ``directory`` holds a dataset of a different spec, generator or solver.
    """
    if distance_fn is None:
        if solver not in SOLVERS:
            raise InputError(f"unknown solver {solver!r}; expected one of {sorted(SOLVERS)}")
        distance_fn, description = SOLVERS[solver]
    else:
        description = f"custom ({getattr(distance_fn, '__name__', 'function')})"
    directory = make_directory(directory)
    share = _work_share(part)
    if share is not None:
        return _build_part(
            spec, directory, factory, share, workers, distance_fn, description, progress
        )
    if (directory / MANIFEST).exists():
        manifest = read_manifest(directory)
        fresh = _new_manifest(spec, factory, description)
        _check_same_dataset(manifest, fresh, directory)
    else:
        manifest = _new_manifest(spec, factory, description)

    return _build_shards(
        spec, directory, factory, _Output(manifest), workers, distance_fn, progress
    )


class _Output(NamedTuple):
    """Where a build records its shards: the manifest dict, the file it is written to
    (``manifest.json``, or a worker's partial manifest), the worker's share of the shard files
    (``None``: all of them) and entries of ``manifest.json`` a worker may count as done."""

    manifest: dict
    path: str = MANIFEST
    share: WorkShare | None = None
    done: dict | None = None


def _build_shards(
    spec: DatasetSpec,
    directory: Path,
    factory,
    output: _Output,
    workers: int,
    distance_fn: DistanceFn,
    progress: bool,
) -> dict:
    if spec.is_collection:
        return _build_collection(spec, directory, factory, output, workers, distance_fn, progress)
    template_vertices, faces = factory.template()
    faces = np.asarray(faces, dtype=np.int64)
    shared = shared_sources(np.asarray(template_vertices), spec.n_shared_sources)
    if not (directory / TEMPLATE).exists():
        template = {
            "faces": faces,
            "shared_sources": shared,
            "template_vertices": np.asarray(template_vertices, dtype=np.float32),
        }
        if output.share is None:
            write_tensors_atomic(directory / TEMPLATE, template)
        else:  # every worker may write it at once (identical bytes): unique temporary names
            _write_tensors_unique(directory / TEMPLATE, template)

    pending = _pending_shards(spec, directory, output.manifest, output.share, output.done)
    jobs = [
        (*spec.shape_key(split, index), spec.n_extra_sources)
        for split, shard, indices in pending
        for index in indices
    ]
    if not jobs:
        return output.manifest
    results = _pool_map(jobs, workers, (factory, distance_fn, shared, faces))
    _write_shards(spec, directory, output, pending, results, len(jobs), workers, progress)
    return output.manifest


def _build_collection(
    spec: DatasetSpec,
    directory: Path,
    factory: CollectionFactory,
    output: _Output,
    workers: int,
    distance_fn: DistanceFn,
    progress: bool,
) -> dict:
    if not hasattr(factory, "generate_mesh"):
        raise InputError("a collection dataset needs a factory with generate_mesh(family, seed)")
    pending = _pending_shards(spec, directory, output.manifest, output.share, output.done)
    jobs = [
        (*spec.shape_key(split, index), spec.n_shared_sources, spec.n_extra_sources)
        for split, shard, indices in pending
        for index in indices
    ]
    if not jobs:
        return output.manifest
    results = _pool_map(jobs, workers, (factory, distance_fn), collection=True)
    _write_shards(spec, directory, output, pending, results, len(jobs), workers, progress)
    return output.manifest


def _write_shards(
    spec: DatasetSpec,
    directory: Path,
    output: _Output,
    pending: list,
    results: Iterator[ShapeRecord],
    n_jobs: int,
    workers: int,
    progress: bool,
) -> None:
    """Consume ``results`` in order, writing each pending shard and the manifest after it."""
    manifest, sharded = output.manifest, output.share is not None
    write_tensors = _write_tensors_unique if sharded else write_tensors_atomic
    write_json = _write_json_unique if sharded else write_json_atomic
    label = f"{spec.name}: shapes" + (f" (share {output.share})" if sharded else "")
    bar = _progress(n_jobs, label, progress)
    stack = _stack_collection_shard if spec.is_collection else _stack_shard
    started = time.perf_counter()
    for split, shard, indices in pending:
        records = []
        for _ in indices:
            records.append(next(results))
            bar.update(1)
        keys = [spec.shape_key(split, index) for index in indices]
        tensors = stack(records, keys, spec, split)
        name = shard_name(split, shard)
        manifest["shards"][name] = {
            "split": split,
            "first_index": indices[0],
            "n_shapes": len(indices),
            "sha256": write_tensors(directory / name, tensors),
            "max_relative_storage_error": max(
                _relative_storage_error(
                    tensors["distances"][i, :, : r.vertices.shape[0]].astype(np.float64),
                    r.distances,
                )
                for i, r in enumerate(records)
            ),
        }
        if sharded:  # per shard, so that a merge can add up the work of every worker
            manifest["shards"][name]["compute_seconds"] = sum(r.seconds for r in records)
        manifest["compute_seconds"] += sum(r.seconds for r in records)
        _update_counts(manifest)
        manifest["updated"] = datetime.now(UTC).isoformat(timespec="seconds")
        manifest["host"] = {
            "machine": platform.machine(),
            "cpus": multiprocessing.cpu_count(),
            "workers": workers,
        }
        manifest["wall_seconds_last_run"] = time.perf_counter() - started
        write_json(directory / output.path, manifest)
    bar.close()
    write_json(directory / output.path, manifest)


BUILD_ORDER = ("val", "test", "train")  # evaluation splits first: a long build is usable early


def planned_shards(spec: DatasetSpec) -> list[tuple[str, int, list[int]]]:
    """Every shard file of ``spec`` in build order: ``(split, shard, shape indices)``; the
    position in this list is the ordinal that :class:`WorkShare` assigns to workers."""
    plan = []
    for split in BUILD_ORDER:
        total = spec.n_shapes.get(split, 0)
        for shard in range(math.ceil(total / spec.shard_size)):
            first = shard * spec.shard_size
            plan.append((split, shard, list(range(first, min(first + spec.shard_size, total)))))
    return plan


def _pending_shards(
    spec: DatasetSpec,
    directory: Path,
    manifest: dict,
    share: WorkShare | None = None,
    done: dict | None = None,
) -> list:
    """The planned shards (of ``share`` only, if given) that are not built: their file is
    missing or does not match the hash in ``manifest`` (nor in ``done``, the entries of
    ``manifest.json`` seen by a worker; a match there is copied into ``manifest``)."""
    pending = []
    for ordinal, (split, shard, indices) in enumerate(planned_shards(spec)):
        if share is not None and not share.owns(ordinal):
            continue
        name = shard_name(split, shard)
        path = directory / name
        candidates = [manifest["shards"].get(name), (done or {}).get(name)]
        digest = file_sha256(path) if path.exists() and any(candidates) else None
        entry = candidates[0]
        if entry is not None and digest == entry["sha256"]:
            continue
        manifest["shards"].pop(name, None)
        entry = candidates[1]
        if entry is not None and digest == entry["sha256"]:
            manifest["shards"][name] = dict(entry)
            continue
        pending.append((split, shard, indices))
    _update_counts(manifest)
    return pending


def _update_counts(manifest: dict) -> None:
    counts = {split: 0 for split in SPLITS}
    for entry in manifest["shards"].values():
        counts[entry["split"]] += entry["n_shapes"]
    manifest["counts"] = counts


def _progress(total: int, description: str, enabled: bool):
    from tqdm.auto import tqdm

    return tqdm(total=total, desc=description, unit="shape", disable=not enabled)


def _manifest_sources(directory: Path) -> list[tuple[str, dict]]:
    """``(file name, manifest)`` of ``manifest.json`` (first, if present) and every partial
    manifest in ``directory``."""
    sources = []
    if (directory / MANIFEST).exists():
        sources.append((MANIFEST, read_manifest(directory)))
    for path in sorted(directory.glob(PART_MANIFEST_GLOB)):
        sources.append((path.name, _read_json(path)))
    if not sources:
        raise ArtifactError(f"no {MANIFEST} nor partial manifests in {directory}")
    return sources


def missing_shards(directory: str | Path) -> list[str]:
    """Names of the planned shard files that no manifest of ``directory`` (``manifest.json``
    or a partial one) lists or whose file is absent (hashes are not checked: see
    :func:`merge_dataset`). Empty when a merge can proceed."""
    directory = Path(directory)
    sources = _manifest_sources(directory)
    spec = DatasetSpec.from_dict(sources[0][1]["spec"])
    listed = {name for _, manifest in sources for name in manifest.get("shards", {})}
    return [
        name
        for name in (shard_name(split, shard) for split, shard, _ in planned_shards(spec))
        if name not in listed or not (directory / name).exists()
    ]


def merge_dataset(directory: str | Path, *, wait_s: float = 0.0, poll_s: float = 30.0) -> dict:
    """Assemble ``manifest.json`` from the partial manifests of a sharded build, verify the
    dataset and return the manifest. Idempotent: a ``manifest.json`` that already lists every
    shard is only verified, never rewritten (its hash is the dataset fingerprint training
    checkpoints record); shards listed by any manifest are accepted when their file hash
    matches.

    Args:
        directory: the dataset directory (a shared volume for a multi-machine build).
        wait_s: wait up to this many seconds for missing shards (other workers still
            running), checking every ``poll_s`` seconds; 0: fail at once.
        poll_s: seconds between checks while waiting.

    Raises:
        ArtifactError: manifests of different datasets, shard files missing or not matching
            any manifest's hash (after ``wait_s``), or a failed :func:`verify_dataset`.
    """
    directory = Path(directory)
    deadline = time.monotonic() + wait_s
    while True:
        missing = missing_shards(directory)
        if not missing or time.monotonic() >= deadline:
            break
        time.sleep(max(0.0, min(poll_s, deadline - time.monotonic())))
    sources = _manifest_sources(directory)
    reference = dict(sources[0][1])
    reference["solver"] = LEGACY_SOLVER_TEXT.get(reference["solver"], reference["solver"])
    for name, manifest in sources[1:]:
        _check_same_dataset(manifest, reference, directory, f" ({name})")
        if manifest.get("format_version") != reference.get("format_version"):
            raise ArtifactError(f"{directory} ({name}) has another format_version")
    spec = DatasetSpec.from_dict(reference["spec"])
    shards: dict[str, dict] = {}
    unmatched = []
    for split, shard, _ in planned_shards(spec):
        name = shard_name(split, shard)
        path = directory / name
        entries = [m["shards"][name] for _, m in sources if name in m.get("shards", {})]
        if not entries or not path.exists():
            continue
        digest = file_sha256(path)
        matching = [entry for entry in entries if entry["sha256"] == digest]
        if matching:
            shards[name] = matching[0]
        else:
            unmatched.append(name)
    absent = [n for n in missing if n not in shards] + unmatched
    if absent:
        raise ArtifactError(
            f"cannot merge {directory}: {len(absent)} of {len(planned_shards(spec))} shard "
            f"files are not built or do not match their manifest (run the missing --shard "
            f"workers again): {', '.join(absent[:10])}{' …' if len(absent) > 10 else ''}"
        )
    if sources[0][0] == MANIFEST and sources[0][1].get("shards") == shards:
        verify_dataset(directory)  # merged already: left byte for byte (stable fingerprint)
        return sources[0][1]
    keys = ("format_version", "spec", "generator", "distance_dtype", "seed_offsets", "units")
    manifest = {key: reference[key] for key in keys if key in reference}
    manifest["solver"] = reference["solver"]
    for key in ("kind", "layout"):
        if key in reference:
            manifest[key] = reference[key]
    parts = [(name, m) for name, m in sources if name != MANIFEST]
    manifest["shards"] = shards
    _update_counts(manifest)
    manifest["compute_seconds"] = _merged_compute_seconds(sources, shards)
    now = datetime.now(UTC).isoformat(timespec="seconds")
    manifest["created"] = min((m["created"] for _, m in sources if m.get("created")), default=now)
    manifest["updated"] = now
    if parts:
        manifest["merged_from"] = sorted(name for name, _ in parts)
    elif "merged_from" in reference:
        manifest["merged_from"] = reference["merged_from"]
    hosts = [m["host"] for _, m in parts if "host" in m]
    if hosts:
        manifest["host"] = {
            "machine": hosts[0].get("machine"),
            "cpus": max(h.get("cpus", 0) for h in hosts),
            "workers": sum(h.get("workers", 0) for h in hosts),
            "parts": len(parts),
        }
    elif "host" in reference:
        manifest["host"] = reference["host"]
    _write_json_unique(directory / MANIFEST, manifest)
    verify_dataset(directory)
    return manifest


def _merged_compute_seconds(sources: list[tuple[str, dict]], shards: dict) -> float:
    """Shards built by workers carry their own seconds; the rest come from a single-process
    ``manifest.json`` whose total covers them (a merged one carries per-shard seconds)."""
    per_shard = sum(float(entry.get("compute_seconds", 0.0)) for entry in shards.values())
    first_name, first = sources[0]
    if first_name == MANIFEST and "merged_from" not in first:
        legacy = [n for n, e in shards.items() if "compute_seconds" not in e]
        if legacy:
            per_shard += float(first.get("compute_seconds", 0.0))
    return per_shard


def verify_dataset(directory: str | Path) -> dict:
    """Check every shard's hash, array shapes and values against the manifest.

    Returns ``{"shards": n, "counts": {...}}``; raises ArtifactError on any mismatch.
    """
    directory = Path(directory)
    manifest = read_manifest(directory)
    if manifest.get("kind", "template") == "collection":
        return _verify_collection(directory, manifest)
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


def _verify_collection(directory: Path, manifest: dict) -> dict:
    """:func:`verify_dataset` for collection datasets: hashes, shapes, per-shape index ranges,
    padding, finite rows and (near-)zero distance at every source."""
    for name, entry in sorted(manifest["shards"].items()):
        path = directory / name
        if not path.exists():
            raise ArtifactError(f"shard {name} listed in the manifest is missing")
        if file_sha256(path) != entry["sha256"]:
            raise ArtifactError(f"shard {name} does not match its manifest hash")
        t = read_tensors(path, COLLECTION_KEYS)
        n_shapes, n_rows, width = t["distances"].shape
        if (
            n_shapes != entry["n_shapes"]
            or t["vertices"].shape[:2] != (n_shapes, width)
            or t["sources"].shape != (n_shapes, n_rows)
            or t["faces"].shape[0] != n_shapes
        ):
            raise ArtifactError(f"shard {name} has inconsistent array shapes")
        for s in range(n_shapes):
            n_v, n_f = int(t["n_vertices"][s]), int(t["n_faces"][s])
            faces, sources, rows = t["faces"][s], t["sources"][s], t["distances"][s]
            if not (0 < n_v <= width and 0 < n_f <= faces.shape[0]):
                raise ArtifactError(f"shard {name} shape {s}: bad vertex/face counts")
            if faces[:n_f].min() < 0 or faces[:n_f].max() >= n_v or (faces[n_f:] != FACE_PAD).any():
                raise ArtifactError(f"shard {name} shape {s}: face indices out of range")
            if sources.min() < 0 or sources.max() >= n_v:
                raise ArtifactError(f"shard {name} shape {s}: sources out of range")
            if not np.isfinite(rows).all() or (rows[:, n_v:] != 0).any():
                raise ArtifactError(f"shard {name} shape {s}: non-finite or misshapen distances")
            at_source = np.abs(rows[np.arange(n_rows), sources].astype(np.float64))
            if (at_source > 1e-3 * max(float(np.abs(rows).max()), 1e-30)).any():
                raise ArtifactError(f"shard {name} shape {s}: a source is not at distance 0")
    return {"shards": len(manifest["shards"]), "counts": manifest["counts"]}


__all__ = [
    "BUILD_ORDER",
    "FLOAT16_MAX",
    "LEGACY_SOLVER_TEXT",
    "PART_MANIFEST_GLOB",
    "SOLVERS",
    "CollectionFactory",
    "DistanceFn",
    "ShapeFactory",
    "ShapeRecord",
    "build_dataset",
    "exact_distance_rows",
    "extra_sources",
    "heat_distance_rows",
    "json_spec",
    "merge_dataset",
    "missing_shards",
    "part_manifest_name",
    "planned_shards",
    "shape_sources",
    "shared_sources",
    "surface_area",
    "verify_dataset",
]
