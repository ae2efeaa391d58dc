"""Posed rigged animals and MakeHuman bodies on one fixed triangulation: matching training data.

The collection sources of :mod:`litege_core.synth.rigged` and :mod:`litege_core.synth.makehuman`
remesh every posed shape, so two poses share no vertices. A matching dataset needs the
opposite: one triangulation per dataset, vertex ``i`` the same point on every shape (the
template kind of :mod:`litege_core.datasets.build`). Here each source model (a rigged species,
the MakeHuman body) gets its own template, built once:

1. the rest pose (centred, unit-area scale) is, for the low-poly animals, Loop-subdivided,
   then remeshed isotropically to ``target_vertices`` (the steps of a posed collection shape,
   so the surfaces look alike); each template vertex is located on that *source surface*
   (closest point: triangle and barycentric weights);
2. a shape ``seed`` is the source's own random pose (:func:`~litege_core.synth.rigged.
   pose_model`: clip, time, perturbed free joints, body scale; :func:`~litege_core.synth.
   makehuman.pose_human`: gender, muscle, weight, pose, body scale) on the source mesh,
   subdivided with the same operator where the template was (same connectivity, positions
   linear in the pose), and read back at the template vertices' barycentric locations.

Pairs of shapes of one source then come with exact dense correspondence, and the build's
shared sources give cross-pose geodesic targets for the matching network (issue 15: pairs drawn
within one species or body model).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from litege_core.errors import ComputationError
from litege_core.synth.makehuman import (
    MAKEHUMAN_VERSION,
    HumanSettings,
    MakeHumanModel,
    body_shape,
    cached_makehuman,
    pose_human,
)
from litege_core.synth.rigged import (
    RIGGED_VERSION,
    PoseSettings,
    RiggedModel,
    animal_path,
    cached_model,
    finish_mesh,
    pose_model,
)

TEMPLATE_VERSION = "posed-template-1"
DEFAULT_TEMPLATE_VERTICES = 4500
MAKEHUMAN = "makehuman"
"""The family of the MakeHuman template dataset."""


@dataclass(frozen=True)
class SurfaceTemplate:
    """A fixed triangulation and where its vertices sit on a source surface.

    Attributes:
        vertices: ``(V, 3)`` template vertices (the rest pose).
        faces: ``(F, 3)`` template triangles.
        source_faces: ``(Fs, 3)`` faces of the source surface (subdivided when ``subdivide``).
        triangle: ``(V,)`` source triangle holding each template vertex.
        barycentric: ``(V, 3)`` weights of that triangle's corners (rows sum to 1).
        subdivide: the source mesh is Loop-subdivided once before reading it.
    """

    vertices: NDArray
    faces: NDArray
    source_faces: NDArray
    triangle: NDArray
    barycentric: NDArray
    subdivide: bool

    def transfer(self, vertices: NDArray, faces: NDArray) -> NDArray:
        """``(V, 3)`` template vertices on a posed source mesh ``(vertices (Vs, 3), faces)``.

        Raises:
            ComputationError: the (subdivided) source has other faces than the template's.
        """
        from litege_core.synth.meshops import subdivide_loop

        if self.subdivide:
            vertices, faces = subdivide_loop(vertices, faces)
        if not np.array_equal(faces, self.source_faces):
            raise ComputationError("the posed source mesh has another connectivity")
        return _interpolate(vertices, self.source_faces, self.triangle, self.barycentric)


def _interpolate(
    vertices: NDArray, faces: NDArray, triangle: NDArray, barycentric: NDArray
) -> NDArray:
    """``(V, 3)`` points at barycentric weights ``(V, 3)`` in triangles ``(V,)`` of a mesh."""
    return np.einsum("vk,vkd->vd", barycentric, vertices[faces[triangle]])


def surface_template(
    rest: NDArray, faces: NDArray, target_vertices: int, subdivide: bool
) -> SurfaceTemplate:
    """The template of a rest mesh ``(rest (Vs, 3), faces)`` (step 1 of the module docstring).

    Raises:
        ComputationError: the remeshed rest pose is not a clean closed manifold.
    """
    import trimesh

    from litege_core.synth.meshops import subdivide_loop

    source_vertices, source_faces = (
        subdivide_loop(rest, faces) if subdivide else (np.asarray(rest), np.asarray(faces))
    )
    # the source surface is already subdivided: remesh it as it is
    vertices, template_faces = finish_mesh(source_vertices, source_faces, target_vertices, False)
    surface = trimesh.Trimesh(source_vertices, source_faces, process=False)
    _, _, triangle = trimesh.proximity.closest_point(surface, vertices)
    triangle = np.asarray(triangle, dtype=np.int64)
    barycentric = trimesh.triangles.points_to_barycentric(
        source_vertices[source_faces[triangle]], vertices
    )
    barycentric = np.clip(barycentric, 0.0, None)
    barycentric /= barycentric.sum(axis=1, keepdims=True)
    on_surface = _interpolate(source_vertices, source_faces, triangle, barycentric)
    return SurfaceTemplate(
        on_surface, template_faces, source_faces, triangle, barycentric, subdivide
    )


@functools.lru_cache(maxsize=16)
def cached_species_template(
    path: str, animal: str, target_vertices: int
) -> tuple[RiggedModel, SurfaceTemplate]:
    """A rigged model and its template (rest pose, centred, Loop-subdivided), per process."""
    model = cached_model(path, animal)
    rest = model.rest_vertices()
    template = surface_template(
        rest - rest.mean(axis=0), model.mesh.faces, target_vertices, subdivide=True
    )
    return model, template


@functools.lru_cache(maxsize=2)
def cached_human_template(
    directory: str, target_vertices: int
) -> tuple[MakeHumanModel, SurfaceTemplate]:
    """The MakeHuman model and its template (the neutral body: gender, muscle and weight ½)."""
    from litege_core.synth.meshops import unit_area_scale

    model = cached_makehuman(directory)
    rest = body_shape(model, 0.5, 0.5, 0.5)[model.body]
    rest = (rest - rest.mean(axis=0)) * unit_area_scale(rest, model.faces)
    return model, surface_template(rest, model.faces, target_vertices, subdivide=False)


class _PosedTemplateSource:
    """``template()`` and ``generate(family, seed)`` of a template factory whose shapes are
    random poses of one source model read off its :class:`SurfaceTemplate`."""

    def _family(self) -> str:
        raise NotImplementedError

    def _loaded(self) -> tuple[Any, SurfaceTemplate]:
        raise NotImplementedError

    def _posed(self, model: Any, seed: int) -> tuple[NDArray, NDArray]:
        """The pose of ``seed`` on the source mesh: ``(vertices, faces)``."""
        raise NotImplementedError

    def template(self) -> tuple[NDArray, NDArray]:
        _, template = self._loaded()
        return template.vertices, template.faces

    def generate(self, family: str, seed: int) -> NDArray:
        if family != self._family():
            raise ComputationError(f"the {self._family()} template factory got family {family!r}")
        model, template = self._loaded()
        return template.transfer(*self._posed(model, seed))


@dataclass(frozen=True)
class RiggedTemplateFactory(_PosedTemplateSource):
    """The template factory of one rigged species (picklable: build workers reload the model):
    the family is the animal, a shape the pose of ``seed`` on the species' template."""

    root: str
    animal: str
    target_vertices: int = DEFAULT_TEMPLATE_VERTICES
    settings: PoseSettings = field(default_factory=PoseSettings)
    category: str = "rigged-template"

    @property
    def version(self) -> str:
        s = self.settings
        bend = f"-{s.bend.describe()}" if s.bend.probability > 0 else ""
        return (
            f"{TEMPLATE_VERSION}-{RIGGED_VERSION}-{self.animal}-{self.target_vertices}-"
            f"{s.perturb_degrees}-{s.body_range[0]}-{s.body_range[1]}{bend}"
        )

    def _family(self) -> str:
        return self.animal

    def _loaded(self) -> tuple[RiggedModel, SurfaceTemplate]:
        path = str(animal_path(self.root, self.animal))
        return cached_species_template(path, self.animal, self.target_vertices)

    def _posed(self, model: RiggedModel, seed: int) -> tuple[NDArray, NDArray]:
        posed, _ = pose_model(model, np.random.default_rng([seed, 0]), self.settings)
        return posed, model.mesh.faces


@dataclass(frozen=True)
class MakeHumanTemplateFactory(_PosedTemplateSource):
    """The template factory of MakeHuman bodies (one family, :data:`MAKEHUMAN`): a shape is
    the shaped, posed body of ``seed`` on the template."""

    root: str
    target_vertices: int = DEFAULT_TEMPLATE_VERTICES
    settings: HumanSettings = field(default_factory=HumanSettings)
    category: str = "makehuman-template"

    @property
    def version(self) -> str:
        s = self.settings
        return (
            f"{TEMPLATE_VERSION}-{MAKEHUMAN_VERSION}-{self.target_vertices}-"
            f"{s.body_range[0]}-{s.body_range[1]}"
        )

    def _family(self) -> str:
        return MAKEHUMAN

    def _loaded(self) -> tuple[MakeHumanModel, SurfaceTemplate]:
        return cached_human_template(str(Path(self.root) / "makehuman"), self.target_vertices)

    def _posed(self, model: MakeHumanModel, seed: int) -> tuple[NDArray, NDArray]:
        posed, _ = pose_human(model, np.random.default_rng([seed, 0]), self.settings)
        return posed, model.faces


__all__ = [
    "DEFAULT_TEMPLATE_VERTICES",
    "MAKEHUMAN",
    "TEMPLATE_VERSION",
    "MakeHumanTemplateFactory",
    "RiggedTemplateFactory",
    "SurfaceTemplate",
    "cached_human_template",
    "cached_species_template",
    "surface_template",
]
