"""Training and validation tables, built once before training, and vectorized pair batches.

**Views.** Every shape of a split gets ``K`` views (:mod:`litege_core.train.augment`). For each
view the transform ``T = canonicalize_bbox(view points)`` is computed, the descriptor is the
basis's UDF-PCA code of ``T(points)`` (batched through the basis engine), the canonical
vertices are ``T(R · vertices)`` (the clean mesh moved like the view and canonicalized with the
view's frame) and the canonical distance scale is ``T.scale``.

**Tables** (:class:`ViewTables`, all tensors on one device; no per-record Python access)::

    descriptors (Nv, E) float32   UDF-PCA codes of the views
    vertices    (Nv, V, 3) float32 canonical vertices of the clean mesh, per view
    scale       (Nv,) float32      canonical units per raw unit
    shape       (Nv,) int64        shape index of each view (into distances / sources)
    kind        (Nv,) int64        0 clean, 1 augmented
    residual    (Nv,) float32      PCA reconstruction residual of the view's UDF
    n_points    (Nv,) int64        points of the view's cloud
    distances   (Ns, R, V) float16/32  raw geodesic rows (as stored by the dataset)
    sources     (Ns, R) int64      vertex index of every row

**Batches** (:class:`PairSampler`). A step draws ``B`` views, ``R_b`` distinct source rows and
``T_b`` random target vertices per view, and gathers everything by tensor indexing: the
``R_b + T_b`` points of a view are embedded once and the network head runs on the
``B · R_b · T_b`` cross pairs (see :mod:`litege_core.train.trainer`). Targets are
``residual_target(s · g_raw, ‖v_s − v_t‖)`` with the Euclidean distance on the canonical,
un-normalized vertices (spec §3.3).

**Validation** (:class:`ValidationPairs`): fixed, seeded ``val_sources × val_targets`` pairs
per validation view, so the metric is comparable across epochs and runs.
"""

from __future__ import annotations

import hashlib
import logging
from dataclasses import dataclass, fields
from pathlib import Path
from typing import NamedTuple

import numpy as np
import torch
from numpy.typing import NDArray

from litege_core.canonical import canonicalize_bbox
from litege_core.datasets import GeodesicDataset
from litege_core.datasets.storage import MANIFEST
from litege_core.descriptor import UdfPcaBasis
from litege_core.errors import ArtifactError, InputError
from litege_core.nets import residual_target
from litege_core.train.augment import View, augmented_view, clean_view
from litege_core.train.config import AugmentConfig

LOG = logging.getLogger("litege.train")


# --------------------------------------------------------------------------- tables


@dataclass(frozen=True)
class ViewTables:
    """Per-view and per-shape tensors of one split (see the module docstring for shapes)."""

    descriptors: torch.Tensor
    vertices: torch.Tensor
    scale: torch.Tensor
    shape: torch.Tensor
    kind: torch.Tensor
    residual: torch.Tensor
    n_points: torch.Tensor
    distances: torch.Tensor
    sources: torch.Tensor

    @property
    def n_views(self) -> int:
        return int(self.descriptors.shape[0])

    @property
    def n_shapes(self) -> int:
        return int(self.distances.shape[0])

    @property
    def n_rows(self) -> int:
        """``R``, source rows per shape."""
        return int(self.distances.shape[1])

    @property
    def n_vertices(self) -> int:
        return int(self.vertices.shape[1])

    @property
    def device(self) -> torch.device:
        return self.descriptors.device

    def to(self, device: torch.device | str) -> ViewTables:
        """The same tables on ``device``."""
        return ViewTables(**{f.name: getattr(self, f.name).to(device) for f in fields(self)})


def dataset_fingerprint(directory: str | Path) -> dict[str, object]:
    """SHA-256 of the dataset's manifest file and its split counts (for provenance)."""
    path = Path(directory) / MANIFEST
    dataset = GeodesicDataset(directory)
    return {
        "path": str(directory),
        "name": dataset.spec.name,
        "category": dataset.spec.category,
        "manifest_sha256": hashlib.sha256(path.read_bytes()).hexdigest(),
        "counts": dict(dataset.manifest["counts"]),
    }


def load_split_arrays(
    dataset: GeodesicDataset, split: str, max_shapes: int = 0
) -> dict[str, NDArray]:
    """``dataset.load_split(split)``, truncated to the first ``max_shapes`` shapes (0: all),
    with the distance rows checked to be finite."""
    arrays = dataset.load_split(split)
    if max_shapes:
        arrays = {key: value[:max_shapes] for key, value in arrays.items()}
    if not np.isfinite(arrays["distances"]).all():
        raise ArtifactError(f"split {split!r} of {dataset.directory} has non-finite distances")
    return arrays


def make_views(
    vertices: NDArray,
    faces: NDArray,
    area: float,
    n_views: int,
    clean_samples: int,
    augment: AugmentConfig,
    seed: int,
    shape_seed: int,
) -> list[View]:
    """The ``n_views`` views of one shape (view 0 clean). View ``j`` draws from the stream
    ``default_rng([seed, shape_seed, j])``: independent of the other views and shapes."""
    views = []
    for j in range(n_views):
        rng = np.random.default_rng([seed, shape_seed, j])
        if j == 0:
            views.append(clean_view(vertices, faces, clean_samples, rng))
        else:
            views.append(augmented_view(vertices, faces, area, augment, rng))
    return views


def build_view_tables(
    arrays: dict[str, NDArray],
    faces: NDArray,
    basis: UdfPcaBasis,
    *,
    n_views: int,
    clean_samples: int,
    augment: AugmentConfig,
    seed: int,
    device: torch.device | str = "cpu",
    chunk: int = 64,
) -> ViewTables:
    """Build the tables of one split (see the module docstring).

    Args:
        arrays: a split as returned by :func:`load_split_arrays` (vertices ``(S, V, 3)``,
            sources ``(S, R)``, distances ``(S, R, V)``, area ``(S,)``, seed ``(S,)``).
        faces: ``(F, 3)`` shared triangulation.
        basis: the UDF-PCA basis (descriptor size ``E``).
        n_views: views per shape (view 0 clean).
        clean_samples: samples of the clean view.
        augment: augmentation settings of the other views.
        seed: run seed (combined with each shape's dataset seed).
        device: where the tables (and the descriptor engine) live.
        chunk: views per descriptor call.
    """
    if n_views < 1:
        raise InputError("n_views must be at least 1")
    raw_vertices = np.asarray(arrays["vertices"], dtype=np.float64)
    n_shapes, n_vertices = raw_vertices.shape[:2]
    if n_shapes == 0:
        raise InputError("cannot build training tables from an empty split")
    engine = basis.engine(device)
    n_total = n_shapes * n_views
    canonical = np.empty((n_total, n_vertices, 3), dtype=np.float32)
    scale = np.empty(n_total, dtype=np.float64)
    kind = np.empty(n_total, dtype=np.int64)
    n_points = np.empty(n_total, dtype=np.int64)
    descriptors: list[torch.Tensor] = []
    residuals: list[torch.Tensor] = []
    pending: list[NDArray] = []

    def flush() -> None:
        if pending:
            result = engine.describe_with_residual([p.astype(np.float32) for p in pending])
            descriptors.append(result.descriptors)
            residuals.append(result.residual)
            pending.clear()

    for s in range(n_shapes):
        views = make_views(
            raw_vertices[s],
            faces,
            float(arrays["area"][s]),
            n_views,
            clean_samples,
            augment,
            seed,
            int(arrays["seed"][s]),
        )
        for j, view in enumerate(views):
            index = s * n_views + j
            transform = canonicalize_bbox(view.points)
            canonical[index] = transform.apply(raw_vertices[s] @ view.rotation.T)
            scale[index] = transform.scale
            kind[index] = view.kind
            n_points[index] = view.points.shape[0]
            pending.append(transform.apply(view.points))
            if len(pending) >= chunk:
                flush()
    flush()
    tables = ViewTables(
        descriptors=torch.cat(descriptors).to(device=device, dtype=torch.float32),
        vertices=torch.from_numpy(canonical).to(device),
        scale=torch.from_numpy(scale.astype(np.float32)).to(device),
        shape=torch.arange(n_shapes, device=device).repeat_interleave(n_views),
        kind=torch.from_numpy(kind).to(device),
        residual=torch.cat(residuals).to(device=device, dtype=torch.float32),
        n_points=torch.from_numpy(n_points).to(device),
        distances=torch.from_numpy(np.ascontiguousarray(arrays["distances"])).to(device),
        sources=torch.from_numpy(arrays["sources"].astype(np.int64)).to(device),
    )
    return tables


# --------------------------------------------------------------------------- batches


class PairBatch(NamedTuple):
    """One training batch (``B`` views, ``R_b`` sources × ``T_b`` targets each).

    Attributes:
        views: ``(B,)`` int64 view indices.
        descriptors: ``(B, E)`` float32.
        points: ``(B, R_b + T_b, 3)`` canonical coordinates: sources first, then targets.
        geodesic: ``(B, R_b, T_b)`` float32 ground truth, canonical units.
        euclidean: ``(B, R_b, T_b)`` float32 ``‖v_s − v_t‖``, canonical units.
        target: ``(B, R_b, T_b)`` float32 ``residual_target(geodesic, euclidean)`` (×1.42).
    """

    views: torch.Tensor
    descriptors: torch.Tensor
    points: torch.Tensor
    geodesic: torch.Tensor
    euclidean: torch.Tensor
    target: torch.Tensor


def gather_pairs(
    tables: ViewTables, views: torch.Tensor, rows: torch.Tensor, targets: torch.Tensor
) -> PairBatch:
    """Gather the cross pairs ``rows × targets`` of each view.

    Args:
        tables: the split's tables.
        views: ``(B,)`` int64 view indices.
        rows: ``(B, R_b)`` int64 source *row* indices (into ``distances[shape]``).
        targets: ``(B, T_b)`` int64 target vertex indices.
    """
    shape = tables.shape[views]  # (B,)
    n_sources = rows.shape[1]
    source_vertex = tables.sources[shape[:, None], rows]  # (B, R_b)
    vertex_index = torch.cat((source_vertex, targets), dim=1)  # (B, R_b + T_b)
    points = tables.vertices[views[:, None], vertex_index]  # (B, R_b + T_b, 3)
    raw = tables.distances[shape[:, None, None], rows[:, :, None], targets[:, None, :]]
    geodesic = raw.to(torch.float32) * tables.scale[views][:, None, None]
    euclidean = torch.linalg.vector_norm(
        points[:, :n_sources, None, :] - points[:, None, n_sources:, :], dim=-1
    )
    return PairBatch(
        views=views,
        descriptors=tables.descriptors[views],
        points=points,
        geodesic=geodesic,
        euclidean=euclidean,
        target=residual_target(geodesic, euclidean),
    )


class PairSampler:
    """Seeded, vectorized batch sampler over a :class:`ViewTables`.

    Indices are drawn on the CPU with a private :class:`torch.Generator` (its state is part of
    a checkpoint, so a resumed run draws exactly the batches an uninterrupted run would) and
    moved to the tables' device for the gathers.

    Args:
        tables: the training tables.
        batch_views: ``B``, views per batch (drawn with replacement across steps, distinct
            within a batch when ``B ≤ Nv``).
        sources_per_view: ``R_b ≤ R`` distinct source rows per view.
        targets_per_view: ``T_b`` target vertices per view (uniform, with replacement).
        seed: seed of the generator.
    """

    def __init__(
        self,
        tables: ViewTables,
        batch_views: int,
        sources_per_view: int,
        targets_per_view: int,
        seed: int,
    ) -> None:
        if sources_per_view > tables.n_rows:
            raise InputError(
                f"sources_per_view={sources_per_view} exceeds the {tables.n_rows} source rows "
                "per shape of the dataset"
            )
        self.tables = tables
        self.batch_views = batch_views
        self.sources_per_view = sources_per_view
        self.targets_per_view = targets_per_view
        self.generator = torch.Generator().manual_seed(seed)

    def draw(self) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """``(views (B,), rows (B, R_b), targets (B, T_b))`` int64 on the tables' device."""
        g, t = self.generator, self.tables
        b = self.batch_views
        if b <= t.n_views:
            views = torch.randperm(t.n_views, generator=g)[:b]
        else:
            views = torch.randint(t.n_views, (b,), generator=g)
        rows = torch.rand(b, t.n_rows, generator=g).argsort(dim=1)[:, : self.sources_per_view]
        targets = torch.randint(t.n_vertices, (b, self.targets_per_view), generator=g)
        device = t.device
        return views.to(device), rows.to(device), targets.to(device)

    def sample(self) -> PairBatch:
        """The next batch."""
        return gather_pairs(self.tables, *self.draw())

    def get_state(self) -> torch.Tensor:
        return self.generator.get_state()

    def set_state(self, state: torch.Tensor) -> None:
        self.generator.set_state(state.to(torch.uint8).cpu())


# --------------------------------------------------------------------------- validation


@dataclass(frozen=True)
class ValidationPairs:
    """Fixed validation pairs: per view ``rows (Nv, Rv)`` × ``targets (Nv, Tv)``."""

    tables: ViewTables
    rows: torch.Tensor
    targets: torch.Tensor

    @property
    def n_pairs(self) -> int:
        return int(self.rows.shape[0] * self.rows.shape[1] * self.targets.shape[1])


def validation_pairs(
    tables: ViewTables, n_sources: int, n_targets: int, seed: int
) -> ValidationPairs:
    """Draw the fixed validation pairs (``min(n_sources, R)`` distinct rows per view)."""
    generator = torch.Generator().manual_seed(seed)
    n_sources = min(n_sources, tables.n_rows)
    rows = torch.rand(tables.n_views, tables.n_rows, generator=generator).argsort(dim=1)
    targets = torch.randint(tables.n_vertices, (tables.n_views, n_targets), generator=generator)
    device = tables.device
    return ValidationPairs(tables, rows[:, :n_sources].to(device), targets.to(device))


def coordinate_statistics(tables: ViewTables) -> tuple[NDArray, NDArray]:
    """Per-axis mean and population std ``(3,)`` float64 of all canonical training vertices
    of all views (the network's coordinate normalization, spec §3.3)."""
    points = tables.vertices.reshape(-1, 3).to(torch.float64)
    return points.mean(dim=0).cpu().numpy(), points.std(dim=0, correction=0).cpu().numpy()


__all__ = [
    "PairBatch",
    "PairSampler",
    "ValidationPairs",
    "ViewTables",
    "build_view_tables",
    "coordinate_statistics",
    "dataset_fingerprint",
    "gather_pairs",
    "load_split_arrays",
    "make_views",
    "validation_pairs",
]
