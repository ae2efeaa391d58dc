"""Training and validation tables, built once before training, and vectorized pair batches.

**Views.** Every shape of a split gets ``K`` views (:mod:`litege_core.train.augment`). For each
view the transform ``T = canonicalize_bbox(view points)`` is computed (turned by the view's
frame jitter, :attr:`~litege_core.train.augment.View.frame`, when it has one), the descriptor is the
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
    vertex_counts (Ns,) int64      vertices of each shape (None: all V, template datasets)

**Collection datasets** (shapes with their own triangulations, see
:mod:`litege_core.datasets.storage`) are padded to the split's largest vertex count ``V``:
``vertices`` and ``distances`` hold zeros beyond ``vertex_counts[shape]``, targets are drawn only
among a shape's own vertices, and the coordinate statistics skip the padding. Template
datasets keep ``vertex_counts = None`` and draw exactly the batches they always did.
:func:`load_training_arrays` merges several dataset directories (of either kind) into one
split.

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
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import torch
from numpy.typing import NDArray

from litege_core.canonical import Transform, canonicalize_bbox
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
    vertex_counts: torch.Tensor | None = None

    @property
    def n_views(self) -> int:
        return int(self.descriptors.shape[0])

    @property
    def is_padded(self) -> bool:
        """Whether shapes have their own vertex counts (collection datasets)."""
        return self.vertex_counts is not None

    @property
    def n_shapes(self) -> int:
        return int(self.distances.shape[0])

    @property
    def n_rows(self) -> int:
        """``R``, source rows per shape."""
        return int(self.distances.shape[1])

    @property
    def n_vertices(self) -> int:
        """``V``, the vertex axis length (the largest shape's count for a collection)."""
        return int(self.vertices.shape[1])

    @property
    def device(self) -> torch.device:
        return self.descriptors.device

    def to(self, device: torch.device | str) -> ViewTables:
        """The same tables on ``device``."""
        moved: dict[str, Any] = {}  # each field's tensor (or None) on `device`
        for f in fields(self):
            value = getattr(self, f.name)
            moved[f.name] = None if value is None else value.to(device)
        return ViewTables(**moved)

    def view_vertex_counts(self) -> torch.Tensor:
        """``(Nv,)`` int64 vertices of each view's shape (on the tables' device)."""
        if self.vertex_counts is None:
            return torch.full((self.n_views,), self.n_vertices, device=self.device)
        return self.vertex_counts[self.shape]


def dataset_fingerprint(directory: str | Path) -> dict[str, object]:
    """SHA-256 of the dataset's manifest file, its split counts and its ground-truth solver
    (for provenance and the model card)."""
    path = Path(directory) / MANIFEST
    dataset = GeodesicDataset(directory)
    return {
        "path": str(directory),
        "name": dataset.spec.name,
        "category": dataset.spec.category,
        "kind": dataset.kind,
        "manifest_sha256": hashlib.sha256(path.read_bytes()).hexdigest(),
        "counts": dict(dataset.manifest["counts"]),
        "solver": dataset.manifest.get("solver"),
    }


def datasets_fingerprint(directories: Sequence[str | Path]) -> dict[str, object]:
    """Provenance of several datasets trained on together: each one's fingerprint and a
    SHA-256 over their manifest hashes (in order)."""
    parts = [dataset_fingerprint(d) for d in directories]
    digest = hashlib.sha256("".join(str(p["manifest_sha256"]) for p in parts).encode())
    return {"datasets": parts, "manifest_sha256": digest.hexdigest()}


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


SEED_STRIDE = 10_000_000
"""Seeds of the ``k``-th merged dataset are offset by ``k · SEED_STRIDE`` (view streams of
different datasets never coincide)."""


def to_collection_arrays(arrays: dict[str, NDArray], faces: NDArray) -> dict[str, NDArray]:
    """A template split in the collection layout: ``faces (S, F, 3)`` int32 repeated,
    ``n_vertices`` / ``n_faces`` constant."""
    n_shapes, n_vertices = arrays["vertices"].shape[:2]
    out = dict(arrays)
    out["faces"] = np.broadcast_to(np.asarray(faces, np.int32), (n_shapes, *faces.shape)).copy()
    out["n_vertices"] = np.full(n_shapes, n_vertices, dtype=np.int64)
    out["n_faces"] = np.full(n_shapes, faces.shape[0], dtype=np.int64)
    return out


def load_training_arrays(
    directories: str | Path | Sequence[str | Path], split: str, max_shapes: int = 0
) -> tuple[dict[str, NDArray], NDArray | None]:
    """One split of one or several datasets as ``(arrays, faces)``.

    * one template dataset: its arrays and shared faces (exactly :func:`load_split_arrays`);
    * several template datasets with the same triangulation: concatenated, shared faces;
    * otherwise (any collection, or different triangulations): the collection layout
      (``faces`` / ``n_vertices`` / ``n_faces`` per shape, padded), ``faces`` ``None``.

    Datasets with different numbers of source rows keep the first ``min R`` rows (the
    shared / farthest-point sources come first). Seeds of dataset ``k`` are offset by
    ``k · SEED_STRIDE`` and family indices by the family counts of the datasets before it.
    ``max_shapes`` (0: all) applies to each dataset. A dataset without shapes in ``split``
    is skipped; none at all is an :class:`InputError`.
    """
    from litege_core.datasets.storage import concatenate_collection

    if isinstance(directories, str | Path):
        directories = [directories]
    if not directories:
        raise InputError("no dataset directory given")
    loaded: list[tuple[dict[str, NDArray], NDArray | None]] = []
    family_offset = 0
    for k, directory in enumerate(directories):
        dataset = GeodesicDataset(directory)
        n_families = len(dataset.spec.families)
        if not dataset.shard_names(split):
            family_offset += n_families
            continue
        arrays = load_split_arrays(dataset, split, max_shapes)
        if k:
            arrays["seed"] = arrays["seed"] + k * SEED_STRIDE
            arrays["family"] = arrays["family"] + family_offset
        family_offset += n_families
        loaded.append((arrays, dataset.faces))
    if not loaded:
        raise InputError(f"no dataset of {[str(d) for d in directories]} has a {split!r} split")
    if len(loaded) == 1:
        return loaded[0]
    n_rows = min(a["sources"].shape[1] for a, _ in loaded)
    trimmed = []
    for arrays, faces in loaded:
        arrays = dict(arrays)
        arrays["sources"] = arrays["sources"][:, :n_rows]
        arrays["distances"] = arrays["distances"][:, :n_rows]
        trimmed.append((arrays, faces))
    first_faces = trimmed[0][1]
    if first_faces is not None and all(
        f is not None and np.array_equal(f, first_faces) for _, f in trimmed
    ):
        keys = trimmed[0][0].keys()
        dtype = np.result_type(*(a["distances"].dtype for a, _ in trimmed))
        merged = {k: np.concatenate([a[k] for a, _ in trimmed]) for k in keys}
        merged["distances"] = np.concatenate([a["distances"].astype(dtype) for a, _ in trimmed])
        return merged, first_faces
    parts = [a if f is None else to_collection_arrays(a, f) for a, f in trimmed]
    dtype = np.result_type(*(a["distances"].dtype for a in parts))
    parts = [{**a, "distances": a["distances"].astype(dtype)} for a in parts]
    return concatenate_collection(parts), None


def shape_meshes(
    arrays: dict[str, NDArray], faces: NDArray | None = None
) -> Iterator[tuple[NDArray, NDArray]]:
    """Yield ``(vertices (V_s, 3) float64, faces (F_s, 3) int64)`` of every shape of a split,
    unpadded (collection layout) or on the shared ``faces`` (template layout)."""
    from litege_core.datasets.reader import shape_mesh

    for index in range(arrays["vertices"].shape[0]):
        yield shape_mesh(arrays, index, faces)


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
    faces: NDArray | None,
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
            sources ``(S, R)``, distances ``(S, R, V)``, area ``(S,)``, seed ``(S,)``; for a
            collection also faces ``(S, F, 3)``, n_vertices ``(S,)``, n_faces ``(S,)``).
        faces: ``(F, 3)`` shared triangulation (``None`` for a collection split).
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
    padded = "n_vertices" in arrays
    if not padded and faces is None:
        raise InputError("a template split needs the dataset's shared faces")
    raw_vertices = np.asarray(arrays["vertices"], dtype=np.float64)
    n_shapes, n_vertices = raw_vertices.shape[:2]
    if n_shapes == 0:
        raise InputError("cannot build training tables from an empty split")
    engine = basis.engine(device)
    n_total = n_shapes * n_views
    canonical = (np.zeros if padded else np.empty)((n_total, n_vertices, 3), dtype=np.float32)
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

    meshes = shape_meshes(arrays, faces)
    for s in range(n_shapes):
        shape_vertices, shape_faces = next(meshes)
        views = make_views(
            shape_vertices,
            shape_faces,
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
            if view.frame is not None:  # frame jitter: turn the canonical frame
                transform = Transform(
                    view.frame @ transform.rotation, transform.center, transform.scale
                )
            n_s = shape_vertices.shape[0]
            canonical[index, :n_s] = transform.apply(shape_vertices @ view.rotation.T)
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
        vertex_counts=(
            torch.from_numpy(np.asarray(arrays["n_vertices"], dtype=np.int64)).to(device)
            if padded
            else None
        ),
    )
    return tables


def _draw_targets(
    n_vertices: int,
    views: torch.Tensor,
    n_targets: int,
    generator: torch.Generator,
    view_counts: torch.Tensor | None,
) -> torch.Tensor:
    """``(B, T)`` int64 target vertices of ``views`` (CPU): uniform over all ``n_vertices``
    for template tables (the original ``randint`` stream), over each view's own shape's
    vertices otherwise (``view_counts``: ``(Nv,)`` CPU vertex counts per view)."""
    if view_counts is None:
        return torch.randint(n_vertices, (views.shape[0], n_targets), generator=generator)
    per_view = view_counts[views]  # (B,)
    uniform = torch.rand(views.shape[0], n_targets, generator=generator, dtype=torch.float64)
    targets = (uniform * per_view[:, None]).long()
    return torch.minimum(targets, per_view[:, None] - 1)


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
        self._view_counts = tables.view_vertex_counts().cpu() if tables.is_padded else None

    def draw(self) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """``(views (B,), rows (B, R_b), targets (B, T_b))`` int64 on the tables' device."""
        g, t = self.generator, self.tables
        b = self.batch_views
        if b <= t.n_views:
            views = torch.randperm(t.n_views, generator=g)[:b]
        else:
            views = torch.randint(t.n_views, (b,), generator=g)
        rows = torch.rand(b, t.n_rows, generator=g).argsort(dim=1)[:, : self.sources_per_view]
        targets = _draw_targets(t.n_vertices, views, self.targets_per_view, g, self._view_counts)
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
    counts = tables.view_vertex_counts().cpu() if tables.is_padded else None
    views = torch.arange(tables.n_views)
    targets = _draw_targets(tables.n_vertices, views, n_targets, generator, counts)
    device = tables.device
    return ValidationPairs(tables, rows[:, :n_sources].to(device), targets.to(device))


def coordinate_statistics(tables: ViewTables) -> tuple[NDArray, NDArray]:
    """Per-axis mean and population std ``(3,)`` float64 of all canonical training vertices
    of all views (the network's coordinate normalization, spec §3.3); padding excluded."""
    if tables.vertex_counts is None:
        points = tables.vertices.reshape(-1, 3).to(torch.float64)
    else:
        counts = tables.view_vertex_counts()
        mask = torch.arange(tables.n_vertices, device=tables.device)[None] < counts[:, None]
        points = tables.vertices[mask].to(torch.float64)
    return points.mean(dim=0).cpu().numpy(), points.std(dim=0, correction=0).cpu().numpy()


__all__ = [
    "PairBatch",
    "PairSampler",
    "ValidationPairs",
    "ViewTables",
    "build_view_tables",
    "coordinate_statistics",
    "dataset_fingerprint",
    "datasets_fingerprint",
    "gather_pairs",
    "load_split_arrays",
    "load_training_arrays",
    "make_views",
    "shape_meshes",
    "to_collection_arrays",
    "validation_pairs",
]
