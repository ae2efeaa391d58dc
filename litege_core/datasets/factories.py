"""Shape factories that feed the dataset builder: the procedural families of ``synth``."""

from __future__ import annotations

from dataclasses import dataclass

from numpy.typing import NDArray

from litege_core.errors import InputError


@dataclass(frozen=True)
class SynthFactory:
    """Procedural shapes of one ``synth`` category (template triangulation shared)."""

    category: str

    @property
    def version(self) -> str:
        from litege_core.synth import GENERATOR_VERSION

        return GENERATOR_VERSION

    def template(self) -> tuple[NDArray, NDArray]:
        from litege_core.synth import template

        tmpl = template(self.category)
        return tmpl.vertices, tmpl.faces

    def generate(self, family: str, seed: int) -> NDArray:
        from litege_core.synth import generate_shape

        return generate_shape(self.category, family, seed).vertices


def factory_for(category: str) -> SynthFactory:
    """The factory of a ``synth`` category (``"quadruped"`` or ``"biped"``)."""
    from litege_core.synth import CATEGORIES

    if category not in CATEGORIES:
        raise InputError(f"unknown category {category!r}; expected one of {CATEGORIES}")
    return SynthFactory(category)
