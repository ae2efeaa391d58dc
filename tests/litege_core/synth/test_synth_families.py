"""Shape families: determinism, shared triangulation, proportions, non-isometry."""

import numpy as np
import pytest

from litege_core import synth
from litege_core.errors import InputError
from litege_core.seams import unique_edges
from litege_core.synth import quality, shape_space


def test_families_are_listed() -> None:
    assert synth.families("quadruped") == ("cat", "dog", "horse", "cow", "hippo")
    assert len(synth.families("biped")) >= 3
    for category in ("quadruped", "biped"):
        assert 10 <= len(shape_space.FACTORS[category]) <= 20


@pytest.mark.parametrize(("category", "family"), [("quadruped", "horse"), ("biped", "heavy")])
def test_same_seed_same_shape_other_seed_other_shape(category: str, family: str) -> None:
    a = synth.generate_shape(category, family, 3, reject=False)
    b = synth.generate_shape(category, family, 3, reject=False)
    c = synth.generate_shape(category, family, 4, reject=False)
    assert np.array_equal(a.vertices, b.vertices)
    assert a.params == b.params and a.pose == b.pose
    assert not np.allclose(a.vertices, c.vertices)
    assert a.vertices.dtype == np.float64 and a.faces.dtype == np.int64


@pytest.mark.parametrize("category", ["quadruped", "biped"])
def test_all_shapes_share_the_template_triangulation(category: str) -> None:
    tmpl = synth.template(category)
    for i, family in enumerate(synth.families(category)):
        shape = synth.generate_shape(category, family, i, reject=False)
        assert np.array_equal(shape.faces, tmpl.faces)
        assert shape.vertices.shape == tmpl.vertices.shape
        assert np.isfinite(shape.vertices).all()
        assert shape.vertices[:, 1].min() == pytest.approx(0.0, abs=1e-12)


# Design proportions (L = trunk length): (measure, family, target, relative tolerance).
PROPORTIONS = [
    ("front_leg", "cat", 0.65, 0.1),
    ("tail", "cat", 0.9, 0.15),
    ("front_leg", "dog", 0.75, 0.1),
    ("front_leg", "horse", 1.05, 0.1),
    ("neck", "horse", 0.6, 0.15),
    ("trunk_radius", "cow", 0.3, 0.15),
    ("front_leg", "hippo", 0.35, 0.15),
    ("trunk_radius", "hippo", 0.38, 0.15),
]


@pytest.mark.parametrize(("measure", "family", "target", "tolerance"), PROPORTIONS)
def test_family_means_have_design_proportions(measure, family, target, tolerance) -> None:
    tmpl = synth.template("quadruped")
    shape = synth.generate_shape("quadruped", family, 0, mean_shape=True, rest_pose=True)
    props = shape_space.quadruped_proportions(
        shape.vertices, shape.joints, tmpl.skeleton, tmpl.parts
    )
    assert props[measure] == pytest.approx(target, rel=tolerance)


def test_relative_family_traits() -> None:
    tmpl = synth.template("quadruped")
    props = {}
    for family in synth.families("quadruped"):
        shape = synth.generate_shape("quadruped", family, 0, mean_shape=True, rest_pose=True)
        props[family] = shape_space.quadruped_proportions(
            shape.vertices, shape.joints, tmpl.skeleton, tmpl.parts
        )
    assert props["hippo"]["head"] > props["dog"]["head"] > props["cat"]["head"]
    assert props["hippo"]["tail"] < 0.4 < props["cat"]["tail"]
    assert props["horse"]["neck"] > props["dog"]["neck"] > props["cow"]["neck"]


def _edge_log_ratio(a: np.ndarray, b: np.ndarray, faces: np.ndarray) -> np.ndarray:
    edges, _ = unique_edges(faces)
    ua, ub = quality.unit_area(a, faces), quality.unit_area(b, faces)
    la = np.linalg.norm(ua[edges[:, 0]] - ua[edges[:, 1]], axis=1)
    lb = np.linalg.norm(ub[edges[:, 0]] - ub[edges[:, 1]], axis=1)
    return np.log(la / lb)


def test_variation_is_not_isometric() -> None:
    """After unit-area scaling, edge lengths differ substantially between families and
    between individuals of one family (an isometry would keep all of them)."""
    faces = synth.template("quadruped").faces
    cat = synth.generate_shape("quadruped", "cat", 1, rest_pose=True)
    hippo = synth.generate_shape("quadruped", "hippo", 1, rest_pose=True)
    assert np.std(_edge_log_ratio(cat.vertices, hippo.vertices, faces)) > 0.2
    dog1 = synth.generate_shape("quadruped", "dog", 1, rest_pose=True)
    dog2 = synth.generate_shape("quadruped", "dog", 2, rest_pose=True)
    assert np.std(_edge_log_ratio(dog1.vertices, dog2.vertices, faces)) > 0.02
    people = [synth.generate_shape("biped", f, 1, rest_pose=True) for f in ("slim", "heavy")]
    biped_faces = synth.template("biped").faces
    ratio = _edge_log_ratio(people[0].vertices, people[1].vertices, biped_faces)
    assert np.std(ratio) > 0.05


def test_spread_widens_the_proportions_and_keeps_the_pose() -> None:
    """``spread`` scales every factor's log deviation from the family mean by the same draw;
    1 is the family's own range, and the pose drawn from the seed does not change."""
    means = shape_space.mean_factors("quadruped", "dog")
    for seed in range(4):
        plain = synth.generate_shape("quadruped", "dog", seed)
        wide = synth.generate_shape("quadruped", "dog", seed, spread=3.0)
        assert wide.pose == plain.pose
        for factor, mean in means.items():
            np.testing.assert_allclose(
                np.log(wide.params[factor] / mean), 3.0 * np.log(plain.params[factor] / mean)
            )
    same = synth.generate_shape("quadruped", "dog", 1, spread=1.0)
    np.testing.assert_array_equal(
        same.vertices, synth.generate_shape("quadruped", "dog", 1).vertices
    )
    with pytest.raises(InputError):
        synth.generate_shape("quadruped", "dog", 1, spread=0.0)


def test_girth_scales_the_girth_factors_together_and_keeps_the_rest() -> None:
    """A shape's build multiplies exactly the girth factors, comes from its own stream (the
    other factors and the pose mode stay), lies in [exp(-2.5 s), exp(s)] and thins the body."""
    from litege_core.synth.generate import girth_multiplier

    for category, girth_factors in shape_space.GIRTH_FACTORS.items():
        assert set(girth_factors) <= set(shape_space.FACTORS[category])
    girths = [girth_multiplier("quadruped", "dog", seed, 0.3) for seed in range(200)]
    assert np.exp(-0.75) - 1e-12 <= min(girths) < 0.8 and 1.2 < max(girths) <= np.exp(0.3)
    assert girth_multiplier("quadruped", "dog", 5, 0.0) == 1.0
    seed = int(np.argmin(girths))
    plain = synth.generate_shape("quadruped", "dog", seed, spread=3.0)
    lean = synth.generate_shape("quadruped", "dog", seed, spread=3.0, girth_std=0.3)
    assert lean.pose == plain.pose
    for factor in shape_space.FACTORS["quadruped"]:  # pose_attempts may differ: rejection
        value = plain.params[factor]
        ratio = girths[seed] if factor in shape_space.GIRTH_FACTORS["quadruped"] else 1.0
        assert lean.params[factor] == pytest.approx(value * ratio)

    def unit_area_volume(vertices: np.ndarray) -> float:
        corners = quality.unit_area(vertices, lean.faces)[lean.faces]
        return float(np.linalg.det(corners).sum() / 6.0)

    assert unit_area_volume(lean.vertices) < 0.9 * unit_area_volume(plain.vertices)
    with pytest.raises(InputError):
        girth_multiplier("quadruped", "dog", 1, -0.1)


def test_bad_arguments_are_input_errors() -> None:
    with pytest.raises(InputError):
        synth.generate_shape("quadruped", "unicorn", 0)
    with pytest.raises(InputError):
        synth.generate_shape("quadruped", "dog", -1)
    with pytest.raises(InputError):
        synth.generate_shape("biped", "average", 0, pose="sitting")
