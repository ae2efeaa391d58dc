"""What a ground-truth geodesic dataset contains: the :class:`DatasetSpec`.

Two kinds of dataset:

* ``template`` (format version 1): one procedural category whose shapes all share one
  triangulation; ``n_shared_sources`` farthest-point samples of the template are sources on
  every shape.
* ``collection`` (format version 2): shapes with their own vertex counts and triangulations
  (posed real animals, MakeHuman bodies, a folder of user meshes). Shared sources make no
  sense across topologies, so ``n_shared_sources`` becomes the number of farthest-point
  sources of *each shape* (starting at its vertex 0).

Shape ``k`` of a split is that split's shape ``i = first_index + k``: family
``families[i % len(families)]`` (or of that split's own family list, ``split_families``, when
families are split by file) and seed ``SPLIT_SEED_OFFSETS[split] + i``, so splits never share a
seed and any shape can be regenerated from (category, family, seed). ``first_index`` (default
0) lets a second dataset continue an earlier one's seeds, more shapes of the same distribution
without rebuilding or repeating the first ones.

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
COLLECTION_FORMAT_VERSION = 2
KINDS = ("template", "collection")
COLLECTION_SOURCES = ("rigged", "makehuman")
"""Collection categories with presets (``folder`` datasets are specified per directory)."""


def is_count(text: str) -> bool:
    """Whether ``text`` is an integer ``>= 0`` written in ASCII digits (``str.isdigit`` also
    accepts ``"²"``, which ``int`` refuses)."""
    return text.isascii() and text.isdecimal()


@dataclass(frozen=True)
class DatasetSpec:
    """Everything that determines a dataset's content.

    Attributes:
        name: dataset name (directory name by convention).
        category: shape category of the factory (``"quadruped"``, ``"biped"``; for
            collections ``"rigged"``, ``"makehuman"`` or ``"folder"``).
        families: families cycled through by shape index.
        n_shapes: shapes per split, e.g. ``{"train": 400, "val": 50, "test": 50}``; at least
            one shape in all.
        n_shared_sources: template kind: sources shared by every shape (farthest-point
            samples of the template), so every pair of shapes yields cross-shape targets;
            collection kind: farthest-point sources of each shape.
        n_extra_sources: extra random sources per shape (seeded by the shape's seed).
        shard_size: shapes per shard file.
        kind: ``"template"`` or ``"collection"`` (see the module docstring).
        split_families: optional per-split family lists (a subset of ``families`` each),
            e.g. the files of a folder split train/val/test by file; ``None``: every split
            cycles through ``families``.
        first_index: index of the first shape of every split in the category's seed
            sequence (0 ≤ first_index < 1,000,000, the gap between split seed offsets).
    """

    name: str
    category: str
    families: tuple[str, ...]
    n_shapes: dict[str, int] = field(default_factory=lambda: {"train": 0, "val": 0, "test": 0})
    n_shared_sources: int = 48
    n_extra_sources: int = 16
    shard_size: int = 32
    kind: str = "template"
    split_families: dict[str, tuple[str, ...]] | None = None
    first_index: int = 0

    def __post_init__(self) -> None:
        if not self.families:
            raise InputError("a dataset needs at least one family")
        if self.kind not in KINDS:
            raise InputError(f"unknown dataset kind {self.kind!r}; expected one of {KINDS}")
        if self.split_families is not None:
            if set(self.split_families) - set(SPLITS):
                raise InputError(f"split_families has unknown splits; expected {SPLITS}")
            for split, names in self.split_families.items():
                if set(names) - set(self.families):
                    raise InputError(f"split_families[{split!r}] names unknown families")
                if self.n_shapes.get(split, 0) > 0 and not names:
                    raise InputError(f"split {split!r} has shapes but no families")
        unknown = set(self.n_shapes) - set(SPLITS)
        if unknown:
            raise InputError(f"unknown splits {sorted(unknown)}; expected {SPLITS}")
        if any(n < 0 for n in self.n_shapes.values()):
            raise InputError("shape counts must be non-negative")
        if sum(self.n_shapes.values()) == 0:
            raise InputError(
                f"nothing to build: every split of dataset {self.name!r} has 0 shapes "
                f"(give at least one, e.g. train=1)"
            )
        if self.n_shared_sources < 1 or self.n_extra_sources < 0 or self.shard_size < 1:
            raise InputError("need n_shared_sources ≥ 1, n_extra_sources ≥ 0, shard_size ≥ 1")
        seed_gap = SPLIT_SEED_OFFSETS["val"] - SPLIT_SEED_OFFSETS["train"]
        last = self.first_index + max(self.n_shapes.values(), default=0)
        if isinstance(self.first_index, bool) or self.first_index < 0 or last > seed_gap:
            raise InputError(
                f"first_index must be ≥ 0 and keep every split's seeds below {seed_gap:,} "
                f"(got first_index {self.first_index} for {last - self.first_index} shapes)"
            )

    @property
    def n_sources(self) -> int:
        return self.n_shared_sources + self.n_extra_sources

    @property
    def is_collection(self) -> bool:
        return self.kind == "collection"

    @property
    def format_version(self) -> int:
        return COLLECTION_FORMAT_VERSION if self.is_collection else FORMAT_VERSION

    def families_of(self, split: str) -> tuple[str, ...]:
        """The families cycled through by ``split``."""
        if self.split_families is not None and split in self.split_families:
            return self.split_families[split]
        return self.families

    def shape_key(self, split: str, index: int) -> tuple[str, int]:
        """``(family, seed)`` of shape ``index`` of ``split``."""
        families = self.families_of(split)
        position = self.first_index + index
        return families[position % len(families)], SPLIT_SEED_OFFSETS[split] + position

    def distance_dtype(self, split: str) -> str:
        return "float16" if split == "train" else "float32"

    def to_json(self) -> str:
        """Canonical JSON; ``kind``, ``split_families`` and ``first_index`` are written only
        when they differ from the defaults, so template specs serialize exactly as format
        version 1 did."""
        data = asdict(self)
        data["families"] = list(self.families)
        if self.kind == "template":
            del data["kind"]
        if self.first_index == 0:
            del data["first_index"]
        if self.split_families is None:
            del data["split_families"]
        else:
            data["split_families"] = {k: list(v) for k, v in self.split_families.items()}
        return json.dumps(data, sort_keys=True)

    @classmethod
    def from_dict(cls, data: dict) -> DatasetSpec:
        data = dict(data)
        data["families"] = tuple(data["families"])
        if data.get("split_families") is not None:
            data["split_families"] = {k: tuple(v) for k, v in data["split_families"].items()}
        return cls(**data)


@dataclass(frozen=True)
class WorkShare:
    """One worker's share of a sharded build (``litege data build --shard I/N``).

    The shard *files* of a dataset are numbered in build order (val, test, then train; see
    :data:`litege_core.datasets.build.BUILD_ORDER`) by a global ordinal ``k``; worker ``I`` of
    ``N`` builds the files with ``k mod N == I``. The assignment depends only on the spec, so
    ``N`` workers (processes, machines, the pods of a Kubernetes Indexed Job) build disjoint
    files into one directory and together produce exactly the single-process dataset.

    Attributes:
        index: ``I``, 0-based (a Kubernetes ``JOB_COMPLETION_INDEX``).
        count: ``N``, the number of workers.
    """

    index: int
    count: int

    def __post_init__(self) -> None:
        if isinstance(self.index, bool) or isinstance(self.count, bool):
            raise InputError("a work share is two integers I/N")
        if self.count < 1 or not 0 <= self.index < self.count:
            raise InputError(f"need 0 <= I < N in --shard I/N, got {self.index}/{self.count}")

    @classmethod
    def parse(cls, text: str) -> WorkShare:
        """``"I/N"`` → ``WorkShare(I, N)``; InputError for anything else."""
        index, sep, count = str(text).strip().partition("/")
        if not sep or not is_count(index.strip()) or not is_count(count.strip()):
            raise InputError(f"--shard must be I/N with integers 0 <= I < N, got {text!r}")
        return cls(int(index), int(count))

    def owns(self, ordinal: int) -> bool:
        """Whether the shard file of global ``ordinal`` belongs to this worker."""
        return ordinal % self.count == self.index

    def __str__(self) -> str:
        return f"{self.index}/{self.count}"


def parse_split_counts(text: str) -> dict[str, int]:
    """``"train=896,val=48,test=48"`` → ``{"train": 896, "val": 48, "test": 48}`` (splits left
    out keep their preset size: merge the result into a preset's ``n_shapes``).

    Raises:
        InputError: an unknown split, a repeated one, or a count that is not an integer ≥ 0.
    """
    counts: dict[str, int] = {}
    for item in str(text).split(","):
        split, sep, value = item.strip().partition("=")
        split, value = split.strip(), value.strip()
        if not sep or split not in SPLITS or not is_count(value):
            raise InputError(
                f"shape counts must read SPLIT=N[,SPLIT=N...] with SPLIT in {SPLITS} and "
                f"integers N >= 0, got {text!r}"
            )
        if split in counts:
            raise InputError(f"split {split!r} is given twice in {text!r}")
        counts[split] = int(value)
    return counts


def preset(name: str, category: str) -> DatasetSpec:
    """Named presets of the procedural categories (and, for ``rigged`` / ``makehuman``, of
    :func:`collection_preset`): ``small`` (≥ 500 shapes, builds on 2 cores in ≤ 30 min), ``large``
    (2,000 training shapes: a few hours on one core, the real-shape scale step), ``full``
    (the paper's scale: ≥ 10K quadrupeds / ≥ 5K bipeds, for a 16-core machine) and
    ``matching`` (180 shapes with only the shared sources, which are all the matching target
    uses: the CPU-sized matching training set; matching is evaluated on freshly generated
    test-seed shapes, so it has no test split)."""
    from litege_core.synth import CATEGORIES, families

    if category in COLLECTION_SOURCES:
        return collection_preset(name, category)
    if category not in CATEGORIES:
        raise InputError(
            f"unknown category {category!r}; expected one of {CATEGORIES + COLLECTION_SOURCES}"
        )
    sizes = {
        ("small", "quadruped"): {"train": 400, "val": 50, "test": 50},
        ("small", "biped"): {"train": 400, "val": 50, "test": 50},
        ("large", "quadruped"): {"train": 2_000, "val": 100, "test": 100},
        ("large", "biped"): {"train": 2_000, "val": 100, "test": 100},
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


def collection_preset(name: str, source: str) -> DatasetSpec:
    """Presets of the collection sources (per-shape triangulations, ~4–5.5K vertices):

    * ``rigged``: the 12 rigged glTF animals (11 Quaternius + the Khronos fox) posed from
      their animation clips, one family each;
    * ``makehuman``: MakeHuman bodies (random gender/muscle/weight and pose), one family.

    ``small``: 480 + 48 + 48 (rigged) / 400 + 50 + 50 (makehuman) shapes, ``large``: 2,400 +
    120 + 120 / 2,000 + 100 + 100. 48 farthest-point + 16 random sources per shape.
    """
    if source not in COLLECTION_SOURCES:
        raise InputError(f"unknown collection source {source!r}; expected {COLLECTION_SOURCES}")
    if source == "rigged":
        from litege_core.synth.rigged import ANIMALS

        families: tuple[str, ...] = ANIMALS
    else:
        families = ("makehuman",)
    sizes = {
        ("small", "rigged"): {"train": 480, "val": 48, "test": 48},
        ("large", "rigged"): {"train": 2_400, "val": 120, "test": 120},
        ("small", "makehuman"): {"train": 400, "val": 50, "test": 50},
        ("large", "makehuman"): {"train": 2_000, "val": 100, "test": 100},
    }
    if (name, source) not in sizes:
        raise InputError(f"unknown preset {name!r} for collection source {source!r}")
    return DatasetSpec(
        name=f"{source}-{name}",
        category=source,
        families=families,
        n_shapes=sizes[(name, source)],
        shard_size=16,
        kind="collection",
    )


def species_matching_spec(
    species: str, category: str, n_shapes: dict[str, int], *, name: str, first_index: int = 0
) -> DatasetSpec:
    """The template-kind matching dataset of one posed source model (a rigged species or the
    MakeHuman body: posed copies on its fixed triangulation,
    :mod:`litege_core.synth.posed_templates`): shared sources only, as the ``matching``
    preset; ``name`` is the set's (the dataset is ``NAME/SPECIES``)."""
    return DatasetSpec(
        name=f"{name}/{species}",
        category=category,
        families=(species,),
        n_shapes=n_shapes,
        n_extra_sources=0,
        shard_size=16,
        first_index=first_index,
    )


SPECIES_MATCHING_SHAPES = {"train": 120, "val": 4, "test": 0}
"""Shapes per source model of ``litege data build --category rigged|makehuman --preset
matching``."""


__all__ = [
    "COLLECTION_FORMAT_VERSION",
    "COLLECTION_SOURCES",
    "FORMAT_VERSION",
    "KINDS",
    "SPECIES_MATCHING_SHAPES",
    "SPLITS",
    "SPLIT_SEED_OFFSETS",
    "DatasetSpec",
    "WorkShare",
    "collection_preset",
    "is_count",
    "parse_split_counts",
    "preset",
    "species_matching_spec",
]
