"""The T-Net training configuration (``configs/tnet-*.toml``): data, augmentation, network,
optimization, report and output sections."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import ClassVar

from litege_core.datasets.spec import COLLECTION_SOURCES
from litege_core.nets.tnet import POINT_LOSS_WEIGHT, PREALIGN_MODES
from litege_core.train.config import ConfigRoot, _check

FAILURE_THRESHOLD = 0.66
"""Angular error (rad) above which a training shape is rejected (spec §1.6)."""


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
            :func:`~litege_core.train.tnet.weights.save_tnet`, or a matching bundle (a
            shipped name such as ``"quadrupeds"``, or a bundle directory) whose T-Net is
            taken; its widths and pre-alignment must be ``[network]``'s (``""``: random
            initialization).
        time_budget_minutes: when positive, the run is re-planned after its first
            :data:`~litege_core.train.tnet.training.PLAN_AFTER_STEPS` steps to the step
            count that fits this many minutes of training at the measured rate (at most
            ``steps``; the cosine schedule spans the planned count, which the summary
            records); the final report comes on top.
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


__all__ = [
    "FAILURE_THRESHOLD",
    "TNetAugmentConfig",
    "TNetDataConfig",
    "TNetNetworkConfig",
    "TNetOptimConfig",
    "TNetOutputConfig",
    "TNetReportConfig",
    "TNetTrainConfig",
    "load_tnet_config",
]
