"""The UDF-PCA basis: the frozen artifact that turns a canonical point cloud into a descriptor.

``z = (udf(points) − μ) · Pᵀ`` — plain projection, no whitening or standardisation (reference
spec §2.4–2.5). :class:`UdfPcaBasis` holds everything needed and nothing else: the grid spec,
the informative voxel indices and centres, the UDF mean, the components, the explained
variance and provenance metadata. It is saved as one ``.safetensors`` file (tensors) whose
header metadata carries a JSON document (grid, counts, content hash, user metadata); no pickle.

Precision: centres and mean are float32; components are used as float32 and **stored** either
as float16 (the default, format version 1) or as int8 codes with one float32 scale per component
(``component_storage="int8"``, format version 2: half the bytes; on the shipped bases the
predicted distances move by 0.005 on a mean-100 scale, BENCHMARKS.md ``basis-int8``). The
constructor rounds the components through their storage, so an in-memory basis and its saved
copy are identical and share one :attr:`UdfPcaBasis.content_hash`.

Precompute-then-query: :meth:`UdfPcaBasis.engine` moves centres, mean and components to a
device once and returns a :class:`DescriptorEngine` (cached per device and UDF backend);
:meth:`UdfPcaBasis.describe` and :meth:`UdfPcaBasis.describe_batch` go through it. torch is
imported by the engine on first use, not by this module: the torch-free runtime
(:mod:`litege_core.learned.numpy_predictor`) loads a basis with numpy alone.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
from dataclasses import dataclass, field
from functools import cached_property
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray
from safetensors import SafetensorError, safe_open
from safetensors.numpy import save_file

from litege_core.arrays import frozen
from litege_core.descriptor._arrays import as_numeric, as_points, positive_int
from litege_core.descriptor.grid import VoxelGrid
from litege_core.descriptor.pca import PcaResult
from litege_core.descriptor.udf import UdfBackend, UdfEvaluator, resolve_backend
from litege_core.device import resolve_device
from litege_core.errors import ArrayShapeError, ArtifactError, InputError, LiteGEError

if TYPE_CHECKING:  # imported where an engine needs it: loading a basis takes numpy only
    import torch

FORMAT_NAME = "litege-udf-pca"
FORMAT_VERSION = 1
"""Format version of a float16 basis file (readable by every release)."""
INT8_FORMAT_VERSION = 2
"""Format version of an int8 basis file (``component_scales`` beside int8 ``components``)."""
COMPONENT_STORAGES: tuple[str, ...] = ("float16", "int8")
HASH_VERSION = b"litege-udf-pca-v1"
_HEADER_KEY = "litege_udf_pca"

#: name → on-disk dtype of every tensor of the file, in hashing order.
TENSOR_DTYPES: dict[str, np.dtype] = {
    "voxel_indices": np.dtype(np.int64),
    "centers": np.dtype(np.float32),
    "mean": np.dtype(np.float32),
    "components": np.dtype(np.float16),
    "explained_variance": np.dtype(np.float64),
    "explained_variance_ratio": np.dtype(np.float64),
}
#: The same for an int8 basis file: int8 component codes and their per-component scales.
INT8_TENSOR_DTYPES: dict[str, np.dtype] = {
    **TENSOR_DTYPES,
    "components": np.dtype(np.int8),
    "component_scales": np.dtype(np.float32),
}


def int8_scales(components: NDArray) -> NDArray:
    """``(k,)`` float32 per-component scales that map ``(k, M)`` components onto int8 codes
    in [-127, 127] (``max |row| / 127``; 1 for an all-zero row)."""
    peak = np.abs(np.asarray(components, dtype=np.float64)).max(axis=1) / 127.0
    return np.where(peak > 0, peak, 1.0).astype(np.float32)


VOXEL_LATTICES: tuple[str, ...] = ("full", "bcc", "stride2")
"""Which informative voxels a :class:`DescriptorEngine` evaluates the UDF at:

* ``"full"`` (default): every one; the descriptor the networks were trained on.
* ``"bcc"``: voxels whose grid indices ``(i, j, k)`` are all even or all odd (a body-centred
  lattice, about 1/4 of them);
* ``"stride2"``: voxels whose indices are all even (about 1/8).

On a lattice, the codes are the least-squares fit of the components to the UDF at the kept
voxels, ``z = (P_S P_Sᵀ)⁻¹ P_S (u_S − μ_S)``, and the residual is that fit's residual scaled by
``√(M / |S|)`` (an estimate of the full one). The UDF is smooth at the voxel scale, so the codes
stay close to the full ones (issue 17, measured by ``scripts/bench_predictor.py
--accuracy``, BENCHMARKS.md ``predictor-accuracy``); they are an approximation. The predictors'
default is :data:`AUTO_LATTICE` (see :meth:`UdfPcaBasis.resolve_lattice`)."""

AUTO_LATTICE = "auto"
"""The default lattice of the predictors: ``"stride2"`` where it keeps at least
:data:`AUTO_STRIDE2_VOXELS_PER_COMPONENT` voxels per component, else ``"full"``."""

LATTICE_CHOICES: tuple[str, ...] = (AUTO_LATTICE, *VOXEL_LATTICES)
"""What a predictor's lattice argument accepts."""

AUTO_STRIDE2_VOXELS_PER_COMPONENT = 8
"""``"auto"`` takes ``"stride2"`` when its least-squares fit is this over-determined. The shipped
bases keep 11.5–12.6 voxels per component there (2,765–3,020 for 240 components), and their
real-shape error moves by at most ±0.03 against the full lattice (BENCHMARKS
``default-speed-configuration``); a small basis fitted by a user falls back to the full lattice."""


def lattice_voxels(grid: VoxelGrid, voxel_indices: ArrayLike, lattice: str) -> NDArray:
    """Positions (into ``voxel_indices``) of the voxels ``lattice`` keeps (sorted)."""
    if lattice not in VOXEL_LATTICES:
        raise InputError(f"lattice must be one of {VOXEL_LATTICES}, got {lattice!r}")
    indices = np.asarray(voxel_indices, dtype=np.int64)
    if lattice == "full":
        return np.arange(indices.shape[0])
    odd = grid.ijk(indices) % 2 == 1  # (M, 3)
    keep = ~odd.any(axis=1)
    if lattice == "bcc":
        keep |= odd.all(axis=1)
    return np.flatnonzero(keep)


class LatticeProjection(NamedTuple):
    """A basis's descriptor on one lattice, in numpy (the torch-free runtime's; the
    :class:`DescriptorEngine` places the same arrays on a device).

    Attributes:
        kept: ``(|S|,)`` positions (into the informative voxels) of the evaluated voxels.
        centers: ``(|S|, 3)`` float32 their centres.
        mean: ``(|S|,)`` float32 mean UDF there.
        projection: ``(|S|, k)`` float32 centred UDF → codes: ``Pᵀ`` on the full lattice,
            the least-squares fit ``P_Sᵀ (P_S P_Sᵀ)⁻¹`` on a sparser one.
        components: ``(k, |S|)`` float32 codes → the fitted centred UDF.
        residual_scale: ``√(M / |S|)``, the residual's scale to an estimate of the full one.
    """

    kept: NDArray
    centers: NDArray
    mean: NDArray
    projection: NDArray
    components: NDArray
    residual_scale: float

    def describe(self, udf: NDArray) -> tuple[NDArray, NDArray]:
        """``(..., |S|)`` UDF at :attr:`centers` → ``(..., k)`` float32 codes and ``(...)``
        float32 reconstruction residuals (scaled to the full lattice)."""
        centred = np.asarray(udf, dtype=np.float32) - self.mean
        codes = centred @ self.projection
        fitted = codes @ self.components
        residual = np.linalg.norm(centred - fitted, axis=-1) * np.float32(self.residual_scale)
        return codes, residual


class DescriptorResult(NamedTuple):
    """Descriptors of a batch of clouds.

    Attributes:
        descriptors: ``(B, k)`` float32 codes ``(udf − μ)Pᵀ``.
        residual: ``(B,)`` float32 ``‖udf − μ − PᵀP(udf − μ)‖``, an out-of-distribution score.
        udf: ``(B, M)`` float32 UDF at the informative voxels (at the lattice's voxels only,
            ``(B, |S|)``, for an engine on a lattice).
    """

    descriptors: torch.Tensor
    residual: torch.Tensor
    udf: torch.Tensor


class DescriptorEngine:
    """A basis placed on one device: centres, mean and components uploaded once.

    Build with :meth:`UdfPcaBasis.engine`.

    The reconstruction residual is computed directly, ``‖c − zP‖`` (see :meth:`_residual`).
    """

    def __init__(
        self,
        basis: UdfPcaBasis,
        device: torch.device,
        udf_backend: UdfBackend,
        lattice: str = "full",
    ) -> None:
        import torch

        self.device = device
        self.n_components = basis.n_components
        self.lattice = lattice
        pieces = basis.lattice_projection(lattice)
        self.n_voxels = int(pieces.kept.shape[0])
        self._full = lattice == "full"
        self.udf = UdfEvaluator(pieces.centers, backend=udf_backend, device=device)
        self.mean = torch.from_numpy(np.array(pieces.mean)).to(device)  # (|S|,)
        self._components_t = torch.from_numpy(pieces.projection).to(device)  # (|S|, k)
        self._subset_components = (
            None if self._full else torch.from_numpy(pieces.components).to(device)
        )
        self._residual_scale = pieces.residual_scale

    @property
    def components(self) -> torch.Tensor:
        """``(k, |S|)`` float32 components at the evaluated voxels (all of them: ``(k, M)``)."""
        if self._subset_components is None:
            return self._components_t.T
        return self._subset_components

    def describe_batch(self, clouds: ArrayLike | torch.Tensor) -> torch.Tensor:
        """``(B, P, 3)`` canonical clouds (or a list of ``(P_b, 3)``) → ``(B, k)`` float32."""
        import torch

        with torch.no_grad():
            return (self.udf(clouds) - self.mean) @ self._components_t

    def describe_with_residual(self, clouds: ArrayLike | torch.Tensor) -> DescriptorResult:
        """Descriptors plus the reconstruction residual and the UDF itself."""
        import torch

        with torch.no_grad():
            udf = self.udf(clouds)
            centred = udf - self.mean
            codes = centred @ self._components_t
            residual = self._residual(centred, codes)
        return DescriptorResult(codes, residual, udf)

    def _residual(self, centred: torch.Tensor, codes: torch.Tensor) -> torch.Tensor:
        """``(B,)`` float32 residual ``‖c − zP‖`` of ``(B, |S|)`` centred UDFs and their
        ``(B, k)`` codes, computed directly: the expanded form ``‖c‖² − 2z·Pc + zᵀGz`` is
        cheaper but cancels catastrophically when the residual is small against ``‖c‖``, and
        the residual is the out-of-distribution score, compared across batches and models."""
        import torch

        fitted = codes @ self.components  # (B, |S|): the fit at the evaluated voxels
        return torch.linalg.vector_norm(centred - fitted, dim=1) * self._residual_scale


@dataclass(frozen=True, eq=False)
class UdfPcaBasis:
    """Frozen UDF-PCA basis (see the module docstring).

    Attributes:
        grid: the voxel grid the indices refer to.
        voxel_indices: ``(M,)`` int64 sorted unique flat indices of the informative voxels.
        centers: ``(M, 3)`` float32 their centres, equal to ``grid.centers(voxel_indices)``.
        mean: ``(M,)`` float32 mean UDF of the fit shapes.
        components: ``(k, M)`` float32 principal axes, representable in their storage.
        explained_variance: ``(k,)`` float64 variance along each component.
        explained_variance_ratio: ``(k,)`` float64 fraction of the total UDF variance.
        n_fit_shapes: number of shapes the basis was fitted on.
        metadata: JSON-serialisable provenance (threshold, sample counts, seeds, ...).
        component_scales: ``None`` (components stored float16) or ``(k,)`` positive float32
            scales: components stored as int8 codes ``round(component / scale)`` in
            [-127, 127] (see :func:`int8_scales` and :meth:`with_component_storage`).

    Direct construction validates and raises :class:`~litege_core.errors.InputError`
    subclasses; :meth:`load` reports the same problems as
    :class:`~litege_core.errors.ArtifactError`.
    """

    grid: VoxelGrid
    voxel_indices: NDArray
    centers: NDArray
    mean: NDArray
    components: NDArray
    explained_variance: NDArray
    explained_variance_ratio: NDArray
    n_fit_shapes: int
    metadata: dict[str, Any] = field(default_factory=dict)
    component_scales: NDArray | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.grid, VoxelGrid):
            raise InputError(f"grid must be a VoxelGrid, got {type(self.grid).__name__}")
        indices = self.grid.check_flat_indices(self.voxel_indices, "voxel_indices")
        if indices.size == 0:
            raise ArrayShapeError("a basis needs at least one informative voxel")
        if np.any(np.diff(indices) <= 0):
            raise ArrayShapeError("voxel_indices must be strictly increasing (sorted, unique)")
        m = indices.shape[0]
        centers = self._float_array("centers", (m, 3))
        expected = self.grid.centers(indices, dtype=np.float32)
        if not np.allclose(centers, expected, rtol=0.0, atol=1e-6 * max(1.0, self.grid.upper)):
            worst = int(np.argmax(np.abs(centers - expected).max(axis=1)))
            raise ArrayShapeError(
                f"centers do not match the grid at voxel {int(indices[worst])}: "
                f"{centers[worst].tolist()} vs {expected[worst].tolist()}"
            )
        mean = self._float_array("mean", (m,))
        components = as_numeric(self.components, "components")
        if components.ndim != 2 or components.shape[1] != m or components.shape[0] < 1:
            raise ArrayShapeError(
                f"components must have shape (k ≥ 1, {m}), got {components.shape}"
            )
        k = components.shape[0]
        stored, scales = self._stored_components(components, k)
        variance = self._float_array("explained_variance", (k,), np.float64)
        ratio = self._float_array("explained_variance_ratio", (k,), np.float64)
        if (variance < 0).any() or (ratio < 0).any() or ratio.sum() > 1.0 + 1e-6:
            raise ArrayShapeError(
                "explained variances must be non-negative with ratios summing to at most 1"
            )
        n_fit = positive_int(self.n_fit_shapes, "n_fit_shapes")
        try:
            metadata = json.loads(json.dumps(self.metadata, allow_nan=False))
        except (TypeError, ValueError) as exc:
            raise InputError(f"metadata must be JSON-serialisable: {exc}") from exc
        if not isinstance(metadata, dict):
            raise InputError("metadata must be a JSON object")
        for name, value in (
            ("voxel_indices", indices),
            ("centers", expected),
            ("mean", mean),
            ("components", self._component_values(stored, scales)),
            ("explained_variance", variance),
            ("explained_variance_ratio", ratio),
        ):
            object.__setattr__(self, name, frozen(value, value.dtype))
        object.__setattr__(self, "component_scales", None if scales is None else frozen(scales))
        object.__setattr__(self, "_stored_codes", stored)
        object.__setattr__(self, "n_fit_shapes", n_fit)
        object.__setattr__(self, "metadata", metadata)
        object.__setattr__(self, "_engines", {})

    def _stored_components(self, components: NDArray, k: int) -> tuple[NDArray, NDArray | None]:
        """The components as stored on disk (float16, or int8 codes) and the int8 scales."""
        if self.component_scales is None:
            with np.errstate(over="ignore", invalid="ignore"):
                half = components.astype(np.float16)
            if not np.isfinite(half).all():
                raise ArrayShapeError("components are not finite in float16 (|value| > 65504?)")
            return half, None
        scales = self._float_array("component_scales", (k,))
        if (scales <= 0).any():
            raise ArrayShapeError("component_scales must be positive")
        with np.errstate(over="ignore", invalid="ignore"):
            codes = np.rint(components.astype(np.float64) / scales[:, None])
        if not np.isfinite(codes).all() or np.abs(codes).max() > 127:
            raise ArrayShapeError("components do not fit int8 codes at their component_scales")
        return codes.astype(np.int8), scales

    @staticmethod
    def _component_values(stored: NDArray, scales: NDArray | None) -> NDArray:
        """``(k, M)`` float32 components from their stored form."""
        if scales is None:
            return stored.astype(np.float32)
        return stored.astype(np.float32) * scales[:, None]

    @property
    def component_storage(self) -> str:
        """``"float16"`` or ``"int8"``: how the components are stored on disk."""
        return "float16" if self.component_scales is None else "int8"

    def with_component_storage(self, storage: str) -> UdfPcaBasis:
        """The same basis with its components stored as ``storage`` (:data:`COMPONENT_STORAGES`);
        ``"int8"`` rounds them to per-component int8 codes (:func:`int8_scales`)."""
        if storage not in COMPONENT_STORAGES:
            raise InputError(
                f"component storage must be one of {COMPONENT_STORAGES}, got {storage!r}"
            )
        if storage == self.component_storage:
            return self
        scales = int8_scales(self.components) if storage == "int8" else None
        return dataclasses.replace(self, component_scales=scales)

    def _float_array(self, name: str, shape: tuple[int, ...], dtype: type = np.float32) -> NDArray:
        array = as_numeric(getattr(self, name), name)
        if array.shape != shape:
            raise ArrayShapeError(f"{name} must have shape {shape}, got {array.shape}")
        array = array.astype(dtype)
        if not np.isfinite(array).all():
            raise ArrayShapeError(f"{name} contains NaN or infinite values")
        return array

    # ----------------------------------------------------------------- construction
    @classmethod
    def from_pca(
        cls,
        grid: VoxelGrid,
        voxel_indices: ArrayLike,
        pca: PcaResult,
        n_fit_shapes: int | None = None,
        metadata: dict[str, Any] | None = None,
    ) -> UdfPcaBasis:
        """Basis from a fitted :class:`~litege_core.descriptor.pca.PcaResult` whose features
        are the UDF at ``voxel_indices`` (in that order)."""
        indices = grid.check_flat_indices(voxel_indices, "voxel_indices")
        return cls(
            grid=grid,
            voxel_indices=indices,
            centers=grid.centers(indices, dtype=np.float32),
            mean=pca.mean,
            components=pca.components,
            explained_variance=pca.explained_variance,
            explained_variance_ratio=pca.explained_variance_ratio,
            n_fit_shapes=pca.n_samples if n_fit_shapes is None else n_fit_shapes,
            metadata={"total_variance": pca.total_variance, **(metadata or {})},
        )

    def truncate(self, n_components: int) -> UdfPcaBasis:
        """The same basis keeping only the first ``n_components`` (e.g. 240 of 400)."""
        k = positive_int(n_components, "n_components")
        if k > self.n_components:
            raise InputError(f"cannot keep {k} of {self.n_components} components")
        return UdfPcaBasis(
            grid=self.grid,
            voxel_indices=self.voxel_indices,
            centers=self.centers,
            mean=self.mean,
            components=self.components[:k],
            explained_variance=self.explained_variance[:k],
            explained_variance_ratio=self.explained_variance_ratio[:k],
            n_fit_shapes=self.n_fit_shapes,
            metadata={**self.metadata, "truncated_from": self.n_components},
            component_scales=(None if self.component_scales is None else self.component_scales[:k]),
        )

    # ----------------------------------------------------------------- properties
    @property
    def n_voxels(self) -> int:
        """``M``, informative voxels."""
        return int(self.voxel_indices.shape[0])

    @property
    def n_components(self) -> int:
        """``k``, descriptor length."""
        return int(self.components.shape[0])

    @cached_property
    def pca(self) -> PcaResult:
        """The basis as a float64 :class:`PcaResult` (numpy project / reconstruct /
        reconstruction_residual)."""
        total = float(self.metadata.get("total_variance", 0.0))
        return PcaResult(
            components=self.components.astype(np.float64),
            mean=self.mean.astype(np.float64),
            explained_variance=self.explained_variance,
            explained_variance_ratio=self.explained_variance_ratio,
            singular_values=np.sqrt(self.explained_variance * max(self.n_fit_shapes - 1, 1)),
            total_variance=total,
            n_samples=self.n_fit_shapes,
        )

    def _disk_tensors(self) -> dict[str, NDArray]:
        dtypes = TENSOR_DTYPES if self.component_scales is None else INT8_TENSOR_DTYPES
        stored = {"components": self._stored_codes}  # type: ignore[attr-defined]
        return {
            name: np.ascontiguousarray(stored.get(name, getattr(self, name)), dtype=dtype)
            for name, dtype in dtypes.items()
        }

    @cached_property
    def content_hash(self) -> str:
        """Hex SHA-256 over a version tag, the grid spec and every tensor (name, dtype, shape,
        little-endian bytes as stored on disk). Metadata is not hashed."""
        digest = hashlib.sha256(HASH_VERSION)
        digest.update(json.dumps(self.grid.to_dict(), sort_keys=True).encode())
        for name, array in self._disk_tensors().items():
            digest.update(name.encode())
            digest.update(array.dtype.newbyteorder("<").str.encode())
            digest.update(np.asarray(array.shape, dtype="<i8").tobytes())
            digest.update(array.astype(array.dtype.newbyteorder("<"), copy=False).tobytes())
        return digest.hexdigest()

    @property
    def nbytes_on_disk(self) -> int:
        """Bytes of tensor data in the saved file (without the header)."""
        return sum(a.nbytes for a in self._disk_tensors().values())

    def __eq__(self, other: object) -> bool:
        return isinstance(other, UdfPcaBasis) and other.content_hash == self.content_hash

    def __hash__(self) -> int:
        return hash(self.content_hash)

    def __repr__(self) -> str:
        return (
            f"UdfPcaBasis(grid={self.grid}, n_voxels={self.n_voxels}, "
            f"n_components={self.n_components}, n_fit_shapes={self.n_fit_shapes}, "
            f"hash={self.content_hash[:12]})"
        )

    # ----------------------------------------------------------------- descriptors
    def lattice_projection(self, lattice: str = "full") -> LatticeProjection:
        """The numpy pieces of the descriptor on ``lattice`` (:data:`VOXEL_LATTICES`)."""
        kept = lattice_voxels(self.grid, self.voxel_indices, lattice)
        if lattice == "full":
            components = np.array(self.components)  # (k, M)
            projection = np.ascontiguousarray(components.T)
            centers, mean = np.array(self.centers), np.array(self.mean)
        else:
            subset = self.components[:, kept].astype(np.float64)  # (k, |S|)
            # least squares on the kept voxels: z = (P_S P_Sᵀ)⁻¹ P_S c_S
            projection = np.linalg.solve(subset @ subset.T, subset).T.astype(np.float32)
            components = np.ascontiguousarray(self.components[:, kept])
            centers, mean = self.centers[kept], self.mean[kept]
        return LatticeProjection(
            kept=kept,
            centers=centers,
            mean=mean,
            projection=projection,
            components=components,
            residual_scale=float(np.sqrt(self.n_voxels / kept.shape[0])),
        )

    def resolve_lattice(self, lattice: str = AUTO_LATTICE) -> str:
        """``lattice`` itself, or for :data:`AUTO_LATTICE` the one the predictors use:
        ``"stride2"`` when it keeps at least :data:`AUTO_STRIDE2_VOXELS_PER_COMPONENT` voxels
        per component, else ``"full"``.

        Raises:
            InputError: not one of :data:`LATTICE_CHOICES`.
        """
        if lattice not in LATTICE_CHOICES:
            raise InputError(f"lattice must be one of {LATTICE_CHOICES}, got {lattice!r}")
        if lattice != AUTO_LATTICE:
            return lattice
        kept = lattice_voxels(self.grid, self.voxel_indices, "stride2").shape[0]
        enough = kept >= AUTO_STRIDE2_VOXELS_PER_COMPONENT * self.n_components
        return "stride2" if enough else "full"

    def engine(
        self,
        device: torch.device | str = "cpu",
        udf_backend: str | UdfBackend = "auto",
        lattice: str = "full",
    ) -> DescriptorEngine:
        """The basis placed on ``device`` (built on first use, then cached); ``lattice``: the
        voxels evaluated (:data:`VOXEL_LATTICES`, default every informative voxel)."""
        dev = resolve_device(device)
        backend = UdfBackend.parse(udf_backend)
        if lattice not in VOXEL_LATTICES:
            raise InputError(f"lattice must be one of {VOXEL_LATTICES}, got {lattice!r}")
        key = (str(dev), backend, lattice)
        engines: dict = self._engines  # type: ignore[attr-defined]
        if key not in engines:
            engines[key] = DescriptorEngine(self, dev, resolve_backend(backend, dev), lattice)
        return engines[key]

    def describe(
        self, points: ArrayLike, device: torch.device | str = "cpu", udf_backend: str = "auto"
    ) -> NDArray:
        """Descriptor of one canonical cloud: ``(P, 3)`` → ``(k,)`` float32 numpy."""
        pts = as_points(points, "points", dtype=np.float32)
        codes = self.engine(device, udf_backend).describe_batch(pts[None])
        return codes[0].cpu().numpy()

    def describe_batch(
        self,
        clouds: ArrayLike | torch.Tensor,
        device: torch.device | str = "cpu",
        udf_backend: str = "auto",
    ) -> torch.Tensor:
        """Descriptors of ``(B, P, 3)`` canonical clouds (or a list of ``(P_b, 3)``) →
        ``(B, k)`` float32 tensor on ``device``."""
        return self.engine(device, udf_backend).describe_batch(clouds)

    # ----------------------------------------------------------------- persistence
    def header(self) -> dict[str, Any]:
        """The JSON document stored in the file's header metadata."""
        return {
            "format": FORMAT_NAME,
            "format_version": self._format_version,
            "grid": self.grid.to_dict(),
            "n_voxels": self.n_voxels,
            "n_components": self.n_components,
            "n_fit_shapes": self.n_fit_shapes,
            "content_hash": self.content_hash,
            "metadata": self.metadata,
        }

    @property
    def _format_version(self) -> int:
        return FORMAT_VERSION if self.component_scales is None else INT8_FORMAT_VERSION

    def save(self, path: str | os.PathLike[str]) -> None:
        """Write the basis to ``path`` (safetensors + JSON header metadata), atomically."""
        target = os.fspath(path)
        temporary = f"{target}.tmp-{os.getpid()}"
        try:
            save_file(
                self._disk_tensors(),
                temporary,
                metadata={"format": FORMAT_NAME, _HEADER_KEY: json.dumps(self.header())},
            )
            os.replace(temporary, target)
        except OSError as exc:
            raise ArtifactError(f"cannot write basis to {target}: {exc}") from exc
        finally:
            if os.path.exists(temporary):
                os.remove(temporary)

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> UdfPcaBasis:
        """Read and validate a basis written by :meth:`save`.

        Raises:
            ArtifactError: unreadable or truncated file, wrong format or version, missing or
                extra tensors, wrong dtypes or shapes, indices outside the grid, centres not
                matching the grid, or a content hash that differs from the recorded one.
        """
        source = os.fspath(path)
        try:
            with safe_open(source, framework="np") as handle:
                file_metadata = handle.metadata() or {}
                tensors = {name: handle.get_tensor(name) for name in handle.keys()}  # noqa: SIM118
        except (OSError, SafetensorError, ValueError, TypeError) as exc:
            raise ArtifactError(f"cannot read basis file {source}: {exc}") from exc
        if file_metadata.get("format") != FORMAT_NAME or _HEADER_KEY not in file_metadata:
            raise ArtifactError(f"{source} is not a {FORMAT_NAME} file (header metadata missing)")
        try:
            header = json.loads(file_metadata[_HEADER_KEY])
        except ValueError as exc:
            raise ArtifactError(f"{source}: header JSON is invalid: {exc}") from exc
        if not isinstance(header, dict):
            raise ArtifactError(f"{source}: header JSON is not an object")
        dtypes = {FORMAT_VERSION: TENSOR_DTYPES, INT8_FORMAT_VERSION: INT8_TENSOR_DTYPES}.get(
            header.get("format_version")  # type: ignore[arg-type]
        )
        if dtypes is None:
            raise ArtifactError(
                f"{source}: unsupported format_version {header.get('format_version')!r}, "
                f"this library reads {FORMAT_VERSION} and {INT8_FORMAT_VERSION}"
            )
        missing = sorted(set(dtypes) - set(tensors))
        extra = sorted(set(tensors) - set(dtypes))
        if missing or extra:
            raise ArtifactError(f"{source}: missing tensors {missing}, unexpected tensors {extra}")
        for name, dtype in dtypes.items():
            if tensors[name].dtype != dtype:
                raise ArtifactError(
                    f"{source}: tensor {name!r} has dtype {tensors[name].dtype}, expected {dtype}"
                )
        if "component_scales" in tensors:
            tensors["components"] = cls._component_values(
                tensors["components"], tensors["component_scales"]
            )
        try:
            basis = cls(
                grid=VoxelGrid.from_dict(header.get("grid")),  # type: ignore[arg-type]
                n_fit_shapes=header.get("n_fit_shapes"),  # type: ignore[arg-type]
                metadata=header.get("metadata", {}),
                **tensors,
            )
        except LiteGEError as exc:
            raise ArtifactError(f"{source}: inconsistent basis: {exc}") from exc
        for key, actual in (
            ("n_voxels", basis.n_voxels),
            ("n_components", basis.n_components),
        ):
            if header.get(key) != actual:
                raise ArtifactError(
                    f"{source}: header says {key}={header.get(key)!r}, tensors say {actual}"
                )
        if header.get("content_hash") != basis.content_hash:
            raise ArtifactError(
                f"{source}: content hash mismatch (header {header.get('content_hash')!r}, "
                f"tensors {basis.content_hash!r}): the file was modified or corrupted"
            )
        return basis


__all__ = [
    "AUTO_LATTICE",
    "AUTO_STRIDE2_VOXELS_PER_COMPONENT",
    "COMPONENT_STORAGES",
    "FORMAT_NAME",
    "FORMAT_VERSION",
    "INT8_FORMAT_VERSION",
    "INT8_TENSOR_DTYPES",
    "LATTICE_CHOICES",
    "TENSOR_DTYPES",
    "VOXEL_LATTICES",
    "DescriptorEngine",
    "DescriptorResult",
    "LatticeProjection",
    "UdfPcaBasis",
    "int8_scales",
    "lattice_voxels",
]
