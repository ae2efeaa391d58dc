"""Training of the matching network and export of a matching bundle (reference-spec §3.4–3.5).

``litege train matching --config FILE``:

1. load the dataset's train and val splits, the trained T-Net and the matching-frame basis
   (fitted on aligned clean training views when its file is absent);
2. build the view tables (:mod:`litege_core.train.matching_data`);
3. **first passes**: ``first_passes`` short runs from different initializations at a
   constant learning rate; the one with the lowest validation *matching* error is kept
   (selection on the validation split, never on the test split — spec §3.5 🐞);
4. continue it with a cosine schedule from ``lr`` to ``eta_min`` (a fresh scheduler, not one
   restored from a 1-epoch run — spec §3.5 🐞), keeping the best validation checkpoint;
5. export ``RUN/bundle`` with :func:`~litege_core.matching.bundle.save_matching_bundle`.

With ``train.init`` (a shipped matching model or a bundle directory) the run continues that
bundle instead: its T-Net, pipeline and basis are kept (the network's inputs do not move), its
first network replaces the first passes, and step 4 trains it on the new data (the start is
kept if no validation beats it). The continued bundle keeps the initial bundle's frame judge
(its ``judge-K`` networks, else its matching networks): the judged frames stay the ones that
were validated, whatever the new network scores.

Validation matching error: for fixed pairs of clean validation views of different shapes,
every shared source vertex of X is matched on Y by the coarse-to-fine search and the error is
the unit-area geodesic on Y from the true vertex (the same source) to the match — read from
the dataset's own distance rows, so no extra ground truth is needed. Mean ×100, as reported.
"""

from __future__ import annotations

import copy
import logging
import math
import platform
import time
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any, ClassVar, cast

import numpy as np
import torch

import litege_core
from litege_core.canonical import calibrate_poisson_target
from litege_core.datasets import GeodesicDataset
from litege_core.descriptor import UdfPcaBasis, VoxelGrid, fit_basis
from litege_core.errors import InputError
from litege_core.matching.bundle import (
    MatchingBundle,
    SearchSettings,
    load_matching_bundle,
    resolve_matching_bundle,
    save_matching_bundle,
)
from litege_core.matching.cache import NNCache
from litege_core.matching.frame import MatchingPipeline, align_shapes
from litege_core.matching.model import ensemble_score_fn
from litege_core.matching.search import coarse_to_fine_search
from litege_core.metrics import auc
from litege_core.nets import FoldedGeodesicNet, GeodesicNet, TNet
from litege_core.nets.geodesic import OutputKind
from litege_core.shape import Shape
from litege_core.train.config import AugmentConfig, ConfigRoot
from litege_core.train.data import dataset_fingerprint, datasets_fingerprint, load_split_arrays
from litege_core.train.matching_data import (
    REJECT_ANGLE,
    MatchingBatch,
    MatchingTables,
    ValidationSet,
    build_matching_tables,
    concatenate_tables,
    misalignment,
    sample_batch,
    stored_frame_offset,
    validation_set,
)
from litege_core.train.trainer import seed_everything
from litege_core.variants import random_rotation

LOG = logging.getLogger("litege.train")


# --------------------------------------------------------------------------- configuration


FRAME_REFERENCES = ("stored", "consensus")
"""Values of ``data.frame`` (:class:`MatchingDataConfig`)."""


@dataclass(frozen=True)
class MatchingDataConfig:
    dataset: str = "data/quadruped-small"
    tnet: str = "out/tnet-quadrupeds/tnet.safetensors"
    views_per_shape: int = 4
    val_view_pairs: int = 24
    max_train_shapes: int = 0
    max_val_shapes: int = 0
    reject_angle: float = REJECT_ANGLE
    frame: str = "stored"
    """What the T-Net filter measures a view's misalignment from: ``"stored"``, the frame the
    dataset's shapes are stored in (procedural and posed-template datasets are built in the
    canonical frame); ``"consensus"``, the frame the T-Net agrees on for the training shapes
    (:func:`~litege_core.train.matching_data.stored_frame_offset`: a user's collection, stored
    in its own convention; the ``species`` datasets take the same offset)."""
    species: str = ""
    """A directory of per-species matching datasets (``litege data build --category rigged
    --preset matching``; ``""``: none). Their training views join ``dataset``'s, each pair drawn
    within one species (their triangulations differ); validation stays on ``dataset``."""


@dataclass(frozen=True)
class MatchingBasisConfig:
    path: str = "data/basis-quadruped-matching.safetensors"
    n_components: int = 240
    std_threshold: float = 0.16
    grid_resolution: int = 121
    grid_pitch: float = 0.02
    fit_samples: int = 2000


@dataclass(frozen=True)
class MatchingNetworkConfig:
    width: int = 400
    output: str = "abs"


@dataclass(frozen=True)
class MatchingOptimConfig:
    view_pairs: int = 16
    rows_per_pair: int = 12
    targets_per_pair: int = 16
    first_passes: int = 3
    first_pass_steps: int = 300
    steps: int = 3000
    validate_every: int = 500
    lr: float = 1e-2
    eta_min: float = 1e-4
    seed: int = 0
    threads: int = 1
    device: str = "cpu"
    init: str = ""
    """A matching bundle (shipped name or directory) to continue from: its T-Net, pipeline,
    basis and first network replace ``data.tnet``, the calibrated pipeline, ``[basis]`` and the
    first passes; ``network.width`` must be its network's (``""``: train from scratch)."""


@dataclass(frozen=True)
class MatchingOutputConfig:
    dir: str = "out/train/matching-quadrupeds"
    name: str = "quadrupeds"
    category: str = "quadruped"
    weights_dtype: str = "float16"


@dataclass(frozen=True)
class MatchingTrainConfig(ConfigRoot):
    """A matching training run (TOML tables ``data``, ``augment``, ``basis``, ``network``,
    ``train``, ``output``; see ``configs/matching-quadrupeds.toml``)."""

    WHAT: ClassVar[str] = "a matching training config"

    data: MatchingDataConfig = field(default_factory=MatchingDataConfig)
    augment: AugmentConfig = field(default_factory=AugmentConfig)
    basis: MatchingBasisConfig = field(default_factory=MatchingBasisConfig)
    network: MatchingNetworkConfig = field(default_factory=MatchingNetworkConfig)
    train: MatchingOptimConfig = field(default_factory=MatchingOptimConfig)
    output: MatchingOutputConfig = field(default_factory=MatchingOutputConfig)

    def check(self) -> None:
        t = self.train
        positive = {
            "train.view_pairs": t.view_pairs,
            "train.rows_per_pair": t.rows_per_pair,
            "train.targets_per_pair": t.targets_per_pair,
            "train.first_passes": t.first_passes,
            "train.validate_every": t.validate_every,
            "data.views_per_shape": self.data.views_per_shape,
            "data.val_view_pairs": self.data.val_view_pairs,
            "network.width": self.network.width,
        }
        for name, value in positive.items():
            if not isinstance(value, int) or value < 1:
                raise InputError(f"{name} must be a positive integer, got {value!r}")
        if t.first_pass_steps < 0 or t.steps < 0:
            raise InputError("train.first_pass_steps and train.steps must be ≥ 0")
        if not 0 < t.eta_min <= t.lr:
            raise InputError("need 0 < train.eta_min ≤ train.lr")
        if self.data.frame not in FRAME_REFERENCES:
            raise InputError(
                f"data.frame must be one of {list(FRAME_REFERENCES)}, got {self.data.frame!r}"
            )


def load_matching_config(path: str | Path) -> MatchingTrainConfig:
    """Read a TOML matching training config (``configs/matching-*.toml``)."""
    return MatchingTrainConfig.load(path)


# --------------------------------------------------------------------------- preparation


def aligned_training_meshes(
    arrays: dict[str, np.ndarray],
    faces: np.ndarray,
    tnet: TNet,
    pipeline: MatchingPipeline,
    seed: int,
):
    """Yield ``(aligned vertices, faces)`` of each shape, randomly rotated then T-Net aligned
    (the frame the basis is fitted in)."""
    for s in range(arrays["vertices"].shape[0]):
        rotation = random_rotation(np.random.default_rng([seed, int(arrays["seed"][s]), 99]))
        shape = Shape.from_arrays(np.asarray(arrays["vertices"][s], np.float64) @ rotation.T, faces)
        ((transform, _, _),) = align_shapes([shape], tnet, pipeline, seed=seed)
        yield transform.apply(shape.vertices), faces


def prepare_matching_basis(
    config: MatchingTrainConfig, arrays, faces, tnet: TNet, pipeline: MatchingPipeline
) -> UdfPcaBasis:
    path = Path(config.basis.path)
    if path.exists():
        LOG.info("basis: %s", path)
        return UdfPcaBasis.load(path)
    LOG.info("basis: fitting on %d aligned training shapes", arrays["vertices"].shape[0])
    b = config.basis
    basis = fit_basis(
        aligned_training_meshes(arrays, faces, tnet, pipeline, config.train.seed),
        grid=VoxelGrid(resolution=b.grid_resolution, pitch=b.grid_pitch),
        std_threshold=b.std_threshold,
        n_components=b.n_components,
        n_udf_samples=b.fit_samples,
        seed=config.train.seed,
        metadata={"pipeline": "matching", "frame": "tnet-unit-area"},
    )
    path.parent.mkdir(parents=True, exist_ok=True)
    basis.save(path)
    return basis


def calibrated_pipeline(arrays, faces, n_meshes: int = 16) -> MatchingPipeline:
    """Poisson-spacing targets (spec §1.4) recomputed with our sampler on training meshes."""
    meshes = [(arrays["vertices"][s], faces) for s in range(min(n_meshes, len(arrays["vertices"])))]
    return MatchingPipeline(
        cloud_8k_target=calibrate_poisson_target(meshes, 8000, 500),
        cloud_500_target=calibrate_poisson_target(meshes, 500, 50),
        broken_target=calibrate_poisson_target(meshes, 56_000, 7000),
    )


def species_datasets(directory: str | Path) -> list[Path]:
    """The dataset directories (with a ``manifest.json``) directly under ``directory``, sorted.

    Raises:
        InputError: ``directory`` is missing or holds no dataset.
    """
    root = Path(directory)
    found = sorted(p.parent for p in root.glob("*/manifest.json")) if root.is_dir() else []
    if not found:
        raise InputError(
            f"data.species {str(directory)!r} holds no dataset: build it with "
            "`litege data build --category rigged --preset matching --out DIR`"
        )
    return found


def species_tables(
    config: MatchingTrainConfig, common: dict[str, Any]
) -> list[tuple[Path, MatchingTables, int]]:
    """``(directory, training tables, shapes)`` of every dataset of ``data.species`` (none when
    unset), each built like the main training set with its own faces and shared sources."""
    if not config.data.species:
        return []
    parts = []
    for k, directory in enumerate(species_datasets(config.data.species)):
        dataset = GeodesicDataset(directory)
        assert dataset.shared_sources is not None, "a species dataset has shared sources"
        arrays = load_split_arrays(dataset, "train", 0)
        part = build_matching_tables(
            arrays,
            np.asarray(dataset.faces),
            int(dataset.shared_sources.size),
            n_views=config.data.views_per_shape,
            seed=config.train.seed + 104729 * (k + 1),
            **common,
        )
        LOG.info("species %s: %d train views", directory.name, part.n_views)
        parts.append((directory, part, int(arrays["vertices"].shape[0])))
    return parts


# --------------------------------------------------------------------------- evaluation


@torch.no_grad()
def validation_metrics(
    net: GeodesicNet,
    tables: MatchingTables,
    val: ValidationSet,
    caches: dict[int, NNCache],
    target_scale: float,
) -> dict[str, float]:
    """Matching error (×100, unit area) over the validation pairs, and the (masked) L1."""
    net.eval()
    batch = val.batch
    pred = net(batch.src, batch.dst, batch.desc_src, batch.desc_dst)
    err = (pred - batch.target).abs()
    local = (pred < 0.17) | (batch.target < 0.17)
    folded = FoldedGeodesicNet(net, tables.vertices.device)
    shape_emb = net.shape_embedding(tables.descriptors)
    bias = folded.shape_bias(shape_emb)
    errors = []
    for a, b in val.pairs.tolist():
        sa, sb = int(tables.shape[a]), int(tables.shape[b])
        rows = tables.sources[sa]
        fx = folded.features(folded.embed(tables.vertices[a][rows], bias[a]))
        fy = folded.features(folded.embed(tables.vertices[b], bias[b]))
        score = ensemble_score_fn([folded], [fx], [fy])
        found, _ = coarse_to_fine_search(caches[b], score, rows.shape[0], beams=1)
        errors.append(tables.distances[sb, torch.arange(rows.shape[0]), found])
    matching = torch.cat(errors)
    return {
        "match_error_x100": float(matching.mean()) * 100.0,
        "match_auc": auc(matching.cpu().numpy(), 0.2),
        "l1": float(err.mean()) / target_scale,
        "masked_l1": float(err[local].mean()) / target_scale if local.any() else math.nan,
    }


# --------------------------------------------------------------------------- training


@dataclass
class PassResult:
    network: GeodesicNet
    metrics: dict[str, float]
    history: list[dict[str, float]]


def _new_network(config: MatchingTrainConfig, basis: UdfPcaBasis, tables: MatchingTables, seed):
    torch.manual_seed(seed)
    output = cast(OutputKind, config.network.output)  # GeodesicNet checks the value
    net = GeodesicNet(config.network.width, basis.n_components, output)
    flat = tables.vertices.reshape(-1, 3)
    net.set_coord_normalization(flat.mean(0).cpu().numpy(), flat.std(0).cpu().numpy())
    return net.to(tables.vertices.device)


def train_pass(
    net: GeodesicNet,
    tables: MatchingTables,
    validation: tuple[MatchingTables, ValidationSet, dict[int, NNCache]],
    config: MatchingTrainConfig,
    *,
    steps: int,
    schedule: bool,
    seed: int,
    target_scale: float,
) -> PassResult:
    """``steps`` Adam steps (cosine to ``eta_min`` when ``schedule``, else constant ``lr``),
    validating every ``validate_every`` steps and at the end; returns the best network."""
    t = config.train
    optimizer = torch.optim.Adam(net.parameters(), lr=t.lr)
    scheduler = (
        torch.optim.lr_scheduler.CosineAnnealingLR(optimizer, max(steps, 1), t.eta_min)
        if schedule
        else None
    )
    generator = torch.Generator(device=tables.shape.device).manual_seed(seed)
    val_tables, val_set, caches = validation
    best: PassResult | None = None
    history = []
    running, since = 0.0, 0
    start = time.perf_counter()
    for step in range(1, steps + 1):
        net.train()
        batch: MatchingBatch = sample_batch(
            tables, t.view_pairs, t.rows_per_pair, t.targets_per_pair, target_scale, generator
        )
        pred = net(batch.src, batch.dst, batch.desc_src, batch.desc_dst)
        loss = (pred - batch.target).abs().mean()
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        optimizer.step()
        if scheduler is not None:
            scheduler.step()
        running += float(loss.detach())
        since += 1
        if step % t.validate_every == 0 or step == steps:
            metrics = validation_metrics(net, val_tables, val_set, caches, target_scale)
            metrics.update(
                step=step,
                train_l1=running / since / target_scale,
                steps_per_s=step / (time.perf_counter() - start),
            )
            running, since = 0.0, 0
            history.append(metrics)
            LOG.info(
                "step %d: val match error %.2f AUC %.1f masked L1 %.4f (%.1f steps/s)",
                step,
                metrics["match_error_x100"],
                metrics["match_auc"],
                metrics["masked_l1"],
                metrics["steps_per_s"],
            )
            if best is None or metrics["match_error_x100"] < best.metrics["match_error_x100"]:
                best = PassResult(copy.deepcopy(net).eval(), metrics, history)
    if best is None:  # steps == 0
        metrics = validation_metrics(net, val_tables, val_set, caches, target_scale)
        best = PassResult(copy.deepcopy(net).eval(), metrics, history)
    best.history = history
    return best


def _initial_bundle(config: MatchingTrainConfig, device: torch.device) -> MatchingBundle | None:
    """The bundle ``train.init`` names, on ``device`` (``None`` without one).

    Raises:
        InputError: an unknown bundle, or a network width other than ``network.width``.
    """
    if not config.train.init:
        return None
    bundle = load_matching_bundle(resolve_matching_bundle(config.train.init), device)
    width = bundle.networks[0].config().get("width")
    if width != config.network.width:
        raise InputError(
            f"train.init {config.train.init!r} has networks of width {width}, the config asks "
            f"for {config.network.width}: set network.width to match it"
        )
    return bundle


def train_matching(config: MatchingTrainConfig) -> dict[str, Any]:
    """Run the whole training (see the module docstring); returns the bundle manifest."""
    from litege_core.train.tnet import load_tnet

    t = config.train
    torch.set_num_threads(t.threads)
    seed_everything(t.seed)
    device = torch.device(t.device)
    seconds: dict[str, float] = {}
    clock = time.perf_counter()
    dataset = GeodesicDataset(config.data.dataset)
    assert dataset.shared_sources is not None, "a matching dataset has shared sources"
    n_shared = int(dataset.shared_sources.size)
    train_arrays = load_split_arrays(dataset, "train", config.data.max_train_shapes)
    val_arrays = load_split_arrays(dataset, "val", config.data.max_val_shapes)
    faces = np.asarray(dataset.faces)
    init = _initial_bundle(config, device)
    if init is not None:  # continue a bundle: its frame, scale and descriptor stay
        tnet, pipeline = init.tnet, init.pipeline
    else:
        tnet = load_tnet(config.data.tnet, device)
        pipeline = calibrated_pipeline(train_arrays, faces)
    seconds["load_and_calibrate"] = time.perf_counter() - clock
    LOG.info("pipeline: %s", pipeline)

    clock = time.perf_counter()
    if init is not None:
        basis = init.basis
    else:
        basis = prepare_matching_basis(config, train_arrays, faces, tnet, pipeline)
    seconds["basis"] = time.perf_counter() - clock

    clock = time.perf_counter()
    frame_offset = None
    frame_record: dict[str, Any] = {"reference": config.data.frame}
    if config.data.frame == "consensus":
        frame_offset, share = stored_frame_offset(train_arrays, faces, tnet, pipeline, seed=t.seed)
        LOG.info(
            "frame: the T-Net's canonical frame lies %.2f rad from the stored one "
            "(%.0f %% of the training shapes agree)",
            misalignment(frame_offset, np.eye(3)),
            100 * share,
        )
        frame_record.update(
            offset=frame_offset.round(6).tolist(),
            offset_angle=misalignment(frame_offset, np.eye(3)),
            agreeing_share=share,
        )
    common: dict[str, Any] = dict(
        basis=basis,
        tnet=tnet,
        pipeline=pipeline,
        augment=config.augment,
        reject_angle=config.data.reject_angle,
        device=device,
        frame_offset=frame_offset,
    )
    tables = build_matching_tables(
        train_arrays, faces, n_shared, n_views=config.data.views_per_shape, seed=t.seed, **common
    )
    val_tables = build_matching_tables(
        val_arrays, faces, n_shared, n_views=1, seed=t.seed + 7919, **common
    )
    n_train_shapes = train_arrays["vertices"].shape[0]
    species = species_tables(config, common)
    if species:
        tables = concatenate_tables([tables, *(part for _, part, _ in species)])
        n_train_shapes += sum(n for _, _, n in species)
    n_train_views = n_train_shapes * config.data.views_per_shape
    rejected = n_train_views - tables.n_views
    val_set = validation_set(
        val_tables,
        config.data.val_view_pairs,
        t.rows_per_pair,
        t.targets_per_pair,
        pipeline.target_scale,
        seed=t.seed + 7919,
    )
    search = SearchSettings()
    caches = {
        int(b): NNCache.build(
            val_tables.vertices[int(b)].double().cpu().numpy(),
            tier_sizes=search.tier_sizes,
            neighbours=search.neighbours,
        )
        for b in val_set.pairs[:, 1].unique().tolist()
    }
    validation = (val_tables, val_set, caches)
    seconds["tables"] = time.perf_counter() - clock
    LOG.info(
        "tables: %d train views (%d rejected by the T-Net filter, angle > %.2f rad), "
        "%d val views; mean T-Net angle %.3f rad",
        tables.n_views,
        rejected,
        config.data.reject_angle,
        val_tables.n_views,
        float(tables.angle.mean()),
    )

    clock = time.perf_counter()
    passes = []
    if init is not None:  # the bundle's network is the only "first pass"
        start = copy.deepcopy(init.networks[0]).to(device)
        metrics = validation_metrics(start, val_tables, val_set, caches, pipeline.target_scale)
        LOG.info("start (%s): val match error %.2f", t.init, metrics["match_error_x100"])
        passes.append(PassResult(start, metrics, []))
    for k in range(0 if init is not None else t.first_passes):
        net = _new_network(config, basis, tables, t.seed + 1000 * k)
        result = train_pass(
            net,
            tables,
            validation,
            config,
            steps=t.first_pass_steps,
            schedule=False,
            seed=t.seed + 1000 * k,
            target_scale=pipeline.target_scale,
        )
        LOG.info("first pass %d: val match error %.2f", k, result.metrics["match_error_x100"])
        passes.append(result)
    chosen = min(range(len(passes)), key=lambda k: passes[k].metrics["match_error_x100"])
    seconds["first_passes"] = time.perf_counter() - clock

    clock = time.perf_counter()
    final = train_pass(
        copy.deepcopy(passes[chosen].network),
        tables,
        validation,
        config,
        steps=t.steps,
        schedule=True,
        seed=t.seed + 17,
        target_scale=pipeline.target_scale,
    )
    if passes[chosen].metrics["match_error_x100"] < final.metrics["match_error_x100"]:
        final = PassResult(passes[chosen].network, passes[chosen].metrics, final.history)
    seconds["main"] = time.perf_counter() - clock

    out = Path(config.output.dir)
    training = {
        "config": {f.name: asdict(getattr(config, f.name)) for f in fields(config)},
        "dataset": (
            datasets_fingerprint([config.data.dataset, *(path for path, _, _ in species)])
            if species
            else dataset_fingerprint(config.data.dataset)
        ),
        "species": {p.name: {"views": part.n_views, "shapes": n} for p, part, n in species},
        "tnet": str(config.data.tnet) if init is None else f"{t.init} (init)",
        "init": None if init is None else {"bundle": t.init, "content_hash": init.content_hash},
        "judge": "matching networks" if init is None else f"{t.init} (init)'s frame judge",
        "train_views": tables.n_views,
        "rejected_views": rejected,
        "frame": frame_record,
        "mean_tnet_angle_train": float(tables.angle.mean()),
        "first_passes": [p.metrics for p in passes],
        "chosen_first_pass": chosen,
        "history": final.history,
        "seconds": seconds,
        "machine": platform.processor() or platform.machine(),
        "torch": torch.__version__,
        "litege": litege_core.__version__,
    }
    if init is not None and "tnet_swap" in init.manifest.get("training", {}):
        training["tnet_swap"] = init.manifest["training"]["tnet_swap"]  # the kept T-Net's origin
    metrics = {f"val_{k}": v for k, v in final.metrics.items() if isinstance(v, float)}
    dtype = getattr(torch, config.output.weights_dtype)
    return save_matching_bundle(
        out / "bundle",
        name=config.output.name,
        category=config.output.category,
        basis=basis,
        tnet=tnet.cpu(),
        networks=[final.network.cpu()],
        pipeline=pipeline,
        search=search,
        training=training,
        metrics=metrics,
        weights_dtype=dtype,
        # a continued bundle keeps the frame judge its frames were validated with
        judge_networks=() if init is None else [n.cpu() for n in init.frame_judge_networks],
        orientation=None if init is None or init.orientation is None else init.orientation.cpu(),
    )


__all__ = [
    "MatchingBasisConfig",
    "MatchingDataConfig",
    "MatchingNetworkConfig",
    "MatchingOptimConfig",
    "MatchingOutputConfig",
    "MatchingTrainConfig",
    "PassResult",
    "aligned_training_meshes",
    "calibrated_pipeline",
    "load_matching_config",
    "prepare_matching_basis",
    "species_datasets",
    "species_tables",
    "train_matching",
    "train_pass",
    "validation_metrics",
]
