"""What a registration of one shape holds: the serializable :class:`ShapeRecord`, the live
:class:`ShapeState` (tensors on the predictor's device) and :class:`ResolvedPoints` (query
points resolved on a state)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch
from numpy.typing import NDArray

from litege_core.arrays import frozen
from litege_core.canonical import Transform
from litege_core.errors import ArtifactError, InputError
from litege_core.projection import CloudProjector, MeshProjector
from litege_core.shape import ShapeKind

OOD_Z_THRESHOLD = 1.25
"""``ood_score`` above which a shape counts as out of distribution (calibrated bundles).

Calibrated on the real dev shapes by ``scripts/calibrate_ood.py`` (BENCHMARKS.md
"ood-calibration"): the largest threshold that flags at least 90 % of the registrations of a
shape under the other category's model (a human under ``quadrupeds``); real shapes it flags
under their own model have about twice the error of those it does not."""


@dataclass(frozen=True, eq=False)
class ShapeRecord:
    """The small, serializable half of a registration: everything :meth:`Predictor.restore`
    needs besides the shape's own arrays to rebuild its :class:`ShapeState` without
    recomputing the UDF-PCA descriptor.

    Attributes:
        shape_id: content hash of the shape it describes.
        bundle_hash: content hash of the bundle that computed it.
        transform: user frame → canonical frame.
        descriptor: ``(k,)`` float32 UDF-PCA descriptor (read-only).
        residual: PCA reconstruction residual (canonical units).
        seed: seed of the surface samples the descriptor came from.
    """

    shape_id: str
    bundle_hash: str
    transform: Transform
    descriptor: NDArray
    residual: float
    seed: int

    def to_arrays(self) -> dict[str, NDArray]:
        """Plain numpy arrays (for safetensors or any other pickle-free format)."""
        return {
            "shape_id": np.frombuffer(self.shape_id.encode("ascii"), dtype=np.uint8).copy(),
            "bundle_hash": np.frombuffer(self.bundle_hash.encode("ascii"), dtype=np.uint8).copy(),
            "rotation": np.asarray(self.transform.rotation, dtype=np.float64),
            "center": np.asarray(self.transform.center, dtype=np.float64),
            "scale": np.array([self.transform.scale], dtype=np.float64),
            "descriptor": np.asarray(self.descriptor, dtype=np.float32),
            "residual": np.array([self.residual], dtype=np.float64),
            "seed": np.array([self.seed], dtype=np.int64),
        }

    @classmethod
    def from_arrays(cls, arrays: dict[str, NDArray]) -> ShapeRecord:
        """Inverse of :meth:`to_arrays`.

        Raises:
            ArtifactError: keys are missing or arrays have the wrong shape or values.
        """
        try:
            descriptor = np.asarray(arrays["descriptor"], dtype=np.float32)
            record = cls(
                shape_id=bytes(np.asarray(arrays["shape_id"], dtype=np.uint8)).decode("ascii"),
                bundle_hash=bytes(np.asarray(arrays["bundle_hash"], dtype=np.uint8)).decode(
                    "ascii"
                ),
                transform=Transform(
                    arrays["rotation"], arrays["center"], float(arrays["scale"].reshape(-1)[0])
                ),
                descriptor=frozen(descriptor),
                residual=float(arrays["residual"].reshape(-1)[0]),
                seed=int(arrays["seed"].reshape(-1)[0]),
            )
        except (KeyError, IndexError, ValueError, TypeError, UnicodeDecodeError) as exc:
            raise ArtifactError(f"malformed shape record: {exc}") from exc
        except InputError as exc:
            raise ArtifactError(f"malformed shape record: {exc}") from exc
        if descriptor.ndim != 1 or not np.all(np.isfinite(descriptor)):
            raise ArtifactError("malformed shape record: descriptor must be a finite vector")
        return record


@dataclass(frozen=True, eq=False)
class ShapeState:
    """Everything cached for one registered shape (build with :meth:`Predictor.register`).

    Attributes:
        shape_id: the shape's content hash (:attr:`Shape.content_hash`).
        kind: mesh or point cloud.
        n_points: ``N``, vertices of a mesh or points of a cloud.
        transform: user frame → canonical frame (distances: canonical = user × ``scale``).
        descriptor: ``(k,)`` float32 UDF-PCA descriptor (read-only).
        residual: PCA reconstruction residual of the UDF (canonical units).
        ood_score: z-score of ``residual`` against the training shapes (or the raw residual
            when the bundle has no calibration, see ``ood_calibrated``).
        ood_calibrated: whether the bundle provided training residual statistics.
        bundle_hash: content hash of the bundle the state was computed with.
        vertices: ``(N, 3)`` float64 vertices in the user's frame (read-only, the shape's own
            array).
        faces: ``(F, 3)`` int64 triangles (read-only) for meshes, ``None`` for clouds.
        device: the predictor's device, where the state's tensors live.
        shape_embedding: ``(n,)`` tensor, the shape MLP output.
        shape_bias: ``(n,)`` tensor, shape part of the folded point MLP.
        record: the :class:`ShapeRecord` the state was built from (what a cache stores).

    Tensors are shared with the predictor's caches: treat them as read-only. Four things are
    built on first use and kept with the state: the canonical vertices (:attr:`canonical_points`
    on the host, :attr:`canonical_vertices` on the device; a query of a few points maps just
    those), the ``(N, 2n)`` head-feature table of every point (:attr:`feature_table`, built by
    :meth:`Predictor.point_table` when a query needs most points; a query of a few points
    embeds just those), and the surface projector used by xyz queries and paths. A small-head
    predictor (``Predictor(..., head="small")``) keeps its own ``(N, m)`` table beside it,
    under another key (:meth:`Predictor.point_table`).
    """

    shape_id: str
    kind: ShapeKind
    n_points: int
    transform: Transform
    descriptor: NDArray
    residual: float
    ood_score: float
    ood_calibrated: bool
    bundle_hash: str
    vertices: NDArray = field(repr=False)
    faces: NDArray | None = field(repr=False)
    device: torch.device
    shape_embedding: torch.Tensor = field(repr=False)
    shape_bias: torch.Tensor = field(repr=False)
    record: ShapeRecord | None = field(default=None, repr=False)
    _lazy: dict[str, Any] = field(default_factory=dict, repr=False)

    @property
    def is_mesh(self) -> bool:
        return self.kind is ShapeKind.MESH

    @property
    def is_out_of_distribution(self) -> bool | None:
        """``ood_score > OOD_Z_THRESHOLD`` for calibrated bundles, ``None`` otherwise."""
        return self.ood_score > OOD_Z_THRESHOLD if self.ood_calibrated else None

    @property
    def canonical_points(self) -> NDArray:
        """``(N, 3)`` float64 canonical vertices (read-only numpy; mapped on first use)."""
        points = self._lazy.get("canonical_points")
        if points is None:
            points = self._lazy["canonical_points"] = frozen(self.transform.apply(self.vertices))
        return points

    def canonical_rows(self, indices: NDArray) -> NDArray:
        """``(Q, 3)`` float64 canonical coordinates of vertices ``indices``: the rows of
        :attr:`canonical_points`, without mapping the other vertices while it is not built."""
        points = self._lazy.get("canonical_points")
        if points is None:
            return self.transform.apply(self.vertices[indices])
        return points[indices]

    @property
    def canonical_vertices(self) -> torch.Tensor:
        """``(N, 3)`` float32 canonical vertices on :attr:`device` (uploaded on first use)."""
        vertices = self._lazy.get("canonical_vertices")
        if vertices is None:
            points = self.canonical_points.astype(np.float32)  # a writable copy
            vertices = self._lazy["canonical_vertices"] = torch.from_numpy(points).to(self.device)
        return vertices

    @property
    def feature_table(self) -> torch.Tensor | None:
        """``(N, 2n)`` head features of every point, or ``None`` until a query built it."""
        return self._lazy.get("features")

    @property
    def nbytes(self) -> int:
        """Bytes held by the cached arrays and tensors, for cache accounting: including, once
        built, the canonical vertices, the feature tables (the full head's and a small head's)
        and what the graph fusion keeps (a cloud's or a mesh's graph, the normals, a k-d
        tree). The embedding and bias count as the storage they keep alive: a state
        registered in a batch holds views of the batch's rows."""
        storages = {
            t.untyped_storage().data_ptr(): t.untyped_storage().nbytes()
            for t in (self.shape_embedding, self.shape_bias)
        }
        tensors = [
            v for k, v in self._lazy.items() if k.startswith(("features", "canonical_vertices"))
        ]
        total = sum(storages.values()) + sum(t.numel() * t.element_size() for t in tensors)
        total += sum(_fusion_nbytes(v) for k, v in self._lazy.items() if k.startswith("fusion."))
        if "canonical_points" in self._lazy:
            total += self._lazy["canonical_points"].nbytes
        total += self.descriptor.nbytes
        return int(total + (0 if self.faces is None else self.faces.nbytes))

    @property
    def projector(self) -> MeshProjector | CloudProjector:
        """Surface projector in the canonical frame (built on first use)."""
        projector = self._lazy.get("projector")
        if projector is None:
            if self.faces is not None:
                projector = MeshProjector(self.canonical_points, self.faces)
            else:
                projector = CloudProjector(self.canonical_points)
            self._lazy["projector"] = projector
        return projector

    @property
    def spacing(self) -> float:
        """Sampling resolution in canonical units: mean edge length (mesh) or mean
        nearest-neighbour distance (cloud)."""
        projector = self.projector
        if isinstance(projector, MeshProjector):
            return projector.mean_edge_length
        return projector.mean_spacing


@dataclass(frozen=True)
class ResolvedPoints:
    """Query points resolved on one shape.

    Attributes:
        features: ``(Q, 2n)`` head features.
        positions: ``(Q, 3)`` float32 canonical coordinates (tensor, on the device).
        canonical: ``(Q, 3)`` float64 canonical coordinates (numpy).
        user: ``(Q, 3)`` float64 coordinates in the user's frame (the vertices themselves for
            indices, the projected points mapped back for xyz queries).
        indices: ``(Q,)`` int64 vertex indices, or ``None`` for projected xyz points.
    """

    features: torch.Tensor
    positions: torch.Tensor
    canonical: NDArray
    user: NDArray
    indices: NDArray | None

    @property
    def count(self) -> int:
        return int(self.positions.shape[0])


def _fusion_nbytes(value: Any) -> int:
    """Bytes of one thing the graph fusion keeps with a state: a sparse graph, a cloud's
    lazily vetoed graph, the ``(roughness, normals)`` pair, a mesh's vertex normals, the veto's
    feature rows or a k-d tree (its points and index)."""
    if isinstance(value, np.ndarray):  # a mesh's vertex normals
        return int(value.nbytes)
    if hasattr(value, "indptr"):  # a CSR graph
        return int(value.data.nbytes + value.indices.nbytes + value.indptr.nbytes)
    if isinstance(value, tuple):  # (roughness, normals) or (veto features, each point's row)
        return int(sum(_array_nbytes(part) for part in value))
    if hasattr(value, "judged"):  # a LazyVetoGraph
        return int(value.nbytes)
    if hasattr(value, "data") and hasattr(value, "indices"):  # a cKDTree
        return int(value.data.nbytes + value.indices.nbytes)
    return 0


def _array_nbytes(value: Any) -> int:
    """Bytes of a numpy array or a torch tensor (0 for anything else)."""
    if isinstance(value, torch.Tensor):
        return value.numel() * value.element_size()
    return int(getattr(value, "nbytes", 0))


__all__ = ["OOD_Z_THRESHOLD", "ResolvedPoints", "ShapeRecord", "ShapeState"]
