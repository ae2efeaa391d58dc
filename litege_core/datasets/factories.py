"""Shape factories that feed the dataset builder.

* :class:`SynthFactory`: the procedural families of ``synth`` (template datasets: one shared
  triangulation);
* collection factories (each shape has its own triangulation, see
  :class:`~litege_core.datasets.build.CollectionFactory`):
  :class:`RiggedFactory` (posed rigged glTF animals), :class:`MakeHumanFactory` (MakeHuman
  bodies) and :class:`FolderFactory` (a directory of user meshes).

The real-shape factories read their assets from a path (never from the repository): the
train-data directory is ``root`` or, by default, ``$LITEGE_TRAIN_DATA`` or
``../shared/train-data``.
"""

from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from numpy.typing import NDArray

from litege_core.errors import InputError

if TYPE_CHECKING:
    from litege_core.synth.folder import FolderSettings
    from litege_core.synth.rigged import PoseSettings

DEFAULT_TRAIN_DATA = "../shared/train-data"


def train_data_root(root: str | os.PathLike | None = None) -> Path:
    """The train-data directory: ``root``, else ``$LITEGE_TRAIN_DATA``, else
    ``../shared/train-data`` (relative to the working directory)."""
    return Path(root or os.environ.get("LITEGE_TRAIN_DATA") or DEFAULT_TRAIN_DATA)


@dataclass(frozen=True)
class SynthFactory:
    """Procedural shapes of one ``synth`` category (template triangulation shared); a
    ``steep_share`` of them rear, leap, sit up or lie on the belly
    (:func:`~litege_core.synth.poses.steep_pose`); ``spread`` widens every family's
    proportion range (:func:`~litege_core.synth.shape_space.sample_factors`) and
    ``girth_std`` draws each shape a lean or stocky build
    (:func:`~litege_core.synth.generate.girth_multiplier`)."""

    category: str
    steep_share: float = 0.0
    spread: float = 1.0
    girth_std: float = 0.0

    @property
    def version(self) -> str:
        from litege_core.synth import GENERATOR_VERSION
        from litege_core.synth.poses import steep_tag

        spread = "" if self.spread == 1.0 else f"+spread{self.spread:g}"
        girth = f"+girth{self.girth_std:g}" if self.girth_std else ""
        return GENERATOR_VERSION + steep_tag(self.category, self.steep_share) + spread + girth

    def template(self) -> tuple[NDArray, NDArray]:
        from litege_core.synth import template

        tmpl = template(self.category)
        return tmpl.vertices, tmpl.faces

    def generate(self, family: str, seed: int) -> NDArray:
        from litege_core.synth import generate_shape
        from litege_core.synth.poses import steep_pose

        pose = steep_pose(self.category, seed, self.steep_share)
        shape = generate_shape(
            self.category, family, seed, pose, spread=self.spread, girth_std=self.girth_std
        )
        return shape.vertices


@dataclass(frozen=True)
class RiggedFactory:
    """Posed, remeshed rigged glTF animals (:mod:`litege_core.synth.rigged`); a family is an
    animal of :data:`~litege_core.synth.rigged.ANIMALS`."""

    root: str
    category: str = "rigged"
    settings: PoseSettings | None = None
    """Pose ranges (``None``: the defaults, e.g. no body bends)."""

    @property
    def version(self) -> str:
        from litege_core.synth.rigged import RIGGED_VERSION

        if self.settings is None:
            return RIGGED_VERSION
        return f"{RIGGED_VERSION}:{self.settings.describe()}"

    def generate_mesh(self, family: str, seed: int) -> tuple[NDArray, NDArray]:
        from litege_core.synth.rigged import PoseSettings, animal_path, cached_model, posed_animal

        model = cached_model(str(animal_path(self.root, family)), family)
        vertices, faces, _ = posed_animal(model, seed, self.settings or PoseSettings())
        return vertices, faces


@dataclass(frozen=True)
class MakeHumanFactory:
    """Shaped, posed, remeshed MakeHuman bodies (:mod:`litege_core.synth.makehuman`); one
    family, ``"makehuman"``; a ``steep_share`` of them bend, balance on one leg or raise their
    arms (:func:`~litege_core.synth.makehuman.steep_angles`)."""

    root: str
    category: str = "makehuman"
    steep_share: float = 0.0

    @property
    def version(self) -> str:
        from litege_core.synth.makehuman import MAKEHUMAN_VERSION
        from litege_core.synth.poses import steep_tag

        return MAKEHUMAN_VERSION + steep_tag(self.category, self.steep_share)

    def generate_mesh(self, family: str, seed: int) -> tuple[NDArray, NDArray]:
        from litege_core.synth.makehuman import cached_makehuman, posed_human

        if family != "makehuman":
            raise InputError(f"unknown makehuman family {family!r}")
        model = cached_makehuman(str(Path(self.root) / "makehuman"))
        vertices, faces, _ = posed_human(model, seed, steep_share=self.steep_share)
        return vertices, faces


@dataclass(frozen=True)
class FolderFactory:
    """Augmented remeshes of the mesh files of a directory (:mod:`litege_core.synth.folder`);
    a family is a file path relative to ``directory``. ``digest`` (of the files' names and
    bytes) is part of the version, so a build never resumes over changed files."""

    directory: str
    digest: str
    settings: FolderSettings | None = None
    category: str = "folder"

    @property
    def version(self) -> str:
        from litege_core.synth.folder import FOLDER_VERSION, FolderSettings

        settings = self.settings or FolderSettings()
        return f"{FOLDER_VERSION}:{self.digest}:{settings.describe()}"

    def generate_mesh(self, family: str, seed: int) -> tuple[NDArray, NDArray]:
        from litege_core.synth.folder import FolderSettings, folder_shape

        return folder_shape(self.directory, family, seed, self.settings or FolderSettings())


def factory_for(
    category: str,
    root: str | os.PathLike | None = None,
    pose: PoseSettings | None = None,
    steep_share: float = 0.0,
    spread: float = 1.0,
    girth_std: float = 0.0,
):
    """The factory of a category: ``"quadruped"`` / ``"biped"`` (procedural, template kind) or
    ``"rigged"`` / ``"makehuman"`` (collection kind, assets under the train-data ``root``);
    ``pose``: the rigged animals' pose ranges (e.g. body bends), ``None`` for the defaults;
    ``steep_share``: the share of shapes in steep poses (procedural quadrupeds rearing,
    leaping, sitting up or lying on the belly; MakeHuman bodies bending, balancing or raising
    their arms); ``spread``: the procedural families' proportion range, × their own;
    ``girth_std``: log std of the procedural shapes' and the rigged animals' build (lean to
    stocky).

    Raises:
        InputError: unknown category, the train-data assets are missing, ``pose`` given
            for a category other than ``rigged``, or a ``steep_share`` outside ``[0, 1]`` or
            for a category without steep poses, a ``spread`` other than 1 for a category
            that is not procedural, a ``girth_std`` for MakeHuman, or either out of range.
    """
    from litege_core.synth import CATEGORIES
    from litege_core.synth.poses import check_steep_share

    if pose is not None and category != "rigged":
        raise InputError(f"pose settings apply to the rigged animals only, not to {category!r}")
    check_steep_share(category, steep_share)
    if spread != 1.0 and category not in CATEGORIES:
        raise InputError(f"--spread applies to the procedural categories, not to {category!r}")
    if girth_std and category not in (*CATEGORIES, "rigged"):
        raise InputError(
            f"--girth-std applies to the procedural and rigged animals, not to {category!r}"
        )
    if not spread > 0.0 or not girth_std >= 0.0:
        raise InputError(f"need spread > 0 and girth_std >= 0, got {spread}, {girth_std}")

    if category in CATEGORIES:
        return SynthFactory(category, steep_share, spread, girth_std)
    if category in ("rigged", "makehuman"):
        base = train_data_root(root)
        probe = base / ("quaternius-uaa" if category == "rigged" else "makehuman")
        if not probe.is_dir():
            raise InputError(
                f"{probe} not found: pass the train-data directory (or set LITEGE_TRAIN_DATA)"
            )
        if category == "rigged":
            if girth_std:
                from litege_core.synth.rigged import PoseSettings

                pose = dataclasses.replace(pose or PoseSettings(), girth_std=girth_std)
            return RiggedFactory(str(base), settings=pose)
        return MakeHumanFactory(str(base), steep_share=steep_share)
    raise InputError(
        f"unknown category {category!r}; expected one of {(*CATEGORIES, 'rigged', 'makehuman')}"
    )


def species_factory(
    name: str, root: str | os.PathLike | None = None, pose: PoseSettings | None = None
):
    """The template factory of one posed source model (posed copies on one triangulation,
    :mod:`litege_core.synth.posed_templates`): a rigged animal of
    :data:`~litege_core.synth.rigged.ANIMALS`, or ``"makehuman"``; assets under the
    train-data ``root``; ``pose``: a rigged animal's pose ranges (``None``: the defaults).

    Raises:
        InputError: unknown name, its asset is missing, or ``pose`` given for MakeHuman.
    """
    from litege_core.synth.posed_templates import (
        MAKEHUMAN,
        MakeHumanTemplateFactory,
        RiggedTemplateFactory,
    )
    from litege_core.synth.rigged import PoseSettings, animal_path

    base = train_data_root(root)
    path = base / "makehuman" if name == MAKEHUMAN else animal_path(base, name)
    if not path.exists():
        raise InputError(
            f"{path} not found: pass the train-data directory (or set LITEGE_TRAIN_DATA)"
        )
    if name == MAKEHUMAN:
        if pose is not None:
            raise InputError("pose settings apply to the rigged animals only, not to MakeHuman")
        return MakeHumanTemplateFactory(str(base))
    return RiggedTemplateFactory(str(base), name, settings=pose or PoseSettings())


__all__ = [
    "DEFAULT_TRAIN_DATA",
    "FolderFactory",
    "MakeHumanFactory",
    "RiggedFactory",
    "SynthFactory",
    "factory_for",
    "species_factory",
    "train_data_root",
]
