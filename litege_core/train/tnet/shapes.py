"""The T-Net's training and validation shapes in their canonical frames: procedural, collection
(MakeHuman bodies, rigged animals) and steep poses, generated once and cached."""

from __future__ import annotations

import logging
import os
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from litege_core.canonical import (
    canonicalize_unit_area,
)
from litege_core.datasets.spec import SPLIT_SEED_OFFSETS
from litege_core.train.tnet.config import TNetDataConfig

LOG = logging.getLogger("litege.train.tnet")


class ShapeSet(NamedTuple):
    """Meshes in the canonical frame (template orientation, centred, unit area).

    ``vertices[i]`` is ``(V_i, 3)`` float64, ``faces[i]`` ``(F_i, 3)`` int64 (procedural shapes
    of a category share one array), ``keys[i]`` the ``(family, seed)`` it came from."""

    vertices: list[NDArray]
    faces: list[NDArray]
    keys: list[tuple[str, int]]

    def __len__(self) -> int:
        return len(self.vertices)


def _canonical_mesh(verts: ArrayLike, tris: ArrayLike, index: int) -> tuple[NDArray, NDArray]:
    """One mesh in the template orientation → its centred, unit-area copy (identity rotation);
    ``index`` seeds the area-weighted samples of the centre."""
    verts = np.asarray(verts, dtype=np.float64)
    tris = np.asarray(tris, dtype=np.int64)
    return canonicalize_unit_area(verts, tris, seed=index).apply(verts), tris


def canonical_shape_set(
    meshes: Sequence[tuple[ArrayLike, ArrayLike]], keys: Sequence[tuple[str, int]] | None = None
) -> ShapeSet:
    """Meshes in the template orientation → centred, unit-area copies (identity rotation)."""
    canonical = [_canonical_mesh(verts, tris, index) for index, (verts, tris) in enumerate(meshes)]
    if keys is None:
        keys = [("", index) for index in range(len(canonical))]
    return ShapeSet([v for v, _ in canonical], [f for _, f in canonical], list(keys))


def _generated_canonical(job: tuple[str, str, int, int, str | None]) -> tuple[NDArray, NDArray]:
    """``(category, family, seed, index, pose)`` → the canonical mesh of that procedural shape
    (``pose`` ``None``: the pose its seed draws)."""
    from litege_core.synth import generate_shape

    category, family, seed, index, pose = job
    shape = generate_shape(category, family, seed, pose)
    return _canonical_mesh(shape.vertices, shape.faces, index)


def _generate_canonical(
    category: str, keys: Sequence[tuple[str, int]], workers: int, steep_share: float = 0.0
) -> ShapeSet:
    """The procedural shapes ``keys`` in the canonical frame, on ``workers`` processes (each
    shape is a pure function of its key and position, so the count does not change them)."""
    from litege_core.synth.poses import steep_pose

    jobs = [
        (category, family, seed, index, steep_pose(category, seed, steep_share))
        for index, (family, seed) in enumerate(keys)
    ]
    meshes = _map_jobs(_generated_canonical, jobs, workers, chunksize=4)
    return ShapeSet([v for v, _ in meshes], [f for _, f in meshes], list(keys))


def _map_jobs(
    function: Callable[[Any], tuple[NDArray, NDArray]],
    jobs: Sequence[Any],
    workers: int,
    chunksize: int,
) -> list[tuple[NDArray, NDArray]]:
    """``[function(job) for job in jobs]``, on ``workers`` forked processes when there are
    several (the results do not depend on the count)."""
    if workers > 1 and len(jobs) > 1:
        import multiprocessing

        with multiprocessing.get_context("fork").Pool(min(workers, len(jobs))) as pool:
            return pool.map(function, jobs, chunksize=chunksize)
    return [function(job) for job in jobs]


def generate_shape_set(
    category: str,
    split: str,
    n_shapes: int,
    cache_dir: str | Path | None = None,
    workers: int = 1,
    steep_share: float = 0.0,
) -> ShapeSet:
    """Procedural shapes ``0..n_shapes−1`` of ``split`` (the dataset convention), canonical;
    a ``steep_share`` of them rear, leap, sit up or lie on the belly
    (:func:`~litege_core.synth.poses.steep_pose`).

    With ``cache_dir`` the set is kept in
    ``<cache_dir>/tnet-shapes-<category>-<split>-<n>-<factory version>.npz`` (the version of
    :class:`~litege_core.datasets.factories.SynthFactory`, which names the steep share):
    the largest cached set of the split is reused (sliced, or extended by generating the missing
    shapes). ``workers`` processes generate the missing shapes.
    """
    from litege_core.datasets.factories import SynthFactory
    from litege_core.synth import families

    names = families(category)
    keys = [(names[k % len(names)], SPLIT_SEED_OFFSETS[split] + k) for k in range(n_shapes)]
    cached: list[NDArray] = []
    faces: NDArray | None = None
    version = SynthFactory(category, steep_share).version  # names the steep share
    prefix, suffix = f"tnet-shapes-{category}-{split}-", f"-{version}.npz"
    largest = _largest_cache(cache_dir, prefix, suffix)
    if largest is not None:
        with np.load(largest) as data:
            cached, faces = list(data["vertices"][:n_shapes]), data["faces"]
    fresh = _generate_canonical(category, keys[len(cached) :], workers, steep_share)
    if faces is None:
        faces = fresh.faces[0] if fresh.faces else np.zeros((0, 3), dtype=np.int64)
    shared = all(np.array_equal(f, faces) for f in fresh.faces)
    if not shared:  # pragma: no cover - procedural shapes share their template's faces
        return ShapeSet(cached + fresh.vertices, [faces] * len(cached) + fresh.faces, keys)
    shapes = ShapeSet(cached + fresh.vertices, [faces] * n_shapes, keys)
    if cache_dir and fresh.vertices:
        _write_cache(
            Path(cache_dir) / f"{prefix}{n_shapes}{suffix}",
            vertices=np.stack(shapes.vertices),
            faces=faces,
        )
    return shapes


def _largest_cache(cache_dir: str | Path | None, prefix: str, suffix: str) -> Path | None:
    """The cached set ``<prefix><n><suffix>`` of largest ``n`` in ``cache_dir`` (or ``None``)."""
    if not cache_dir:
        return None
    sizes = [
        int(path.name[len(prefix) : -len(suffix)])
        for path in Path(cache_dir).glob(f"{prefix}*{suffix}")
        if path.name[len(prefix) : -len(suffix)].isdigit()
    ]
    return Path(cache_dir) / f"{prefix}{max(sizes)}{suffix}" if sizes else None


def _write_cache(path: Path, **arrays: NDArray) -> None:
    """Write an ``.npz`` atomically (a concurrent run never reads half a file)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    temporary = path.with_name(f"{path.stem}.tmp-{os.getpid()}.npz")
    np.savez(temporary, **arrays)  # type: ignore[arg-type]  # numpy's stub types **kwds as bool
    os.replace(temporary, path)


def _collection_canonical(
    job: tuple[str, str, str, int, int, float, float],
) -> tuple[NDArray, NDArray]:
    """``(source, root, family, seed, index, bend, steep_share)`` → the canonical mesh of that
    collection shape."""
    from litege_core.datasets.factories import factory_for
    from litege_core.synth.rigged import bent_pose_settings

    source, root, family, seed, index, bend, steep_share = job
    factory = factory_for(source, root, bent_pose_settings(bend), steep_share)
    vertices, faces = factory.generate_mesh(family, seed)
    return _canonical_mesh(vertices, faces, index)


def collection_shape_set(
    source: str,
    split: str,
    n_shapes: int,
    root: str | Path | None = None,
    cache_dir: str | Path | None = None,
    workers: int = 1,
    bend: float = 0.0,
    steep_share: float = 0.0,
) -> ShapeSet:
    """Posed meshes ``0..n_shapes−1`` of a collection source (``"makehuman"``, ``"rigged"``) in
    ``split``, canonical: the shapes ``litege data build --category SOURCE [--bend B]
    [--steep S]`` starts from (same families and seeds), without remeshing for ground truth
    beyond what the source does; ``bend``: share of the rigged animals bent along the body;
    ``steep_share``: share of the MakeHuman bodies in steep poses.

    With ``cache_dir`` the set is kept in ``tnet-shapes-<source>-<split>-<n>-<version>.npz``
    (ragged: concatenated vertices and faces with per-shape counts) and the largest cached set
    of the split is reused and extended.
    """
    from litege_core.datasets.factories import factory_for, train_data_root
    from litege_core.datasets.spec import preset
    from litege_core.synth.rigged import bent_pose_settings

    root = str(train_data_root(root))
    factory = factory_for(source, root, bent_pose_settings(bend), steep_share)
    names = preset("small", source).families_of(split)
    keys = [(names[k % len(names)], SPLIT_SEED_OFFSETS[split] + k) for k in range(n_shapes)]
    prefix, suffix = f"tnet-shapes-{source}-{split}-", f"-{factory.version}.npz"
    meshes: list[tuple[NDArray, NDArray]] = []
    largest = _largest_cache(cache_dir, prefix, suffix)
    if largest is not None:
        with np.load(largest) as data:
            v_split = np.cumsum(data["vertex_counts"])[:-1]
            f_split = np.cumsum(data["face_counts"])[:-1]
            vertices = np.split(data["vertices"], v_split)
            faces = np.split(data["faces"], f_split)
            meshes = list(zip(vertices, faces, strict=True))[:n_shapes]
    jobs = [
        (source, root, family, seed, index, bend, steep_share)
        for index, (family, seed) in enumerate(keys)
        if index >= len(meshes)
    ]
    meshes += _map_jobs(_collection_canonical, jobs, workers, chunksize=2)
    if cache_dir and jobs:
        _write_cache(
            Path(cache_dir) / f"{prefix}{n_shapes}{suffix}",
            vertices=np.concatenate([v for v, _ in meshes]),
            faces=np.concatenate([f for _, f in meshes]),
            vertex_counts=np.array([len(v) for v, _ in meshes]),
            face_counts=np.array([len(f) for _, f in meshes]),
        )
    return ShapeSet([v for v, _ in meshes], [f for _, f in meshes], keys)


def concatenate_shape_sets(*sets: ShapeSet) -> ShapeSet:
    """One :class:`ShapeSet` holding the shapes of ``sets`` in order."""
    return ShapeSet(
        [v for s in sets for v in s.vertices],
        [f for s in sets for f in s.faces],
        [k for s in sets for k in s.keys],
    )


def training_shape_sets(data: TNetDataConfig) -> tuple[ShapeSet, ShapeSet]:
    """The train and val :class:`ShapeSet` of a data config: the procedural shapes of
    ``data.category``, then the ``data.extra_category`` collection shapes."""
    sets = []
    for split, n_procedural, n_extra in (
        ("train", data.n_train, data.n_extra_train),
        ("val", data.n_val, data.n_extra_val),
    ):
        mark = time.perf_counter()
        shapes = generate_shape_set(
            data.category, split, n_procedural, data.cache_dir, data.workers, data.steep_share
        )
        if n_extra:
            extra = collection_shape_set(
                data.extra_category,
                split,
                n_extra,
                data.train_data or None,
                data.cache_dir,
                data.workers,
                data.extra_bend,
            )
            shapes = concatenate_shape_sets(shapes, extra)
        LOG.info("%d %s shapes in %.1f s", len(shapes), split, time.perf_counter() - mark)
        sets.append(shapes)
    return sets[0], sets[1]


__all__ = [
    "ShapeSet",
    "canonical_shape_set",
    "collection_shape_set",
    "concatenate_shape_sets",
    "generate_shape_set",
    "training_shape_sets",
]
