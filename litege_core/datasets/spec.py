"""What a ground-truth geodesic dataset contains: the :class:`DatasetSpec`.

A dataset covers one category (all shapes share one triangulation). Shape ``k`` of a split has
family ``families[k % len(families)]`` and seed ``SPLIT_SEED_OFFSETS[split] + k``, so splits
never share a seed and any shape can be regenerated from (category, family, seed).

Storage precision (decided here, recorded in the manifest):

* vertices: float32. Targets are residuals ``geodesic − euclidean`` of short pairs, so the
  coordinates need ~1e-6 relative precision; float16 (~5e-4) would swamp short residuals.
* train distances: float16. Relative rounding error ≤ 2⁻¹¹ ≈ 4.9e-4, far below the ~2 % model
  error it trains, and halves the size of the largest array. Overflow (> 65504) is refused.
* val / test distances: float32. Ground truth used to *measure* errors must not add any.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field

from litege_core.errors import InputError

SPLITS = ("train", "val", "test")
SPLIT_SEED_OFFSETS = {"train": 0, "val": 1_000_000, "test": 2_000_000}
FORMAT_VERSION = 1


@dataclass(frozen=True)
class DatasetSpec:
    """Everything that determines a dataset's content.

    Attributes:
        name: dataset name (directory name by convention).
        category: shape category of the factory (``"quadruped"`` or ``"biped"``).
        families: families cycled through by shape index.
        n_shapes: shapes per split, e.g. ``{"train": 400, "val": 50, "test": 50}``.
        n_shared_sources: sources shared by every shape (farthest-point samples of the
            template), so every pair of shapes yields cross-shape targets.
        n_extra_sources: extra random sources per shape (seeded by the shape's seed).
        shard_size: shapes per shard file.
    """

    name: str
    category: str
    families: tuple[str, ...]
    n_shapes: dict[str, int] = field(default_factory=lambda: {"train": 0, "val": 0, "test": 0})
    n_shared_sources: int = 48
    n_extra_sources: int = 16
    shard_size: int = 32

    def __post_init__(self) -> None:
        if not self.families:
            raise InputError("a dataset needs at least one family")
        unknown = set(self.n_shapes) - set(SPLITS)
        if unknown:
            raise InputError(f"unknown splits {sorted(unknown)}; expected {SPLITS}")
        if any(n < 0 for n in self.n_shapes.values()):
            raise InputError("shape counts must be non-negative")
        if self.n_shared_sources < 1 or self.n_extra_sources < 0 or self.shard_size < 1:
            raise InputError("need n_shared_sources ≥ 1, n_extra_sources ≥ 0, shard_size ≥ 1")

    @property
    def n_sources(self) -> int:
        return self.n_shared_sources + self.n_extra_sources

    def shape_key(self, split: str, index: int) -> tuple[str, int]:
        """``(family, seed)`` of shape ``index`` of ``split``."""
        return self.families[index % len(self.families)], SPLIT_SEED_OFFSETS[split] + index

    def distance_dtype(self, split: str) -> str:
        return "float16" if split == "train" else "float32"

    def to_json(self) -> str:
        data = asdict(self)
        data["families"] = list(self.families)
        return json.dumps(data, sort_keys=True)

    @classmethod
    def from_dict(cls, data: dict) -> DatasetSpec:
        data = dict(data)
        data["families"] = tuple(data["families"])
        return cls(**data)


def preset(name: str, category: str) -> DatasetSpec:
    """Named presets: ``small`` (≥ 500 shapes, builds on 2 cores in ≤ 30 min), ``full``
    (the paper's scale: ≥ 10K quadrupeds / ≥ 5K bipeds, for a 16-core machine) and
    ``matching`` (180 shapes with only the shared sources, which are all the matching target
    uses: the CPU-sized matching training set; matching is evaluated on freshly generated
    test-seed shapes, so it has no test split)."""
    from litege_core.synth import CATEGORIES, families

    if category not in CATEGORIES:
        raise InputError(f"unknown category {category!r}; expected one of {CATEGORIES}")
    sizes = {
        ("small", "quadruped"): {"train": 400, "val": 50, "test": 50},
        ("small", "biped"): {"train": 400, "val": 50, "test": 50},
        ("full", "quadruped"): {"train": 10_000, "val": 300, "test": 200},
        ("full", "biped"): {"train": 5_000, "val": 200, "test": 100},
        ("matching", "quadruped"): {"train": 160, "val": 20, "test": 0},
        ("matching", "biped"): {"train": 160, "val": 20, "test": 0},
    }
    if (name, category) not in sizes:
        raise InputError(f"unknown preset {name!r} for category {category!r}")
    return DatasetSpec(
        name=f"{category}-{name}",
        category=category,
        families=families(category),
        n_shapes=sizes[(name, category)],
        n_extra_sources=0 if name == "matching" else DatasetSpec.n_extra_sources,
    )
