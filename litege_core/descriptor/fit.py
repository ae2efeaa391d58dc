"""End-to-end fit of a :class:`~litege_core.descriptor.basis.UdfPcaBasis` from training shapes.

One pass over the shapes (so a generator is fine), then passes over temporary memmaps:

1. per shape: occupancy (mesh: inside-or-surface, :func:`mesh_occupancy`; point cloud:
   :func:`point_cloud_occupancy`) into an :class:`OccupancyStatistics`, and
   ``n_udf_samples`` area-weighted surface samples (a cloud is subsampled, or padded by
   repeating its points) appended to a float32 file;
2. informative voxels ``std > std_threshold``;
3. UDF of every stored sample at the informative centres, in batches, into an
   ``(n_shapes, M)`` float32 memmap;
4. streamed randomized PCA over the memmap rows.

Peak memory: the occupancy counts (7 MB at 121³), one batch of UDF rows and the PCA working
set ``O((n + M)·(k + oversample))``; the UDF matrix itself stays on disk.
"""

from __future__ import annotations

import tempfile
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

import litege_core
from litege_core.descriptor._arrays import positive_int
from litege_core.descriptor.basis import UdfPcaBasis
from litege_core.descriptor.grid import VoxelGrid
from litege_core.descriptor.informative import (
    OccupancyStatistics,
    frequency_band,
    std_to_variance,
)
from litege_core.descriptor.occupancy import mesh_occupancy, point_cloud_occupancy
from litege_core.descriptor.pca import fit_pca_streamed
from litege_core.descriptor.udf import UdfBackend, UdfEvaluator
from litege_core.errors import ArrayShapeError, InputError
from litege_core.sampling import sample_surface
from litege_core.shape import Shape
from litege_core.validate import validate_arrays

ShapeInput = Shape | tuple[ArrayLike, ArrayLike | None] | ArrayLike


def _unpack(item: ShapeInput, index: int) -> tuple[NDArray, NDArray | None]:
    """Shape, ``(vertices, faces)``, ``(points, None)`` or ``(P, 3)`` points → validated."""
    if isinstance(item, Shape):
        return item.vertices, item.faces
    try:
        if isinstance(item, tuple) and len(item) == 2:
            return validate_arrays(item[0], item[1])
        return validate_arrays(item, None)
    except InputError as exc:
        raise type(exc)(f"shape #{index}: {exc.message}") from exc


def udf_samples(
    vertices: NDArray, faces: NDArray | None, n_samples: int, rng: np.random.Generator
) -> NDArray:
    """``(n_samples, 3)`` float32 points for the UDF: area-weighted surface samples of a mesh;
    for a cloud a random subset without replacement, padded with random repeats when the cloud
    has fewer points (repeats do not change nearest-point distances)."""
    if faces is not None:
        return sample_surface(vertices, faces, n_samples, rng).points.astype(np.float32)
    n_points = vertices.shape[0]
    if n_points >= n_samples:
        pick = rng.choice(n_points, n_samples, replace=False)
    else:
        pick = np.concatenate([np.arange(n_points), rng.choice(n_points, n_samples - n_points)])
    return vertices[pick].astype(np.float32)


def fit_basis(
    shapes: Iterable[ShapeInput],
    grid: VoxelGrid | None = None,
    std_threshold: float = 0.14,
    n_components: int = 400,
    n_udf_samples: int = 2000,
    seed: int = 0,
    *,
    point_cloud_dilation: int = 0,
    udf_backend: str | UdfBackend = UdfBackend.AUTO,
    udf_batch: int = 16,
    pca_oversample: int = 10,
    pca_power_iter: int = 4,
    pca_chunk_rows: int = 256,
    workdir: str | Path | None = None,
    metadata: dict[str, Any] | None = None,
    progress: Callable[[str, int], None] | None = None,
) -> UdfPcaBasis:
    """Fit a UDF-PCA basis on canonical training shapes.

    Args:
        shapes: iterable (one pass) of canonical-frame :class:`~litege_core.shape.Shape`,
            ``(vertices (N, 3), faces (F, 3) | None)`` tuples, or ``(P, 3)`` point clouds.
        grid: voxel grid (default 121³ at pitch 0.02).
        std_threshold: keep voxels whose occupancy std exceeds it (spec §2.3; 0.14 for the
            authors' matching basis).
        n_components: ``k``; must not exceed the number of shapes or of informative voxels.
        n_udf_samples: points per shape for the UDF (2000 as in the regression test).
        seed: base seed; shape ``i`` samples with ``default_rng([seed, i])``.
        point_cloud_dilation: dilation (voxels) of point-cloud occupancy.
        udf_backend: see :mod:`litege_core.descriptor.udf`.
        udf_batch: clouds per UDF call.
        pca_oversample, pca_power_iter, pca_chunk_rows: streamed PCA settings.
        workdir: where the temporary memmaps go (default: the system temp dir).
        metadata: extra provenance stored in the basis.
        progress: optional ``callback(stage, count)``.

    Returns:
        The fitted :class:`UdfPcaBasis`; its metadata records the threshold, frequency band,
        informative-voxel count, sampling, PCA settings and explained variance.

    Raises:
        InputError: no shapes, no voxel above the threshold, or ``n_components`` too large.
    """
    grid = VoxelGrid() if grid is None else grid
    n_udf_samples = positive_int(n_udf_samples, "n_udf_samples")
    udf_batch = positive_int(udf_batch, "udf_batch")
    k = positive_int(n_components, "n_components")
    variance = std_to_variance(std_threshold)
    stats = OccupancyStatistics(grid)
    with tempfile.TemporaryDirectory(prefix="litege-fit-", dir=workdir) as tmp:
        samples_path, udf_path = Path(tmp) / "samples.f32", Path(tmp) / "udf.f32"
        n_meshes = 0
        with samples_path.open("wb") as sample_file:
            for index, item in enumerate(shapes):
                vertices, faces = _unpack(item, index)
                if faces is not None:
                    occupancy = mesh_occupancy(vertices, faces, grid)
                    n_meshes += 1
                else:
                    occupancy = point_cloud_occupancy(vertices, grid, point_cloud_dilation)
                stats.add(occupancy)
                rng = np.random.default_rng([seed, index])
                sample_file.write(udf_samples(vertices, faces, n_udf_samples, rng).tobytes())
                if progress is not None:
                    progress("occupancy", index + 1)
        n_shapes = stats.n_shapes
        if n_shapes < 2:
            raise InputError(f"fitting a basis needs at least 2 shapes, got {n_shapes}")
        indices = stats.select(std_threshold)
        if indices.size == 0:
            raise InputError(
                f"no voxel has an occupancy std above {std_threshold} over {n_shapes} shapes"
            )
        if k > min(n_shapes, indices.size):
            raise InputError(
                f"n_components={k} exceeds min(n_shapes={n_shapes}, "
                f"n_informative_voxels={indices.size})"
            )
        samples = np.memmap(samples_path, np.float32, "r", shape=(n_shapes, n_udf_samples, 3))
        udf = np.memmap(udf_path, np.float32, "w+", shape=(n_shapes, indices.size))
        evaluator = UdfEvaluator(grid.centers(indices), backend=udf_backend)
        for start in range(0, n_shapes, udf_batch):
            stop = min(start + udf_batch, n_shapes)
            udf[start:stop] = evaluator(np.asarray(samples[start:stop])).numpy()
            if progress is not None:
                progress("udf", stop)
        udf.flush()
        rows = pca_chunk_rows

        def chunks() -> Iterable[NDArray]:
            return (udf[s : s + rows] for s in range(0, n_shapes, rows))

        pca = fit_pca_streamed(
            chunks, k, oversample=pca_oversample, n_power_iter=pca_power_iter, seed=seed
        )
    if pca.components.shape[1] != indices.size:  # pragma: no cover - internal invariant
        raise ArrayShapeError("PCA width does not match the informative voxels")
    p0, p1 = frequency_band(std_threshold)
    provenance = {
        "litege_version": litege_core.__version__,
        "std_threshold": float(std_threshold),
        "variance_threshold": variance,
        "frequency_band": [p0, p1],
        "n_informative_voxels": int(indices.size),
        "n_fit_meshes": n_meshes,
        "n_fit_point_clouds": n_shapes - n_meshes,
        "occupancy": {
            "mesh": "ray-parity vote (x, y, z; odd columns abstain) OR exact triangle-box",
            "point_cloud_dilation": int(point_cloud_dilation),
        },
        "udf": {"n_samples": n_udf_samples, "sampling": "area-weighted", "seed": int(seed)},
        "pca": {
            "method": "streamed randomized SVD",
            "oversample": int(pca_oversample),
            "n_power_iter": int(pca_power_iter),
            "seed": int(seed),
        },
        **(metadata or {}),
    }
    return UdfPcaBasis.from_pca(grid, indices, pca, n_fit_shapes=n_shapes, metadata=provenance)


__all__ = ["ShapeInput", "fit_basis", "udf_samples"]
