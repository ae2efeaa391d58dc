"""Training of the T-Net (shape orientation for matching, reference-spec §1.6) on procedural shapes.

``litege train tnet --config configs/tnet-quadrupeds.toml [--out DIR]`` runs
:func:`run_tnet_training`:

1. **Shapes.** Shape ``k`` of a split is ``generate_shape(category, families[k % n], offset + k)``
   with the offsets of :data:`~litege_core.datasets.spec.SPLIT_SEED_OFFSETS` (train 0…,
   val 1,000,000…), generated once and kept in memory. Each is brought into the canonical frame:
   the template orientation, centred on the mean of 8000 area-weighted samples and scaled to unit
   area (:func:`~litege_core.canonical.canonicalize_unit_area` with the identity rotation).
   With ``data.extra_category`` the posed meshes of a collection source (MakeHuman bodies,
   rigged animals: the shapes of ``litege data build --category SOURCE``, same seeds) follow
   in both splits, canonical in the same way (:func:`training_shape_sets`). With
   ``data.steep_share`` that share of the procedural shapes rears, leaps, sits up or lies
   on the belly instead (:func:`~litege_core.synth.poses.steep_pose`), still in the ground
   frame of the template.
2. **Batches.** Every step draws ``batch_size`` shapes, one point count ``n`` per batch
   (log-uniform in ``[min_points, max_points]``: 500-point clouds up to the 2000 points
   :func:`predict_rotation` feeds) and, per item, ``n`` fresh area-weighted samples. Items are
   augmented so one network serves every input kind: with ``broken_probability`` a fraction of
   the faces is removed before sampling (broken meshes), with ``noise_probability`` Gaussian noise
   is added (σ uniform up to ``noise_sigma``, unit-area units), each cloud is re-centred on its own
   mean and rescaled by a log-uniform factor in ``[scale_min, scale_max]`` (the Poisson-spacing
   scale of point clouds and broken meshes is not exactly the unit-area scale: with the paper's
   constants and our sampler a 40 %-broken mesh comes out about 1.33× larger). A uniform rotation
   ``R_gt`` (``scipy Rotation.random``) per item gives ``pc_rot = pc_canon @ R_gtᵀ``; the loss is
   :func:`~litege_core.nets.tnet_loss` (angle + λ·point, λ = 2). Step ``t`` draws everything from
   ``default_rng([seed, 1, t])``, so a run is a pure function of its config.
3. **Network.** :class:`~litege_core.nets.TNet` with the ``[network]`` widths and pre-alignment:
   ``prealign = "pca"`` makes the network regress only the residual rotation of the PCA-aligned
   cloud (same :meth:`~litege_core.nets.TNet.rotation` contract), which is what makes a CPU
   budget of about a thousand steps enough; ``"none"`` is the reference T-Net.
4. **Optimization.** Adam, learning rate cosine from ``lr`` to ``eta_min`` over all steps; every
   ``val_every`` steps the mean angle on a FIXED validation set (each val shape as a 2000-sample
   mesh, a 500-point cloud and a 40 %-broken mesh, fixed rotations and samples) is measured; the
   best weights by that mean are kept and written to ``RUN/tnet.safetensors``.
5. **Report** (``RUN/report.json``) with the best weights: the alignment-error distribution on
   the training shapes (one random rotation each, ``default_rng(20)`` as the reference's
   ``np.random.seed(20)``; the indices above 0.66 rad are the rejection filter of spec §1.6),
   on the val shapes as meshes, as 500-point clouds and as broken meshes, the last two scaled as
   at inference (:func:`~litege_core.canonical.canonicalize_poisson` with the §1.4 settings).

The weights file holds the :func:`~litege_core.nets.state_to_tensors` tensors and, in its
safetensors metadata, ``format = "litege-tnet"``, the network ``config`` and a ``training``
summary; :func:`load_tnet` reads it back, :func:`predict_rotation` applies it to one cloud.
"""

from __future__ import annotations

import json
import logging
import math
import os
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar, NamedTuple

import numpy as np
import torch
from numpy.typing import ArrayLike, NDArray
from safetensors import SafetensorError, safe_open
from safetensors.torch import save_file
from scipy.spatial.transform import Rotation

from litege_core.canonical import (
    POISSON_500_CLOUD,
    POISSON_BROKEN_MESH,
    PoissonScaleSetting,
    canonicalize_poisson,
    canonicalize_unit_area,
)
from litege_core.datasets.spec import COLLECTION_SOURCES, SPLIT_SEED_OFFSETS
from litege_core.errors import ArtifactError, InputError
from litege_core.nets import TNet, load_state, rotation_angle, state_to_tensors, tnet_loss
from litege_core.nets.tnet import CUBE_ROTATIONS, POINT_LOSS_WEIGHT, PREALIGN_MODES, pca_frames
from litege_core.sampling import as_points, poisson_disk_subsample, sample_surface
from litege_core.train.config import ConfigRoot, _check, run_log
from litege_core.variants import broken_mesh

LOG = logging.getLogger("litege.train.tnet")

TNET_FORMAT = "litege-tnet"
"""``format`` entry of the safetensors metadata of a T-Net weights file."""

PREDICT_MAX_POINTS = 2000
""":func:`predict_rotation` feeds at most this many points (the authors' training count)."""

FAILURE_THRESHOLD = 0.66
"""Angular error (rad) above which a training shape is rejected (spec §1.6)."""

PLAN_AFTER_STEPS = 100
"""With ``train.time_budget_minutes``, the steps timed before the run is re-planned."""

_VAL_MODES = ("mesh", "cloud500", "broken")


# --------------------------------------------------------------------------- configuration


@dataclass(frozen=True)
class TNetDataConfig:
    """Which procedural shapes: ``n_train`` train-split and ``n_val`` val-split shapes."""

    category: str = "quadruped"
    n_train: int = 300
    n_val: int = 40
    cache_dir: str = ""
    """When set, the canonical shapes of a split are stored there (``.npz``, keyed by category,
    split, count and generator version) and reused by later runs (generation ≈ 0.5 s/shape)."""
    workers: int = 1
    """Processes generating the shapes (the same shapes for any count)."""
    extra_category: str = ""
    """A collection source of ``litege data`` (``"makehuman"``, ``"rigged"``) whose posed meshes
    are mixed into both splits: ``n_extra_train`` / ``n_extra_val`` of them. Its meshes must
    share the template orientation (MakeHuman bodies and procedural bipeds: +y up, facing +z)."""
    n_extra_train: int = 0
    n_extra_val: int = 0
    extra_bend: float = 0.0
    """Share of the ``rigged`` extra shapes bent along the body (curled, head turned back,
    arched: :mod:`litege_core.synth.bend`; the body's centre keeps its heading, so the
    template's frame stays the true one)."""
    steep_share: float = 0.0
    """Share of the procedural shapes posed in a steep mode (rearing, leaping, sitting up or
    lying on the belly, :data:`~litege_core.synth.poses.QUADRUPED_STEEP_MODES`), as real
    animals do; the others keep the pose their seed draws
    (:func:`~litege_core.synth.poses.steep_pose`)."""
    train_data: str = ""
    """Root of the collection assets (``""``: ``$LITEGE_TRAIN_DATA``, else
    ``../shared/train-data``)."""

    def __post_init__(self) -> None:
        _check(bool(self.category), "data.category is required")
        _check(self.n_train >= 1 and self.n_val >= 1, "data.n_train and data.n_val must be ≥ 1")
        _check(self.workers >= 1, "data.workers must be ≥ 1")
        _check(
            self.n_extra_train >= 0 and self.n_extra_val >= 0,
            "data.n_extra_train and data.n_extra_val must be ≥ 0",
        )
        _check(
            bool(self.extra_category) or self.n_extra_train + self.n_extra_val == 0,
            "data.n_extra_train / n_extra_val need data.extra_category",
        )
        _check(
            self.extra_category in ("", *COLLECTION_SOURCES),
            f"data.extra_category must be one of {COLLECTION_SOURCES}",
        )
        _check(0.0 <= self.extra_bend <= 1.0, "data.extra_bend must be in [0, 1]")
        _check(
            self.extra_bend == 0.0 or self.extra_category == "rigged",
            'data.extra_bend needs data.extra_category = "rigged"',
        )
        from litege_core.synth.poses import check_steep_share

        check_steep_share(self.category, self.steep_share)


@dataclass(frozen=True)
class TNetAugmentConfig:
    """Per-batch point counts and per-item corruptions (see the module docstring)."""

    min_points: int = 500
    max_points: int = 2000
    broken_probability: float = 0.25
    broken_min: float = 0.3
    broken_max: float = 0.5
    noise_probability: float = 0.3
    noise_sigma: float = 0.01
    scale_min: float = 0.85
    scale_max: float = 1.4
    frame_turns: bool = False
    """Pre-aligned networks: turn each item's PCA frame by a random one of the 24
    :data:`~litege_core.nets.tnet.CUBE_ROTATIONS` (every PCA axis order / sign equally often)."""
    axis_scale: float = 0.0
    """Per-item stretch of each canonical axis by a log-uniform factor in ``[1/(1+a), 1+a]``
    (before rotation): more body shapes than the generated ones (0: off)."""

    def __post_init__(self) -> None:
        _check(8 <= self.min_points <= self.max_points, "need 8 ≤ min_points ≤ max_points")
        for name in ("broken_probability", "noise_probability"):
            _check(0.0 <= getattr(self, name) <= 1.0, f"augment.{name} must lie in [0, 1]")
        _check(0.0 <= self.broken_min <= self.broken_max < 0.95, "need 0 ≤ broken_min ≤ max < 0.95")
        _check(self.noise_sigma >= 0.0, "augment.noise_sigma must be ≥ 0")
        _check(0.0 < self.scale_min <= self.scale_max, "need 0 < scale_min ≤ scale_max")
        _check(0.0 <= self.axis_scale < 1.0, "augment.axis_scale must lie in [0, 1)")


@dataclass(frozen=True)
class TNetNetworkConfig:
    """:class:`~litege_core.nets.TNet` widths (reference: (128, 512, 2048), (512, 128)) and
    pre-alignment (``"none"``: the reference; ``"pca"``: residual in the principal-axis frame)."""

    conv_widths: tuple[int, ...] = (64, 128, 256)
    fc_widths: tuple[int, ...] = (256, 128)
    prealign: str = "none"

    def __post_init__(self) -> None:
        _check(self.prealign in PREALIGN_MODES, f"network.prealign ∈ {list(PREALIGN_MODES)}")
        _check(len(self.conv_widths) >= 1, "network.conv_widths needs at least one layer")
        for name in ("conv_widths", "fc_widths"):
            _check(all(w >= 1 for w in getattr(self, name)), f"network.{name} must be positive")


@dataclass(frozen=True)
class TNetOptimConfig:
    """Batches, Adam + cosine schedule, validation cadence, seed and device.

    Attributes:
        batch_size: clouds per step (≥ 2: BatchNorm in the FC head).
        steps: optimizer steps of the whole run.
        lr, eta_min: cosine schedule from ``lr`` to ``eta_min`` over ``steps``.
        point_weight: λ of the point term of the loss (2 in the reference).
        val_every: validate (and maybe checkpoint) every this many steps, and at the end.
        val_points: samples of the validation meshes and broken meshes.
        log_every: a training log line every this many steps.
        seed: network initialization, batches, validation set.
        device: ``"auto"``, ``"cpu"``, ``"cuda"``…; threads: torch CPU threads (0: default).
        loader_workers: processes sampling the batches ahead of the optimizer (0: the training
            process samples them itself); the batches are the same either way.
        init: a T-Net to start from instead of random weights: a weights file of
            :func:`save_tnet`, or a matching bundle (a shipped name such as ``"quadrupeds"``, or
            a bundle directory) whose T-Net is taken; its widths and pre-alignment must be
            ``[network]``'s (``""``: random initialization).
        time_budget_minutes: when positive, the run is re-planned after its first
            :data:`PLAN_AFTER_STEPS` steps to the step count that fits this many minutes of
            training at the measured rate (at most ``steps``; the cosine schedule spans the
            planned count, which the summary records); the final report comes on top.
    """

    batch_size: int = 32
    steps: int = 2000
    lr: float = 1e-3
    eta_min: float = 1e-5
    point_weight: float = POINT_LOSS_WEIGHT
    val_every: int = 100
    val_points: int = 2000
    log_every: int = 25
    seed: int = 0
    device: str = "cpu"
    threads: int = 1
    loader_workers: int = 0
    init: str = ""
    time_budget_minutes: float = 0.0

    def __post_init__(self) -> None:
        _check(self.batch_size >= 2, "train.batch_size must be ≥ 2 (BatchNorm in the FC head)")
        _check(self.loader_workers >= 0, "train.loader_workers must be ≥ 0")
        _check(self.time_budget_minutes >= 0.0, "train.time_budget_minutes must be ≥ 0")
        _check(self.steps >= 1, "train.steps must be ≥ 1")
        _check(0.0 < self.eta_min <= self.lr, "need 0 < eta_min ≤ lr")
        _check(self.point_weight >= 0.0, "train.point_weight must be ≥ 0")
        _check(self.val_every >= 1 and self.log_every >= 1, "val_every and log_every ≥ 1")
        _check(self.val_points >= 8, "train.val_points must be ≥ 8")
        _check(self.threads >= 0, "train.threads must be ≥ 0")


@dataclass(frozen=True)
class TNetReportConfig:
    """The final alignment-error report (see the module docstring)."""

    rotation_seed: int = 20
    samples: int = 2000
    broken_fraction: float = 0.4
    failure_threshold: float = FAILURE_THRESHOLD

    def __post_init__(self) -> None:
        _check(self.samples >= 8, "report.samples must be ≥ 8")
        _check(0.0 <= self.broken_fraction < 0.95, "report.broken_fraction must lie in [0, 0.95)")
        _check(self.failure_threshold > 0.0, "report.failure_threshold must be positive")


@dataclass(frozen=True)
class TNetOutputConfig:
    """``dir`` receives ``tnet.safetensors``, ``report.json`` and ``train.log``."""

    dir: str = "out/tnet"

    def __post_init__(self) -> None:
        _check(bool(self.dir), "output.dir is required")


@dataclass(frozen=True)
class TNetTrainConfig(ConfigRoot):
    """The whole T-Net training configuration (TOML tables of the same names)."""

    WHAT: ClassVar[str] = "a T-Net training config"

    data: TNetDataConfig = field(default_factory=TNetDataConfig)
    augment: TNetAugmentConfig = field(default_factory=TNetAugmentConfig)
    network: TNetNetworkConfig = field(default_factory=TNetNetworkConfig)
    train: TNetOptimConfig = field(default_factory=TNetOptimConfig)
    report: TNetReportConfig = field(default_factory=TNetReportConfig)
    output: TNetOutputConfig = field(default_factory=TNetOutputConfig)


def load_tnet_config(path: str | Path) -> TNetTrainConfig:
    """Read a TOML T-Net training config (``configs/tnet-*.toml``)."""
    return TNetTrainConfig.load(path)


# --------------------------------------------------------------------------- shapes


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


# --------------------------------------------------------------------------- batches


class TNetBatch(NamedTuple):
    """``canonical (B, N, 3)``, ``rotated = canonical @ R_gtᵀ``, ``R_gt (B, 3, 3)`` and, for
    pre-aligned networks, ``frame_turns (B, 3, 3)`` (identity unless ``augment.frame_turns``)."""

    canonical: torch.Tensor
    rotated: torch.Tensor
    R_gt: torch.Tensor
    frame_turns: torch.Tensor | None = None


def _item_cloud(
    vertices: NDArray,
    faces: NDArray,
    n_points: int,
    augment: TNetAugmentConfig,
    rng: np.random.Generator,
) -> NDArray:
    """One augmented, centred, rescaled cloud in the canonical orientation."""
    if rng.random() < augment.broken_probability:
        fraction = rng.uniform(augment.broken_min, augment.broken_max)
        faces = faces[broken_mesh(faces, fraction, rng)]
    points = sample_surface(vertices, faces, n_points, rng).points
    if rng.random() < augment.noise_probability:
        points = points + rng.normal(0.0, rng.uniform(0.0, augment.noise_sigma), points.shape)
    points = points - points.mean(axis=0)
    scale = math.exp(rng.uniform(math.log(augment.scale_min), math.log(augment.scale_max)))
    if augment.axis_scale > 0.0:
        bound = math.log1p(augment.axis_scale)
        return points * (scale * np.exp(rng.uniform(-bound, bound, 3)))
    return points * scale


class _BatchArrays(NamedTuple):
    """A batch as float32 numpy arrays (what a loader process sends back) and the indices of
    its :data:`~litege_core.nets.tnet.CUBE_ROTATIONS` frame turns (``None``: no turns)."""

    canonical: NDArray
    rotated: NDArray
    R_gt: NDArray
    turn_indices: NDArray | None = None

    def tensors(self) -> TNetBatch:
        turns = None if self.turn_indices is None else CUBE_ROTATIONS[self.turn_indices].float()
        return TNetBatch(
            torch.from_numpy(self.canonical),
            torch.from_numpy(self.rotated),
            torch.from_numpy(self.R_gt),
            turns,
        )


def _batch_arrays(canonical: NDArray, rotations: NDArray) -> _BatchArrays:
    rotated = np.einsum("bnj,bij->bni", canonical, rotations)
    return _BatchArrays(*(np.asarray(a, dtype=np.float32) for a in (canonical, rotated, rotations)))


def _make_batch(canonical: NDArray, rotations: NDArray) -> TNetBatch:
    return _batch_arrays(canonical, rotations).tensors()


def _sample_batch_arrays(
    shapes: ShapeSet, config: TNetTrainConfig, step: int, batch_size: int | None = None
) -> _BatchArrays:
    augment = config.augment
    rng = np.random.default_rng([config.train.seed, 1, step])
    batch = config.train.batch_size if batch_size is None else batch_size
    low, high = math.log(augment.min_points), math.log(augment.max_points)
    n_points = round(math.exp(rng.uniform(low, high)))
    n_points = min(max(n_points, augment.min_points), augment.max_points)
    index = rng.integers(len(shapes), size=batch)
    rotations = Rotation.random(batch, random_state=rng).as_matrix()
    clouds = np.stack(
        [_item_cloud(shapes.vertices[i], shapes.faces[i], n_points, augment, rng) for i in index]
    )
    arrays = _batch_arrays(clouds, rotations)
    if augment.frame_turns:
        arrays = arrays._replace(turn_indices=rng.integers(len(CUBE_ROTATIONS), size=batch))
    return arrays


def sample_batch(
    shapes: ShapeSet, config: TNetTrainConfig, step: int, batch_size: int | None = None
) -> TNetBatch:
    """The training batch of (0-based) ``step``; a pure function of ``(seed, step)``."""
    return _sample_batch_arrays(shapes, config, step, batch_size).tensors()


_LOADER_INPUTS: tuple[ShapeSet, TNetTrainConfig] | None = None
"""What a loader process samples from (set in each one by :func:`_set_loader_inputs`)."""


def _set_loader_inputs(shapes: ShapeSet, config: TNetTrainConfig) -> None:
    """Pool initializer of :class:`BatchLoader` (forked: the inputs are inherited, not pickled)."""
    global _LOADER_INPUTS
    _LOADER_INPUTS = (shapes, config)


def _loader_batch(step: int) -> _BatchArrays:
    assert _LOADER_INPUTS is not None, "loader process started without its inputs"
    shapes, config = _LOADER_INPUTS
    return _sample_batch_arrays(shapes, config, step)


class BatchLoader:
    """The training batches of steps ``0, 1, 2, …`` in order, sampled ``workers`` processes
    ahead of the optimizer (at most ``2 × workers`` batches in flight), or in this process when
    ``workers`` is 0. Either way batch ``t`` is :func:`sample_batch` of step ``t``.

    Use as a context manager; the processes are forked on entry (before any CUDA work of the
    caller is safest: they only run numpy) and stopped on exit.
    """

    def __init__(self, shapes: ShapeSet, config: TNetTrainConfig, workers: int) -> None:
        self.shapes, self.config, self.workers = shapes, config, workers
        self._pool: Any = None
        self._pending: deque[Any] = deque()
        self._next_submit = 0

    def __enter__(self) -> BatchLoader:
        if self.workers > 0:
            import multiprocessing

            self._pool = multiprocessing.get_context("fork").Pool(
                self.workers, _set_loader_inputs, (self.shapes, self.config)
            )
            for _ in range(2 * self.workers):
                self._submit()
        return self

    def __exit__(self, *exc: object) -> None:
        if self._pool is not None:
            self._pool.terminate()
            self._pool.join()
            self._pool = None

    def _submit(self) -> None:
        self._pending.append(self._pool.apply_async(_loader_batch, (self._next_submit,)))
        self._next_submit += 1

    def batch(self, step: int) -> TNetBatch:
        """The batch of ``step`` (steps must be asked for in order, from 0)."""
        if self._pool is None:
            return sample_batch(self.shapes, self.config, step)
        expected = self._next_submit - len(self._pending)
        if step != expected:
            raise InputError(f"BatchLoader serves steps in order: asked {step}, next {expected}")
        arrays = self._pending.popleft().get()
        self._submit()
        return arrays.tensors()


class ValidationSet(NamedTuple):
    """Fixed validation batches, one per input kind (``mesh``, ``cloud500``, ``broken``)."""

    batches: dict[str, TNetBatch]

    @property
    def n_items(self) -> int:
        return sum(b.R_gt.shape[0] for b in self.batches.values())


def validation_set(shapes: ShapeSet, config: TNetTrainConfig) -> ValidationSet:
    """Each val shape as a ``val_points``-sample mesh, a 500-point cloud and a 40 %-broken
    mesh, each with its own fixed rotation; seeded by ``train.seed`` only."""
    n_points = config.train.val_points
    batches = {}
    for mode_index, mode in enumerate(_VAL_MODES):
        rng = np.random.default_rng([config.train.seed, 2, mode_index])
        clouds = []
        for verts, tris in zip(shapes.vertices, shapes.faces, strict=True):
            count = n_points
            if mode == "broken":
                tris = tris[broken_mesh(tris, 0.4, rng)]
            elif mode == "cloud500":
                count = 500
            points = sample_surface(verts, tris, count, rng).points
            clouds.append(points - points.mean(axis=0))
        rotations = Rotation.random(len(shapes), random_state=rng).as_matrix()
        batches[mode] = _make_batch(np.stack(clouds), rotations)
    return ValidationSet(batches)


# --------------------------------------------------------------------------- evaluation


def _device_of(net: torch.nn.Module) -> torch.device:
    return next(net.parameters()).device


@torch.no_grad()
def batch_angles(net: TNet, rotated: torch.Tensor, R_gt: torch.Tensor, chunk: int = 64) -> NDArray:
    """Angles (rad, float64 numpy) between the eval-mode prediction and ``R_gt``."""
    was_training = net.training
    net.eval()
    device = _device_of(net)
    try:
        out = []
        for start in range(0, rotated.shape[0], chunk):
            R_pred = net.rotation(rotated[start : start + chunk].to(device))
            gt = R_gt[start : start + chunk].to(device, R_pred.dtype)
            out.append(rotation_angle(R_pred.double(), gt.double(), eps=0.0).cpu().numpy())
    finally:
        net.train(was_training)
    return np.concatenate(out)


def validate(net: TNet, val: ValidationSet) -> dict[str, float]:
    """Mean angle per input kind and over all items (``mean``)."""
    angles = {mode: batch_angles(net, b.rotated, b.R_gt) for mode, b in val.batches.items()}
    result = {mode: float(a.mean()) for mode, a in angles.items()}
    result["mean"] = float(np.concatenate(list(angles.values())).mean())
    return result


def angle_statistics(angles: ArrayLike, threshold: float = FAILURE_THRESHOLD) -> dict[str, Any]:
    """``n``, mean / std / median / p90 / p95 / max (rad) and the indices above ``threshold``."""
    values = np.asarray(angles, dtype=np.float64)
    failures = np.flatnonzero(values > threshold)
    return {
        "n": int(values.size),
        "mean": float(values.mean()),
        "std": float(values.std()),
        "median": float(np.median(values)),
        "p90": float(np.quantile(values, 0.9)),
        "p95": float(np.quantile(values, 0.95)),
        "max": float(values.max()),
        "threshold": float(threshold),
        "n_failures": int(failures.size),
        "failures": [int(i) for i in failures],
        "failure_angles": [float(values[i]) for i in failures],
    }


def _poisson_cloud(points: NDArray, setting: PoissonScaleSetting, seed: int) -> NDArray:
    """Centre and Poisson-scale a cloud as at inference (the subset itself when
    ``subset_is_cloud``: its own spacing, all of its points)."""
    n_poisson = points.shape[0] if setting.subset_is_cloud else setting.n_poisson
    transform = canonicalize_poisson(points, n_poisson, setting.target_mean_nn, seed)
    return transform.apply(points)


def _report_angles(
    net: TNet, shapes: ShapeSet, report: TNetReportConfig, salt: int, mode: str
) -> NDArray:
    """Angles of one input kind for every shape, with the reference rotations.

    The rotation of shape ``i`` is the ``i``-th of ``Rotation.random(len, default_rng(seed))``;
    ``mesh``: ``report.samples`` area-weighted samples of the unit-area mesh; ``cloud500``:
    500 samples of the rotated mesh scaled by Poisson spacing (§1.4, K=50); ``broken``:
    ``broken_fraction`` of the faces removed, ``n_cloud`` samples of the rest, their Poisson
    subset of about 7000 points is the cloud (§1.4), :func:`predict_rotation` keeps 2000.
    """
    rotations = Rotation.random(
        len(shapes), random_state=np.random.default_rng(report.rotation_seed)
    ).as_matrix()
    angles = np.empty(len(shapes))
    for i, (verts, tris) in enumerate(zip(shapes.vertices, shapes.faces, strict=True)):
        rng = np.random.default_rng([report.rotation_seed, salt, i])
        R_gt = rotations[i]
        rotated_verts = verts @ R_gt.T
        if mode == "mesh":
            cloud = sample_surface(rotated_verts, tris, report.samples, rng).points
        elif mode == "cloud500":
            cloud = sample_surface(rotated_verts, tris, POISSON_500_CLOUD.n_cloud, rng).points
            cloud = _poisson_cloud(cloud, POISSON_500_CLOUD, int(rng.integers(2**31)))
        else:
            kept = tris[broken_mesh(tris, report.broken_fraction, rng)]
            dense = sample_surface(rotated_verts, kept, POISSON_BROKEN_MESH.n_cloud, rng).points
            subset = dense[poisson_disk_subsample(dense, POISSON_BROKEN_MESH.n_poisson, rng)]
            cloud = _poisson_cloud(subset, POISSON_BROKEN_MESH, 0)
        R_pred = predict_rotation(net, cloud)
        angles[i] = float(
            rotation_angle(torch.as_tensor(R_pred), torch.as_tensor(R_gt), eps=0.0).item()
        )
    return angles


def alignment_report(
    net: TNet, train_shapes: ShapeSet, val_shapes: ShapeSet, report: TNetReportConfig
) -> dict[str, Any]:
    """The alignment-error distributions of the module docstring (step 5)."""
    result: dict[str, Any] = {
        "units": "rad",
        "rotation_seed": report.rotation_seed,
        "samples": report.samples,
        "broken_fraction": report.broken_fraction,
    }
    threshold = report.failure_threshold
    train = angle_statistics(_report_angles(net, train_shapes, report, 0, "mesh"), threshold)
    train["failed_keys"] = [list(train_shapes.keys[i]) for i in train["failures"]]
    result["train"] = train
    for name, mode, salt in (
        ("val", "mesh", 1),
        ("val_cloud500", "cloud500", 2),
        ("val_broken", "broken", 3),
    ):
        result[name] = angle_statistics(
            _report_angles(net, val_shapes, report, salt, mode), threshold
        )
    result["failed_train_indices"] = train["failures"]
    return result


# --------------------------------------------------------------------------- weights


def save_tnet(net: TNet, path: str | Path, training: dict[str, Any] | None = None) -> None:
    """Weights (:func:`state_to_tensors`) + config in the metadata, written atomically."""
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    temporary = target.with_name(f"{target.name}.tmp-{os.getpid()}")
    metadata = {
        "format": TNET_FORMAT,
        "config": json.dumps(net.config(), sort_keys=True),
        "training": json.dumps(training or {}, sort_keys=True),
    }
    try:
        save_file(state_to_tensors(net), str(temporary), metadata=metadata)
        os.replace(temporary, target)
    finally:
        if temporary.exists():
            temporary.unlink()


def read_tnet_metadata(path: str | Path) -> dict[str, Any]:
    """``{"config": …, "training": …}`` of a weights file written by :func:`save_tnet`."""
    return _read(path)[1]


def _read(path: str | Path) -> tuple[dict[str, torch.Tensor], dict[str, Any]]:
    try:
        with safe_open(str(path), framework="pt") as handle:
            metadata = handle.metadata() or {}
            tensors = {name: handle.get_tensor(name) for name in handle.keys()}  # noqa: SIM118
    except (OSError, SafetensorError, ValueError) as exc:
        raise ArtifactError(f"cannot read T-Net weights {path}: {exc}") from exc
    if metadata.get("format") != TNET_FORMAT or "config" not in metadata:
        raise ArtifactError(f"{path} is not a LiteGE T-Net weights file")
    try:
        info = {
            "config": json.loads(metadata["config"]),
            "training": json.loads(metadata.get("training", "{}")),
        }
    except ValueError as exc:
        raise ArtifactError(f"{path}: T-Net metadata is not valid JSON: {exc}") from exc
    return tensors, info


def start_from(net: TNet, init: str | Path) -> None:
    """Load into ``net`` the weights of ``init`` (see :class:`TNetOptimConfig`'s ``init``).

    Raises:
        InputError: ``init`` names no weights file or matching bundle, or its T-Net's widths or
            pre-alignment differ from ``net``'s.
        ArtifactError: a damaged weights file or bundle.
    """
    from litege_core.matching.bundle import load_matching_bundle, resolve_matching_bundle

    path = Path(init)
    if path.is_file():
        source = load_tnet(path)
    else:
        source = load_matching_bundle(resolve_matching_bundle(str(init))).tnet
    if source.config() != net.config():
        raise InputError(
            f"train.init {str(init)!r} is a T-Net {source.config()}, the config asks for "
            f"{net.config()}: set [network] to match it"
        )
    load_state(net, state_to_tensors(source))
    LOG.info("started from the T-Net of %s", init)


def load_tnet(path: str | Path, device: str | torch.device = "cpu") -> TNet:
    """The T-Net of a weights file, on ``device``, in eval mode (ArtifactError if damaged)."""
    tensors, info = _read(path)
    try:
        net = TNet.from_config(info["config"])
    except InputError as exc:
        raise ArtifactError(f"{path}: bad T-Net config: {exc}") from exc
    load_state(net, tensors)
    return net.to(device).eval()


@torch.no_grad()
def predict_rotation(net: TNet, points: ArrayLike) -> NDArray:
    """``R_pred`` ``(3, 3)`` float64 for one cloud; align it with ``points @ R_pred``.

    ``points`` ``(N, 3)`` must be scale-normalized (unit-area mesh samples or a Poisson-scaled
    cloud, spec §1.3–§1.4). Clouds of more than :data:`PREDICT_MAX_POINTS` points are subsampled
    deterministically (``default_rng(0)``, without replacement); the subset is centred on its
    own mean (as in training: a translation does not change the rotation). Runs in eval mode.
    """
    cloud = as_points(points)
    if cloud.shape[0] > PREDICT_MAX_POINTS:
        keep = np.random.default_rng(0).choice(cloud.shape[0], PREDICT_MAX_POINTS, replace=False)
        cloud = cloud[np.sort(keep)]
    cloud = cloud - cloud.mean(axis=0)
    reference = next(net.parameters())
    was_training = net.training
    net.eval()
    try:
        tensor = torch.as_tensor(cloud, dtype=reference.dtype, device=reference.device)
        R_pred = net.rotation(tensor[None])[0]
    finally:
        net.train(was_training)
    return R_pred.double().cpu().numpy()


# --------------------------------------------------------------------------- training


def cosine_lr(step: int, config: TNetOptimConfig, total: int | None = None) -> float:
    """``η_min + (η_0 − η_min)(1 + cos(π·step/total))/2`` (``total``: ``steps`` by default)."""
    fraction = min(max(step / (total or config.steps), 0.0), 1.0)
    return config.eta_min + (config.lr - config.eta_min) * 0.5 * (1 + math.cos(math.pi * fraction))


def train_step(
    net: TNet, optimizer: torch.optim.Optimizer, batch: TNetBatch, point_weight: float
) -> dict[str, float]:
    """One Adam step on ``batch`` (network in training mode); the loss terms as floats."""
    device = _device_of(net)
    canonical, rotated, R_gt = (t.to(device) for t in batch[:3])
    frames = None
    if batch.frame_turns is not None and net.prealign != "none":
        frames = pca_frames(rotated) @ batch.frame_turns.to(device, rotated.dtype)
    loss = tnet_loss(net.rotation(rotated, frames), R_gt, canonical, rotated, point_weight)
    optimizer.zero_grad(set_to_none=True)
    loss.total.backward()
    optimizer.step()
    return {
        name: float(value.detach())
        for name, value in zip(("loss", "angle", "point"), loss, strict=True)
    }


@dataclass
class TNetRunResult:
    """A finished run: the best network (eval mode) and what was measured."""

    net: TNet
    best_val: dict[str, float]
    best_step: int
    history: list[dict[str, Any]]
    seconds: float
    steps_per_second: float
    steps: int = 0
    """Optimizer steps run (``train.steps``, or the count a time budget planned)."""
    report: dict[str, Any] | None = None


def _resolve_device(name: str) -> torch.device:
    from litege_core.device import resolve_device

    return resolve_device(name)


def train_tnet(
    config: TNetTrainConfig,
    *,
    train_shapes: ShapeSet | None = None,
    val_shapes: ShapeSet | None = None,
    weights_path: str | Path | None = None,
    make_report: bool = True,
) -> TNetRunResult:
    """Train per ``config``; shapes are generated when not given (tests pass small ones).

    The best weights by validation mean angle are written to ``weights_path`` (when given)
    each time they improve; the returned network holds them, in eval mode.
    """
    opt = config.train
    if opt.threads > 0:
        torch.set_num_threads(opt.threads)
    device = _resolve_device(opt.device)
    started = time.perf_counter()
    if train_shapes is None or val_shapes is None:
        generated_train, generated_val = training_shape_sets(config.data)
        train_shapes = generated_train if train_shapes is None else train_shapes
        val_shapes = generated_val if val_shapes is None else val_shapes
    val = validation_set(val_shapes, config)
    with BatchLoader(train_shapes, config, opt.loader_workers) as loader:
        result = _optimize(config, loader, val, device, weights_path)
    result.seconds = time.perf_counter() - started
    if make_report:
        mark = time.perf_counter()
        result.report = alignment_report(result.net, train_shapes, val_shapes, config.report)
        LOG.info("alignment report in %.1f s", time.perf_counter() - mark)
    return result


def _planned_steps(config: TNetOptimConfig, done: int, elapsed: float) -> int:
    """The step count that fits ``time_budget_minutes`` at the rate of the first ``done`` steps
    (``elapsed`` wall seconds, validation included), at least ``done`` and at most ``steps``."""
    budget = config.time_budget_minutes * 60.0
    fitting = done + int((budget - elapsed) * done / max(elapsed, 1e-9))
    return min(config.steps, max(done, fitting))


def _optimize(
    config: TNetTrainConfig,
    loader: BatchLoader,
    val: ValidationSet,
    device: torch.device,
    weights_path: str | Path | None,
) -> TNetRunResult:
    """The optimization loop of :func:`train_tnet`; the network comes back with the best
    validation weights, in eval mode (also written to ``weights_path`` at each improvement).
    ``seconds`` of the result counts the optimizer steps only."""
    opt = config.train
    torch.manual_seed(opt.seed)
    network = config.network
    net = TNet(network.conv_widths, network.fc_widths, network.prealign)
    if opt.init:
        start_from(net, opt.init)
    net = net.to(device)
    optimizer = torch.optim.Adam(net.parameters(), lr=opt.lr)
    n_params = sum(p.numel() for p in net.parameters())
    LOG.info(
        "T-Net %s (%d parameters) on %s, %d steps × %d clouds of %d..%d points, %d loader "
        "processes%s",
        net.config(), n_params, device, opt.steps, opt.batch_size, config.augment.min_points,
        config.augment.max_points, opt.loader_workers,
        f", budget {opt.time_budget_minutes:g} min" if opt.time_budget_minutes else "",
    )  # fmt: skip

    best_val: dict[str, float] = {"mean": math.inf}
    best_state: dict[str, torch.Tensor] = state_to_tensors(net)
    best_step = 0
    history: list[dict[str, Any]] = []
    window: list[dict[str, float]] = []
    train_seconds = 0.0
    total = opt.steps
    started = time.perf_counter()
    step = 0
    while step < total:
        tick = time.perf_counter()
        for group in optimizer.param_groups:
            group["lr"] = cosine_lr(step, opt, total)
        net.train()
        batch = loader.batch(step)
        window.append(train_step(net, optimizer, batch, opt.point_weight))
        train_seconds += time.perf_counter() - tick
        step = done = step + 1
        if opt.time_budget_minutes > 0:
            elapsed = time.perf_counter() - started
            if done == min(PLAN_AFTER_STEPS, total):
                total = _planned_steps(opt, done, elapsed)
                LOG.info("time budget %g min: %d steps planned", opt.time_budget_minutes, total)
            elif elapsed > opt.time_budget_minutes * 60.0:
                LOG.info("time budget spent at step %d of %d planned", done, total)
                total = done
        if done % opt.log_every == 0 or done == total:
            means = {k: float(np.mean([w[k] for w in window])) for k in window[0]}
            LOG.info(
                "step %d/%d lr %.2e loss %.4f angle %.4f point %.4f (N=%d, %.2f steps/s)",
                done, total, optimizer.param_groups[0]["lr"], means["loss"], means["angle"],
                means["point"], batch.canonical.shape[1], done / train_seconds,
            )  # fmt: skip
            window = []
        if done % opt.val_every == 0 or done == total:
            scores = validate(net, val)
            improved = scores["mean"] < best_val["mean"]
            history.append({"step": done, "val": scores, "improved": improved})
            if improved:
                best_val, best_step = scores, done
                best_state = state_to_tensors(net)
                if weights_path is not None:
                    save_tnet(net, weights_path, _training_summary(config, best_step, best_val))
            LOG.info(
                "val step %d: mean %.4f (mesh %.4f, cloud500 %.4f, broken %.4f)%s",
                done, scores["mean"], scores["mesh"], scores["cloud500"], scores["broken"],
                " *best*" if improved else "",
            )  # fmt: skip
    load_state(net, best_state)
    net.eval()
    return TNetRunResult(
        net=net,
        best_val=best_val,
        best_step=best_step,
        history=history,
        seconds=train_seconds,
        steps_per_second=total / train_seconds if train_seconds > 0 else 0.0,
        steps=total,
    )


def _training_summary(config: TNetTrainConfig, best_step: int, best_val: dict) -> dict[str, Any]:
    return {
        "best_step": best_step,
        "best_val": best_val,
        "config": config.to_dict(),
        "config_hash": config.content_hash(),
    }


def run_tnet_training(
    config: TNetTrainConfig,
    out: str | Path | None = None,
    *,
    train_shapes: ShapeSet | None = None,
    val_shapes: ShapeSet | None = None,
) -> dict[str, Any]:
    """A whole run into ``RUN`` (``out`` or ``output.dir``): ``tnet.safetensors``,
    ``report.json``, ``train.log``. Returns the report. Shapes are generated per ``[data]``
    unless given."""
    if out is not None:
        config = config.replace(output={"dir": str(out)})
    run_dir = config.run_dir
    run_dir.mkdir(parents=True, exist_ok=True)
    with run_log(LOG, run_dir):
        LOG.info("config %s", json.dumps(config.to_dict(), sort_keys=True))
        weights = run_dir / "tnet.safetensors"
        result = train_tnet(
            config, train_shapes=train_shapes, val_shapes=val_shapes, weights_path=weights
        )
        summary = _training_summary(config, result.best_step, result.best_val)
        summary.update(
            seconds=round(result.seconds, 1),
            steps_per_second=round(result.steps_per_second, 3),
            steps_run=result.steps,
            threads=torch.get_num_threads(),
        )
        save_tnet(result.net, weights, summary)
        report = {
            "weights": str(weights),
            "network": result.net.config(),
            "training": summary,
            "history": result.history,
            "alignment": result.report,
        }
        (run_dir / "report.json").write_text(json.dumps(report, indent=2) + "\n")
        alignment = result.report or {}
        for name in ("train", "val", "val_cloud500", "val_broken"):
            stats = alignment.get(name, {})
            LOG.info(
                "%s: mean %.4f std %.4f median %.4f max %.4f failures>%.2f %d/%d",
                name, stats["mean"], stats["std"], stats["median"], stats["max"],
                stats["threshold"], stats["n_failures"], stats["n"],
            )  # fmt: skip
        return report


__all__ = [
    "FAILURE_THRESHOLD",
    "PREDICT_MAX_POINTS",
    "TNET_FORMAT",
    "BatchLoader",
    "ShapeSet",
    "TNetAugmentConfig",
    "TNetBatch",
    "TNetDataConfig",
    "TNetNetworkConfig",
    "TNetOptimConfig",
    "TNetOutputConfig",
    "TNetReportConfig",
    "TNetRunResult",
    "TNetTrainConfig",
    "ValidationSet",
    "alignment_report",
    "angle_statistics",
    "batch_angles",
    "canonical_shape_set",
    "cosine_lr",
    "generate_shape_set",
    "load_tnet",
    "load_tnet_config",
    "predict_rotation",
    "read_tnet_metadata",
    "run_tnet_training",
    "sample_batch",
    "save_tnet",
    "start_from",
    "train_step",
    "train_tnet",
    "validate",
    "validation_set",
]
