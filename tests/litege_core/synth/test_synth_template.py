"""Template validity: closed, manifold, genus 0, symmetric, ~3.9K uniform triangles."""

import numpy as np
import pytest

from litege_core import synth
from litege_core.errors import InputError
from litege_core.synth import quality, templates

CATEGORIES = ("quadruped", "biped")


@pytest.mark.parametrize("category", CATEGORIES)
def test_template_is_closed_genus0_manifold(category: str) -> None:
    tmpl = synth.template(category)
    assert quality.is_closed_manifold(tmpl.faces)
    assert quality.euler_characteristic(tmpl.faces) == 2
    assert len(np.unique(tmpl.faces)) == len(tmpl.vertices)
    assert 3700 <= len(tmpl.vertices) <= 4100
    assert len(tmpl.faces) == 2 * len(tmpl.vertices) - 4


@pytest.mark.parametrize("category", CATEGORIES)
def test_template_is_outward_oriented(category: str) -> None:
    tmpl = synth.template(category)
    p = tmpl.vertices[tmpl.faces]
    signed_volume = np.einsum("ij,ij->i", p[:, 0], np.cross(p[:, 1], p[:, 2])).sum() / 6.0
    assert signed_volume > 0


@pytest.mark.parametrize("category", CATEGORIES)
def test_symmetry_map_mirrors_vertices_and_faces(category: str) -> None:
    tmpl = synth.template(category)
    sym = synth.symmetry_map(category)
    assert np.array_equal(sym[sym], np.arange(len(sym)))
    mirrored = tmpl.vertices * np.array([-1.0, 1.0, 1.0])
    assert np.abs(tmpl.vertices[sym] - mirrored).max() < 1e-9
    # The mirror of every face (reversed for orientation) is a face.
    faces = {tuple(np.roll(f, -int(np.argmin(f)))) for f in tmpl.faces.tolist()}
    for f in sym[tmpl.faces][:, ::-1].tolist():
        assert tuple(np.roll(f, -int(np.argmin(f)))) in faces


@pytest.mark.parametrize("category", CATEGORIES)
def test_template_triangles_are_fairly_uniform(category: str) -> None:
    tmpl = synth.template(category)
    report = quality.mesh_report(tmpl.vertices, tmpl.faces)
    assert report["min_angle"] > 10.0
    assert report["mean_min_angle"] > 50.0
    assert report["aspect_p99"] < 2.5
    assert report["edge_cv"] < 0.2


def test_template_build_is_deterministic() -> None:
    """A fresh build (no cache) reproduces the cached template exactly."""
    vertices, faces, symmetry = templates.rebuild("quadruped")
    tmpl = synth.template("quadruped")
    assert np.array_equal(faces, tmpl.faces)
    assert np.array_equal(symmetry, tmpl.symmetry)
    assert np.array_equal(vertices, tmpl.vertices)


def test_unknown_category_is_an_input_error() -> None:
    with pytest.raises(InputError):
        synth.template("octopus")
    with pytest.raises(InputError):
        synth.families("octopus")


def test_quadruped_skeleton_follows_smal_pattern() -> None:
    skel = synth.template("quadruped").skeleton
    assert 30 <= skel.n_joints <= 36
    assert sum(n.startswith("tail") for n in skel.names) == 7
    for leg in ("shoulder", "elbow", "wrist", "fpaw", "hip", "knee", "ankle", "hpaw"):
        assert f"{leg}_l" in skel.names and f"{leg}_r" in skel.names
    assert {"jaw", "head", "neck1", "neck2"} <= set(skel.names)
    assert np.allclose(skel.positions[skel.mirror] * [-1, 1, 1], skel.positions)


def test_biped_skeleton_has_limbs_hands_feet() -> None:
    skel = synth.template("biped").skeleton
    for joint in ("shoulder", "elbow", "wrist", "hand", "hip", "knee", "ankle", "foot"):
        assert f"{joint}_l" in skel.names and f"{joint}_r" in skel.names
    assert "head" in skel.names
