"""Procedural quadruped and biped shape families with shared triangulations.

Public API::

    from litege_core import synth
    shape = synth.generate_shape("quadruped", "horse", seed=7)   # GeneratedShape
    synth.template("biped")            # Template: vertices, faces, weights, skeleton, symmetry
    synth.families("quadruped")        # ("cat", "dog", "horse", "cow", "hippo")
    synth.symmetry_map("quadruped")    # (V,) left-right vertex map
    synth.pose_modes("biped")          # ("standing", "walking", "arms_raised", "crouching")

A shape is a pure function of ``(category, family, seed)`` (and the optional pose mode);
all shapes of a category share the template's faces, so vertex ``i`` corresponds across them.
"""

from litege_core.synth.generate import (
    GeneratedShape,
    families,
    generate_shape,
    pose_modes,
    symmetry_map,
)
from litege_core.synth.templates import CATEGORIES, GENERATOR_VERSION, Template, template

__all__ = [
    "CATEGORIES",
    "GENERATOR_VERSION",
    "GeneratedShape",
    "Template",
    "families",
    "generate_shape",
    "pose_modes",
    "symmetry_map",
    "template",
]
