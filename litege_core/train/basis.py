"""The UDF-PCA basis of a training run: load the configured one, or fit one on the train split.

Fitting follows the regression pipeline (spec §1.2, §2): every training mesh is canonicalized
with :func:`~litege_core.canonical.canonicalize_bbox` of ``fit_samples`` area-weighted samples
(seeded by the shape's dataset seed), then :func:`~litege_core.descriptor.fit_basis` selects
the informative voxels (occupancy std > ``std_threshold`` on the configured grid) and fits the
PCA on the UDF of ``fit_samples`` samples per shape. The fitted basis is saved as
``basis.safetensors`` in the run directory and reused when the run is resumed.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Iterator
from pathlib import Path

from numpy.typing import NDArray

from litege_core.canonical import canonicalize_bbox
from litege_core.datasets import shape_mesh
from litege_core.descriptor import UdfPcaBasis, VoxelGrid, fit_basis
from litege_core.errors import InputError
from litege_core.sampling import sample_surface
from litege_core.train.config import BasisConfig

LOG = logging.getLogger("litege.train")
BASIS_FILE = "basis.safetensors"
VARIANCE_AT = 50  # explained variance reported at this many components


def canonical_meshes(
    arrays: dict[str, NDArray], faces: NDArray | None, n_samples: int
) -> Iterator[tuple[NDArray, NDArray]]:
    """Yield ``(canonical vertices (V, 3), faces)`` of every shape of a split, each
    canonicalized from ``n_samples`` area-weighted samples seeded by the shape's seed.
    ``faces`` is the shared triangulation (``None`` for a collection split, whose shapes
    carry their own faces)."""
    for index, seed in enumerate(arrays["seed"]):
        verts, shape_faces = shape_mesh(arrays, index, faces)
        points = sample_surface(verts, shape_faces, n_samples, int(seed)).points
        yield canonicalize_bbox(points).apply(verts), shape_faces


def fit_training_basis(
    settings: BasisConfig,
    arrays: dict[str, NDArray],
    faces: NDArray | None,
    category: str,
    seed: int,
) -> UdfPcaBasis:
    """Fit a basis on the training split (see the module docstring); logs the number of
    informative voxels and the explained variance at 50 components."""
    if settings.fit_shapes:
        arrays = {key: value[: settings.fit_shapes] for key, value in arrays.items()}
    start = time.perf_counter()
    basis = fit_basis(
        canonical_meshes(arrays, faces, settings.fit_samples),
        grid=VoxelGrid(settings.grid_resolution, settings.grid_pitch),
        std_threshold=settings.std_threshold,
        n_components=settings.n_components,
        n_udf_samples=settings.fit_samples,
        seed=seed,
        metadata={
            "category": category,
            "pipeline": "bbox",
            "fit": "litege_core.train.basis (train split of the training dataset)",
            "n_train_shapes": len(arrays["seed"]),
        },
    )
    at = min(VARIANCE_AT, basis.n_components)
    variance = float(basis.pca.explained_variance_curve([at])[0])
    LOG.info(
        "fitted basis on %d shapes in %.0f s: %d informative voxels (std > %g), "
        "explained variance %.3f at %d components",
        basis.n_fit_shapes,
        time.perf_counter() - start,
        basis.n_voxels,
        settings.std_threshold,
        variance,
        at,
    )
    return basis


def fit_mismatch(basis: UdfPcaBasis, settings: BasisConfig) -> str:
    """Differences between how ``basis`` was fitted and the ``[basis]`` settings ("" if none)."""
    wanted = {
        "grid": VoxelGrid(settings.grid_resolution, settings.grid_pitch).to_dict(),
        "std_threshold": settings.std_threshold,
    }
    found = {"grid": basis.grid.to_dict(), "std_threshold": basis.metadata.get("std_threshold")}
    return ", ".join(
        f"{key} {found[key]} instead of {wanted[key]}"
        for key in wanted
        if found[key] != wanted[key]
    )


def prepare_basis(
    settings: BasisConfig,
    run_dir: Path,
    train_arrays: dict[str, NDArray],
    faces: NDArray | None,
    category: str,
    seed: int,
) -> tuple[UdfPcaBasis, str]:
    """The run's basis and where it came from.

    Order: ``settings.path`` when that file exists (differences from the fit settings are
    logged); else ``run_dir/basis.safetensors`` when it exists (a resumed or repeated run; it
    must match the grid and threshold of the settings); else a new fit on ``train_arrays``
    saved there (``faces``: the shared triangulation, ``None`` when each shape of the split
    carries its own). A basis with more components than ``settings.n_components`` is
    truncated.

    Returns:
        ``(basis, source)`` with ``source`` the file the basis was read from or saved to.
    """
    candidates = [Path(settings.path)] if settings.path else []
    candidates.append(run_dir / BASIS_FILE)
    for path in candidates:
        if path.is_file():
            basis = UdfPcaBasis.load(path)
            mismatch = fit_mismatch(basis, settings)
            if mismatch and path == run_dir / BASIS_FILE:
                raise InputError(
                    f"{path} was fitted with other settings ({mismatch}); delete it or point "
                    "basis.path at it explicitly"
                )
            if mismatch:
                LOG.info("basis %s differs from the [basis] fit settings: %s", path, mismatch)
            LOG.info(
                "loaded basis %s (%d voxels, %d components)",
                path,
                basis.n_voxels,
                basis.n_components,
            )
            break
    else:
        if settings.path:
            LOG.info("basis %s does not exist: fitting one on the train split", settings.path)
        basis = fit_training_basis(settings, train_arrays, faces, category, seed)
        path = run_dir / BASIS_FILE
        path.parent.mkdir(parents=True, exist_ok=True)
        basis.save(path)
    if basis.n_components < settings.n_components:
        raise InputError(
            f"basis {path} has {basis.n_components} components, "
            f"basis.n_components asks for {settings.n_components}"
        )
    if basis.n_components > settings.n_components:
        basis = basis.truncate(settings.n_components)
    return basis, str(path)


__all__ = [
    "BASIS_FILE",
    "canonical_meshes",
    "fit_mismatch",
    "fit_training_basis",
    "prepare_basis",
]
