"""Posed rigged animals on one fixed triangulation per species: matching training data.

The rigged source of :mod:`litege_core.synth.rigged` remeshes every posed shape, so two poses
of one animal share no vertices. A matching dataset needs the opposite: one triangulation per
dataset, vertex ``i`` the same point on every shape (the template kind of
:mod:`litege_core.datasets.build`). Here each species gets its own template, built once:

1. the skinned rest pose (centred, unit area) is Loop-subdivided and remeshed isotropically
   to ``target_vertices`` (the same steps as a posed rigged shape, so the surfaces look
   alike); each template vertex is located on the subdivided rest surface (closest point:
   triangle and barycentric weights);
2. a shape ``(species, seed)`` is a pose of :func:`~litege_core.synth.rigged.pose_model`
   (clip, time, perturbed free joints, anisotropic body scale) applied to the low-poly body,
   Loop-subdivided with the same operator (same connectivity, positions linear in the
   pose) and read back at the template vertices' barycentric locations.

Pairs of poses of one species then come with exact dense correspondence, and the build's
shared sources give cross-pose geodesic targets for the matching network (issue 15: rigged
animals as matching data, pairs drawn within a species).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from litege_core.errors import ComputationError
from litege_core.synth.rigged import (
    RIGGED_VERSION,
    PoseSettings,
    RiggedModel,
    animal_path,
    cached_model,
    finish_mesh,
    pose_model,
)

RIGGED_TEMPLATE_VERSION = f"rigged-template-1-{RIGGED_VERSION}"
DEFAULT_TEMPLATE_VERTICES = 4500


@dataclass(frozen=True)
class SpeciesTemplate:
    """One species' fixed triangulation and where its vertices sit on the subdivided body.

    Attributes:
        vertices: ``(V, 3)`` template vertices (rest pose, centred, unit-area scale).
        faces: ``(F, 3)`` template triangles.
        subdivided_faces: ``(Fs, 3)`` faces of the Loop-subdivided low-poly body.
        triangle: ``(V,)`` subdivided triangle holding each template vertex.
        barycentric: ``(V, 3)`` weights of that triangle's corners (rows sum to 1).
    """

    vertices: NDArray
    faces: NDArray
    subdivided_faces: NDArray
    triangle: NDArray
    barycentric: NDArray

    def transfer(self, subdivided_vertices: NDArray) -> NDArray:
        """``(V, 3)`` template vertices on a posed subdivided body ``(Vs, 3)``."""
        corners = subdivided_vertices[self.subdivided_faces[self.triangle]]
        return np.einsum("vk,vkd->vd", self.barycentric, corners)


def species_template(model: RiggedModel, target_vertices: int) -> SpeciesTemplate:
    """Build the template of ``model`` (step 1 of the module docstring).

    Raises:
        ComputationError: the remeshed rest pose is not a clean closed manifold.
    """
    import trimesh

    from litege_core.synth.meshops import subdivide_loop

    rest = model.rest_vertices()
    rest = rest - rest.mean(axis=0)
    sub_vertices, sub_faces = subdivide_loop(rest, model.mesh.faces)
    vertices, faces = finish_mesh(rest, model.mesh.faces, target_vertices, subdivide=True)
    surface = trimesh.Trimesh(sub_vertices, sub_faces, process=False)
    _, _, triangle = trimesh.proximity.closest_point(surface, vertices)
    triangle = np.asarray(triangle, dtype=np.int64)
    barycentric = trimesh.triangles.points_to_barycentric(
        sub_vertices[sub_faces[triangle]], vertices
    )
    barycentric = np.clip(barycentric, 0.0, None)
    barycentric /= barycentric.sum(axis=1, keepdims=True)
    template = SpeciesTemplate(vertices, faces, sub_faces, triangle, barycentric)
    return SpeciesTemplate(template.transfer(sub_vertices), faces, sub_faces, triangle, barycentric)


@functools.lru_cache(maxsize=16)
def cached_species_template(
    path: str, animal: str, target_vertices: int
) -> tuple[RiggedModel, SpeciesTemplate]:
    """The loaded model and its :func:`species_template`, memoized per process."""
    model = cached_model(path, animal)
    return model, species_template(model, target_vertices)


def posed_species_shape(
    model: RiggedModel, template: SpeciesTemplate, seed: int, settings: PoseSettings
) -> NDArray:
    """``(V, 3)`` template vertices of the pose of ``seed`` (step 2 of the module docstring),
    centred, unit-area scale before the anisotropic body scale.

    Raises:
        ComputationError: the subdivision changed connectivity (never for a closed body).
    """
    from litege_core.synth.meshops import subdivide_loop

    posed, _ = pose_model(model, np.random.default_rng([seed, 0]), settings)
    sub_vertices, sub_faces = subdivide_loop(posed, model.mesh.faces)
    if not np.array_equal(sub_faces, template.subdivided_faces):
        raise ComputationError(f"{model.name} seed {seed}: the subdivision changed connectivity")
    return template.transfer(sub_vertices)


@dataclass(frozen=True)
class RiggedTemplateFactory:
    """The template factory of one rigged species (picklable: build workers reload the model).

    ``generate(animal, seed)`` is a posed shape of the species on its fixed template
    (:func:`posed_species_shape`); ``template()`` is the rest pose on it."""

    root: str
    animal: str
    target_vertices: int = DEFAULT_TEMPLATE_VERTICES
    settings: PoseSettings = field(default_factory=PoseSettings)
    category: str = "rigged-template"

    @property
    def version(self) -> str:
        s = self.settings
        return (
            f"{RIGGED_TEMPLATE_VERSION}-{self.animal}-{self.target_vertices}-"
            f"{s.perturb_degrees}-{s.body_range[0]}-{s.body_range[1]}"
        )

    def _loaded(self) -> tuple[RiggedModel, SpeciesTemplate]:
        path = str(animal_path(self.root, self.animal))
        return cached_species_template(path, self.animal, self.target_vertices)

    def template(self) -> tuple[NDArray, NDArray]:
        _, template = self._loaded()
        return template.vertices, template.faces

    def generate(self, family: str, seed: int) -> NDArray:
        if family != self.animal:
            raise ComputationError(f"the {self.animal} template factory got family {family!r}")
        model, template = self._loaded()
        return posed_species_shape(model, template, seed, self.settings)


__all__ = [
    "DEFAULT_TEMPLATE_VERTICES",
    "RIGGED_TEMPLATE_VERSION",
    "RiggedTemplateFactory",
    "SpeciesTemplate",
    "cached_species_template",
    "posed_species_shape",
    "species_template",
]
