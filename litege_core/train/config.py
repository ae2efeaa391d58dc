"""Training configuration of the geodesic network: a frozen dataclass read from TOML.

A config file has up to six tables, each optional except ``[data]`` (its ``dataset`` key)::

    [data]      dataset directory, views per shape, validation pairs
    [augment]   what users send: point counts, noise, missing regions, rotations
    [basis]     an existing UDF-PCA basis file, or the settings to fit one
    [network]   width and output kind of :class:`~litege_core.nets.GeodesicNet`
    [train]     batch layout, steps, epochs, Adam + cosine schedule, early stopping, seed, device
    [output]    run directory (checkpoints, log, basis, bundle), bundle name and category

Unknown tables or keys, values of the wrong type and values out of range raise
:class:`~litege_core.errors.InputError`. Relative paths are taken relative to the current
working directory (run from the repository root). ``configs/geodesic-*.toml`` are examples.

Every training config (this one, the T-Net's :class:`~litege_core.train.tnet.TNetTrainConfig`
and the matching network's :class:`~litege_core.train.matching.MatchingTrainConfig`) is a
:class:`ConfigRoot`: one strict TOML reader, ``from_dict`` / ``to_dict`` / ``replace`` /
``content_hash`` and the run directory ``output.dir``.

Units: ``augment.noise_sigma`` is in unit-area units (multiplied by ``√area`` of each shape);
learning rates are Adam step sizes; everything else is a count or a probability.
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import json
import logging
import math
import tomllib
import typing
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar, Self

from litege_core.errors import InputError

if TYPE_CHECKING:
    import torch

_OUTPUT_KINDS = ("abs", "softplus")
_SCHEDULES = ("step", "epoch")
_WEIGHT_DTYPES = ("float32", "float16")


def _check(condition: bool, message: str) -> None:
    if not condition:
        raise InputError(message)


@dataclass(frozen=True)
class DataConfig:
    """Which dataset and how the training / validation tables are built.

    Attributes:
        dataset: directory of a built geodesic dataset (``litege data build``).
        extra_datasets: more dataset directories trained on together with ``dataset``
            (template or collection datasets, merged by
            :func:`~litege_core.train.data.load_training_arrays`).
        views_per_shape: ``K`` views per training shape: view 0 is the clean mesh described
            from ``clean_samples`` area-weighted samples, views 1..K−1 are augmented.
        clean_samples: samples of the clean view (2000, as ``describe_shape`` uses for meshes).
        val_augmented_views: augmented views per validation shape (besides the clean one).
        val_sources: distinct source rows per validation view (fixed, seeded).
        val_targets: random target vertices per validation view; the validation pairs of a
            view are the ``val_sources × val_targets`` cross product.
        max_train_shapes: use only the first N training shapes (0: all), for quick runs.
        max_val_shapes: the same for the validation split.
        view_chunk: views described per call of the descriptor engine.
    """

    dataset: str = ""
    extra_datasets: tuple[str, ...] = ()
    views_per_shape: int = 4
    clean_samples: int = 2000
    val_augmented_views: int = 1
    val_sources: int = 16
    val_targets: int = 128
    max_train_shapes: int = 0
    max_val_shapes: int = 0
    view_chunk: int = 64

    @property
    def datasets(self) -> list[str]:
        """``dataset`` followed by ``extra_datasets``."""
        return [self.dataset, *self.extra_datasets]

    def __post_init__(self) -> None:
        _check(bool(self.dataset), "data.dataset (the dataset directory) is required")
        _check(all(self.extra_datasets), "data.extra_datasets must name directories")
        _check(self.views_per_shape >= 1, "data.views_per_shape must be at least 1")
        _check(self.clean_samples >= 4, "data.clean_samples must be at least 4")
        _check(self.val_augmented_views >= 0, "data.val_augmented_views must be ≥ 0")
        _check(self.val_sources >= 1 and self.val_targets >= 1, "need val_sources, targets ≥ 1")
        _check(self.max_train_shapes >= 0 and self.max_val_shapes >= 0, "max_*_shapes ≥ 0")
        _check(self.view_chunk >= 1, "data.view_chunk must be at least 1")


@dataclass(frozen=True)
class AugmentConfig:
    """Augmented views: what users send instead of clean 2000-sample meshes.

    Every augmented view is an area-weighted point cloud of ``n`` points, ``log n`` uniform
    in ``[log min_points, log max_points]``; with probability ``noise_probability`` Gaussian
    noise of ``noise_sigma`` (unit-area units) is added; with probability ``cut_probability``
    a fraction uniform in ``[cut_min, cut_max]`` is cut away by two parallel planes
    (:func:`~litege_core.variants.cut_by_planes`); with ``rotate`` the whole input (cloud and
    mesh) is rotated uniformly at random, which the canonicalization must absorb. All
    corruptions act on the cloud before canonicalization and before the UDF (spec §7.2).

    ``frame_jitter_degrees`` (geodesic training only; 0 = off, the paper) turns the canonical
    frame of each augmented view by a random rotation of at most that angle (uniform axis,
    angle uniform in ``[0, max]``) after canonicalization: the network learns to tolerate the
    frame errors that PCA makes on real shapes (issue 14, step 2). The descriptor and the
    canonical vertices see the same turned frame; distances are unchanged.

    ``axis_turn_probability`` (geodesic training only; 0 = off) turns the canonical frame of
    that share of the augmented views by a quarter, half or three-quarter turn (uniform)
    about the first principal axis, after any jitter: the frames PCA picks when a shape's
    second and third extents nearly tie (a human with the arms in front is as deep as it is
    wide), which swap those two axes (issue 14, step 2; BENCHMARKS "axis-turns").
    """

    min_points: int = 300
    max_points: int = 8000
    noise_probability: float = 0.4
    noise_sigma: float = 0.01
    cut_probability: float = 0.3
    cut_min: float = 0.10
    cut_max: float = 0.15
    rotate: bool = True
    frame_jitter_degrees: float = 0.0
    axis_turn_probability: float = 0.0

    def __post_init__(self) -> None:
        _check(4 <= self.min_points <= self.max_points, "need 4 ≤ min_points ≤ max_points")
        _check(
            0.0 <= self.frame_jitter_degrees <= 90.0,
            "augment.frame_jitter_degrees must lie in [0, 90]",
        )
        for name in ("noise_probability", "cut_probability", "axis_turn_probability"):
            _check(0.0 <= getattr(self, name) <= 1.0, f"augment.{name} must lie in [0, 1]")
        _check(self.noise_sigma >= 0.0, "augment.noise_sigma must be ≥ 0")
        _check(0.0 <= self.cut_min <= self.cut_max < 1.0, "need 0 ≤ cut_min ≤ cut_max < 1")


@dataclass(frozen=True)
class BasisConfig:
    """The UDF-PCA basis: an existing file, or how to fit one on the training split.

    Attributes:
        path: an existing basis (``.safetensors``); when empty or missing, a basis is fitted
            from the training meshes (canonicalized from ``fit_samples`` samples each) and
            saved as ``basis.safetensors`` in the run directory (reused on resume).
        n_components: descriptor size ``E`` (an existing basis is truncated to it).
        std_threshold: occupancy std threshold of the informative voxels (spec §2.3).
        grid_resolution: voxels per axis of the fit grid.
        grid_pitch: voxel edge, canonical units.
        fit_samples: surface samples per shape for canonicalization and the UDF.
        fit_shapes: fit on the first N training shapes only (0: all).
    """

    path: str = ""
    n_components: int = 240
    std_threshold: float = 0.16
    grid_resolution: int = 121
    grid_pitch: float = 0.02
    fit_samples: int = 2000
    fit_shapes: int = 0

    def __post_init__(self) -> None:
        _check(self.n_components >= 1, "basis.n_components must be at least 1")
        _check(0.0 < self.std_threshold < 0.5, "basis.std_threshold must lie in (0, 0.5)")
        _check(self.grid_resolution >= 2 and self.grid_pitch > 0, "bad basis grid")
        _check(self.fit_samples >= 4 and self.fit_shapes >= 0, "bad basis fit sizes")


@dataclass(frozen=True)
class NetworkConfig:
    """:class:`~litege_core.nets.GeodesicNet` hyper-parameters (``E`` = basis.n_components)."""

    width: int = 200
    output: str = "abs"

    def __post_init__(self) -> None:
        _check(self.width >= 1, "network.width must be at least 1")
        _check(self.output in _OUTPUT_KINDS, f"network.output must be one of {_OUTPUT_KINDS}")


@dataclass(frozen=True)
class OptimConfig:
    """Batches, optimization, schedule and early stopping (spec §3.5).

    A step draws ``batch_views`` views and, on each, ``sources_per_view`` distinct source
    rows × ``targets_per_view`` random target vertices: ``pairs_per_step`` pairs.

    Attributes:
        lr: initial Adam learning rate (1e-2 as the authors).
        eta_min: final learning rate of the cosine schedule (1e-4).
        schedule: ``"step"``: cosine over all ``epochs × steps_per_epoch`` steps (smooth);
            ``"epoch"``: cosine evaluated at the epoch index (the reference's per-epoch
            ``CosineAnnealingLR`` with ``T_max = epochs``). Either way the learning rate is a
            pure function of the step counter, so resuming can never restore a wrong ``T_max``.
        patience: stop after this many epochs without a new best validation error (0: never).
        seed: seed of the network initialization, the views and the batches.
        device: ``"auto"`` (CUDA when available, else CPU), ``"cpu"``, ``"cuda"``, ``"cuda:1"``.
        threads: torch CPU threads (0: leave torch's default).
    """

    batch_views: int = 16
    sources_per_view: int = 12
    targets_per_view: int = 16
    steps_per_epoch: int = 500
    epochs: int = 10
    lr: float = 1e-2
    eta_min: float = 1e-4
    schedule: str = "step"
    patience: int = 3
    seed: int = 0
    device: str = "auto"
    threads: int = 0

    def __post_init__(self) -> None:
        _check(self.batch_views >= 2, "train.batch_views must be ≥ 2 (BatchNorm over views)")
        _check(self.sources_per_view >= 1 and self.targets_per_view >= 1, "empty batches")
        _check(self.steps_per_epoch >= 1 and self.epochs >= 1, "need ≥ 1 step and epoch")
        _check(0.0 < self.eta_min <= self.lr, "need 0 < eta_min ≤ lr")
        _check(self.schedule in _SCHEDULES, f"train.schedule must be one of {_SCHEDULES}")
        _check(self.patience >= 0 and self.threads >= 0, "patience and threads must be ≥ 0")

    @property
    def pairs_per_step(self) -> int:
        return self.batch_views * self.sources_per_view * self.targets_per_view

    @property
    def total_steps(self) -> int:
        return self.epochs * self.steps_per_epoch


@dataclass(frozen=True)
class OutputConfig:
    """Where the run goes and what the exported bundle is called.

    ``dir`` receives ``train.log``, ``checkpoints/`` (``last.*``, ``best.safetensors``),
    ``basis.safetensors`` (when fitted) and ``bundle/`` (the exported model).
    """

    dir: str = "out/train/geodesic"
    name: str = "model"
    category: str = "unknown"
    weights_dtype: str = "float32"

    def __post_init__(self) -> None:
        _check(bool(self.dir) and bool(self.name), "output.dir and output.name are required")
        _check(self.weights_dtype in _WEIGHT_DTYPES, f"weights_dtype ∈ {list(_WEIGHT_DTYPES)}")

    @property
    def torch_weights_dtype(self) -> torch.dtype:
        import torch

        return getattr(torch, self.weights_dtype)


class ConfigRoot:
    """Base of the training configurations: a frozen dataclass whose fields are the TOML tables
    (each a frozen dataclass with ``dir`` in the ``output`` table), read strictly.

    Subclasses set :attr:`WHAT` (used in error messages), :attr:`REQUIRED_TABLES` (tables a
    document must have) and may override :meth:`check` for checks across tables.
    """

    WHAT: ClassVar[str] = "a training config"
    REQUIRED_TABLES: ClassVar[tuple[str, ...]] = ()
    __dataclass_fields__: ClassVar[dict[str, Any]]  # every subclass is a dataclass
    output: Any

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Self:
        """Build from nested dicts (a parsed TOML document); strict about keys and types."""
        if isinstance(data, dict):
            for name in cls.REQUIRED_TABLES:
                if name not in data:
                    raise InputError(f"{cls.WHAT} needs a [{name}] table")
        config = cls(**parse_tables(cls, data, cls.WHAT))
        config.check()
        return config

    @classmethod
    def load(cls, path: str | Path) -> Self:
        """Read a TOML config file."""
        return cls.from_dict(read_toml(path))

    def check(self) -> None:
        """Checks that involve several tables (each table checks its own values)."""

    def to_dict(self) -> dict[str, Any]:
        """JSON/TOML-safe nested dict (tuples as lists); ``from_dict(to_dict())`` is equal."""
        data: dict[str, Any] = json.loads(json.dumps(dataclasses.asdict(self)))
        return data

    def replace(self, **tables: dict[str, Any]) -> Self:
        """A copy with some keys of some tables changed: ``replace(train={"epochs": 2})``."""
        data = self.to_dict()
        for name, values in tables.items():
            if name not in data:
                raise InputError(f"unknown config table {name!r}")
            data[name] = {**data[name], **values}
        return self.from_dict(data)

    def content_hash(self) -> str:
        """SHA-256 of the canonical JSON of the config."""
        return hashlib.sha256(json.dumps(self.to_dict(), sort_keys=True).encode()).hexdigest()

    @property
    def run_dir(self) -> Path:
        """The run directory, ``output.dir``."""
        return Path(self.output.dir)


@dataclass(frozen=True)
class TrainConfig(ConfigRoot):
    """The whole training configuration of the geodesic network (see the module docstring)."""

    WHAT: ClassVar[str] = "a training config"
    REQUIRED_TABLES: ClassVar[tuple[str, ...]] = ("data",)

    data: DataConfig
    augment: AugmentConfig = field(default_factory=AugmentConfig)
    basis: BasisConfig = field(default_factory=BasisConfig)
    network: NetworkConfig = field(default_factory=NetworkConfig)
    train: OptimConfig = field(default_factory=OptimConfig)
    output: OutputConfig = field(default_factory=OutputConfig)

    def resolve_device(self) -> torch.device:
        """``train.device`` as a torch device (``auto``: CUDA if available, else CPU)."""
        from litege_core.device import resolve_device

        return resolve_device(self.train.device)


def parse_tables(config_cls: type, data: Any, what: str) -> dict[str, Any]:
    """A parsed TOML document → ``{table name: table dataclass}`` for the tables present,
    strict about table names, key names and value types (the fields of ``config_cls`` are
    the table dataclasses)."""
    if not isinstance(data, dict):
        raise InputError(f"{what} must be a table")
    hints = typing.get_type_hints(config_cls)
    unknown = sorted(set(data) - set(hints))
    if unknown:
        raise InputError(f"unknown config tables {unknown}; expected {sorted(hints)}")
    return {name: parse_table(hints[name], name, values) for name, values in data.items()}


def parse_table(cls: type, name: str, values: Any) -> Any:
    """One table → its dataclass, checking key names and value types (``bool``, ``int``,
    ``float``, ``str``, ``tuple[int, ...]`` and ``tuple[str, ...]`` fields)."""
    if not isinstance(values, dict):
        raise InputError(f"[{name}] must be a table, got {type(values).__name__}")
    hints = typing.get_type_hints(cls)
    unknown = sorted(set(values) - set(hints))
    if unknown:
        raise InputError(f"unknown keys in [{name}]: {unknown}; expected {sorted(hints)}")
    checked = {}
    for key, value in values.items():
        if hints[key] == tuple[int, ...]:
            ok = isinstance(value, list | tuple) and all(
                isinstance(v, int) and not isinstance(v, bool) for v in value
            )
            if not ok:
                raise InputError(f"{name}.{key} must be an array of integers, got {value!r}")
            checked[key] = tuple(value)
        elif hints[key] == tuple[str, ...]:
            if not (isinstance(value, list | tuple) and all(isinstance(v, str) for v in value)):
                raise InputError(f"{name}.{key} must be an array of strings, got {value!r}")
            checked[key] = tuple(value)
        else:
            checked[key] = _typed(f"{name}.{key}", hints[key], value)
    return cls(**checked)


def check_time_budget(seconds: float | None) -> float | None:
    """A training's wall-clock budget in seconds (``None``: none), checked.

    Raises:
        InputError: a budget that is not a positive number (0, negative or NaN).
    """
    if seconds is not None and not seconds > 0:
        raise InputError(
            f"the time budget must be a positive number of minutes, got {seconds / 60:g}"
        )
    return seconds


def read_toml(path: str | Path) -> dict[str, Any]:
    """A TOML config file as nested dicts; every failure is an :class:`InputError`."""
    source = Path(path)
    try:
        return tomllib.loads(source.read_text())
    except FileNotFoundError as exc:
        raise InputError(f"config file {source} does not exist") from exc
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"cannot read config file {source}: {exc}") from exc
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"{source} is not valid TOML: {exc}") from exc


def _typed(key: str, kind: type, value: Any) -> Any:
    if kind is bool:
        ok = isinstance(value, bool)
    elif kind is int:
        ok = isinstance(value, int) and not isinstance(value, bool)
    elif kind is float:
        ok = isinstance(value, int | float) and not isinstance(value, bool)
        if ok:
            value = float(value)
            ok = math.isfinite(value)
    elif kind is str:
        ok = isinstance(value, str)
    else:  # pragma: no cover - every field is one of the above
        ok = False
    if not ok:
        raise InputError(f"{key} must be a {kind.__name__}, got {value!r}")
    return value


def load_config(path: str | Path) -> TrainConfig:
    """Read a TOML training config (see the module docstring)."""
    return TrainConfig.load(path)


@contextlib.contextmanager
def run_log(logger: logging.Logger, run_dir: Path) -> Iterator[None]:
    """Within the block, ``logger`` (at INFO or finer) also writes to ``run_dir/train.log``
    (overwritten), one timestamped line per record."""
    handler = logging.FileHandler(run_dir / "train.log", mode="w")
    handler.setFormatter(logging.Formatter("%(asctime)s %(message)s", "%H:%M:%S"))
    logger.addHandler(handler)
    if logger.level == logging.NOTSET or logger.level > logging.INFO:
        logger.setLevel(logging.INFO)
    try:
        yield
    finally:
        logger.removeHandler(handler)
        handler.close()


__all__ = [
    "AugmentConfig",
    "BasisConfig",
    "ConfigRoot",
    "DataConfig",
    "NetworkConfig",
    "OptimConfig",
    "OutputConfig",
    "TrainConfig",
    "check_time_budget",
    "load_config",
    "parse_table",
    "parse_tables",
    "read_toml",
    "run_log",
]
