"""Posed real animals (rigged glTF) and MakeHuman bodies. They need the train-data directory
(``$LITEGE_TRAIN_DATA`` or ../shared/train-data), which users do not have: skipped without it."""

import dataclasses
import os
from pathlib import Path

import numpy as np
import pytest

from litege_core.synth import makehuman, meshops, rigged
from litege_core.synth.bend import BendSettings

TRAIN_DATA = Path(
    os.environ.get("LITEGE_TRAIN_DATA")
    or Path(__file__).resolve().parents[4] / "shared" / "train-data"
)
pytestmark = pytest.mark.skipif(not TRAIN_DATA.is_dir(), reason="train-data not available")
FAST_ANIMAL = rigged.PoseSettings(vertex_range=(1200, 1400))
FAST_HUMAN = makehuman.HumanSettings(vertex_range=(1500, 1700))


@pytest.fixture(scope="module")
def fox():
    return rigged.cached_model(str(rigged.animal_path(TRAIN_DATA, rigged.KHRONOS_FOX)), "fox")


@pytest.fixture(scope="module")
def human():
    return makehuman.cached_makehuman(str(TRAIN_DATA / "makehuman"))


def test_every_rigged_animal_loads_as_a_closed_body_with_clips():
    for name in rigged.ANIMALS:
        model = rigged.cached_model(str(rigged.animal_path(TRAIN_DATA, name)), name)
        report = meshops.manifold_report(model.mesh.vertices, model.mesh.faces)
        assert report.closed and report.manifold and report.oriented, name
        assert report.components == 1 and report.euler == 2, name
        assert len(model.clips) >= 3 and 0 < model.leg_joints.sum() < model.leg_joints.size
        assert model.free_joints.any() and not (model.free_joints & model.leg_joints).any()
        area = meshops.triangle_area_total(model.rest_vertices(), model.mesh.faces)
        assert area == pytest.approx(1.0, rel=1e-9), name


def test_posed_animals_are_seeded_clean_manifolds(fox):
    vertices, faces, draw = rigged.posed_animal(fox, 5, FAST_ANIMAL)
    again, again_faces, again_draw = rigged.posed_animal(fox, 5, FAST_ANIMAL)
    np.testing.assert_array_equal(vertices, again)
    np.testing.assert_array_equal(faces, again_faces)
    assert draw == again_draw and draw.clip in {c.name for c in fox.clips}
    other, _, _ = rigged.posed_animal(fox, 6, FAST_ANIMAL)
    assert other.shape != vertices.shape or not np.allclose(other, vertices)
    report = meshops.manifold_report(vertices, faces)
    assert report.ok and report.euler == 2
    assert abs(len(vertices) / draw.target_vertices - 1.0) < 0.15
    # the pose keeps roughly unit area (stretches are within ±15 %)
    assert 0.6 < meshops.triangle_area_total(vertices, faces) < 1.6


def test_unperturbed_clip_pose_is_the_clip_keyframe(fox):
    settings = rigged.PoseSettings(perturb_degrees=0.0, body_range=(1.0, 1.0))
    posed, draw = rigged.pose_model(fox, np.random.default_rng(0), settings)
    clip = next(c for c in fox.clips if c.name == draw.clip)
    translation, rotation, scale = rigged.gltf.sample_pose(fox.tree, clip, draw.time)
    local = fox.tree.local_matrices(translation, rotation, scale)
    matrices = rigged.gltf.skin_matrices(fox.tree, fox.mesh, local)
    expected = rigged.gltf.linear_blend_skinning(
        fox.mesh.vertices, fox.mesh.joints, fox.mesh.weights, matrices
    )
    expected = (expected - expected.mean(axis=0)) * fox.scale
    np.testing.assert_allclose(posed, expected, atol=1e-12)


def test_makehuman_rest_pose_and_a_single_bone_rotation(human):
    shaped = makehuman.body_shape(human, 0.5, 0.5, 0.5)
    heads, _ = makehuman.joint_positions(human, shaped)
    rest = shaped[human.body]
    identity = makehuman.bone_matrices(human, heads, {})
    np.testing.assert_allclose(makehuman.skin(human, rest, identity), rest, atol=1e-12)
    bone = human.bone("lowerarm01.L")
    rotation = makehuman._rot([1.0, 0.0, 0.0], 40.0)
    posed = makehuman.skin(
        human, rest, makehuman.bone_matrices(human, heads, {"lowerarm01.L": rotation})
    )
    subtree = {bone}
    for b in range(len(human.bones)):  # parents come first
        if human.parents[b] in subtree:
            subtree.add(b)
    influence = np.asarray(human.weights[:, sorted(subtree)].sum(axis=1)).ravel()
    moved = np.linalg.norm(posed - rest, axis=1) > 1e-12
    np.testing.assert_array_equal(moved, influence > 1e-12)
    rigid = influence > 1 - 1e-9
    assert rigid.sum() > 100  # the hand and forearm move rigidly about the elbow
    expected = (rest[rigid] - heads[bone]) @ rotation.T + heads[bone]
    np.testing.assert_allclose(posed[rigid], expected, atol=1e-9)


def test_makehuman_targets_change_the_body(human):
    female = makehuman.body_shape(human, 0.0, 0.5, 0.5)
    male = makehuman.body_shape(human, 1.0, 0.5, 0.5)
    heavy = makehuman.body_shape(human, 1.0, 0.5, 1.0)
    strong = makehuman.body_shape(human, 1.0, 1.0, 0.5)
    for other in (female, heavy, strong):
        assert np.abs(other - male).max() > 0.1
    # at average muscle and weight only the gender targets act
    only_gender = human.base.copy()
    for name in ("caucasian-male-young",):
        np.add.at(only_gender, human.targets[name][0], human.targets[name][1])
    np.testing.assert_allclose(male, only_gender, atol=1e-12)


def test_corner_factors_interpolate_the_grid():
    assert makehuman.corner_factors(0.0, 1.0) == {
        ("min", "min"): 0.0,
        ("min", "max"): 1.0,
        ("max", "min"): 0.0,
        ("max", "max"): 0.0,
    }
    assert sum(makehuman.corner_factors(0.5, 0.5).values()) == 0.0
    edge = makehuman.corner_factors(0.5, 1.0)  # average muscle, max weight
    assert edge[("min", "max")] == edge[("max", "max")] == 0.5
    assert sum(makehuman.corner_factors(0.75, 0.25).values()) == pytest.approx(0.75)


def test_posed_humans_are_seeded_clean_manifolds(human):
    vertices, faces, draw = makehuman.posed_human(human, 3, FAST_HUMAN)
    again, _, again_draw = makehuman.posed_human(human, 3, FAST_HUMAN)
    np.testing.assert_array_equal(vertices, again)
    assert draw == again_draw
    report = meshops.manifold_report(vertices, faces)
    assert report.ok and report.euler == 2
    extent = np.ptp(vertices, axis=0)
    assert extent.max() > 1.5 * extent.min()  # a body, not a blob


def _toes_forward(vertices: np.ndarray) -> float:
    """Median z of the lowest 3 % of the height (toes) minus that of the band above (ankles)."""
    y = vertices[:, 1]
    height = y.max() - y.min()
    toes = vertices[y < y.min() + 0.03 * height, 2]
    ankles = vertices[(y > y.min() + 0.06 * height) & (y < y.min() + 0.09 * height), 2]
    return float(np.median(toes) - np.median(ankles))


def test_humans_stand_like_the_biped_template(human):
    """The T-Net of configs/tnet-humans-mh.toml trains on both as one canonical frame: +y up,
    facing (toes toward) +z. Posing turns no root bone, so posed bodies keep the rest frame."""
    from litege_core import synth

    template = np.asarray(synth.template("biped").vertices)
    assert _toes_forward(template) > 0.0
    assert np.array_equal(makehuman.FORWARD, [0.0, 0.0, 1.0])
    for gender in (0.0, 1.0):
        rest = makehuman.body_shape(human, gender, 0.5, 0.5)[human.body]
        assert (rest.max(axis=0) - rest.min(axis=0)).argmax() == 1
        assert _toes_forward(rest) > 0.0
    for seed in range(4):
        vertices, _, _ = makehuman.posed_human(human, seed, FAST_HUMAN)
        assert (vertices.max(axis=0) - vertices.min(axis=0)).argmax() == 1  # standing


def _head_forward(vertices: np.ndarray) -> float:
    """Mean z of the top 15 % of the height (head and neck) minus the body's mean z."""
    y = vertices[:, 1]
    top = vertices[y > y.max() - 0.15 * (y.max() - y.min())]
    return float(top[:, 2].mean() - vertices[:, 2].mean())


def test_rigged_animals_stand_like_the_quadruped_template():
    """configs/tnet-quadrupeds-rigged.toml trains the T-Net on both as one canonical frame:
    +y up, +z toward the head, x across the body."""
    from litege_core import synth

    template = np.asarray(synth.template("quadruped").vertices)
    assert _head_forward(template) > 0.0
    for name in (rigged.KHRONOS_FOX, "Horse", "Wolf"):
        model = rigged.cached_model(str(rigged.animal_path(TRAIN_DATA, name)), name)
        vertices, _, _ = rigged.posed_animal(model, 0)
        extent = vertices.max(axis=0) - vertices.min(axis=0)
        assert extent.argmin() == 0  # narrowest across the body
        assert _head_forward(vertices) > 0.0


def test_bent_animals_are_seeded_clean_manifolds_and_default_poses_stay_straight(fox):
    bent_settings = rigged.PoseSettings(
        vertex_range=(1200, 1400), bend=BendSettings(probability=1.0)
    )
    vertices, faces, draw = rigged.posed_animal(fox, 5, bent_settings)
    again, _, again_draw = rigged.posed_animal(fox, 5, bent_settings)
    np.testing.assert_array_equal(vertices, again)
    assert draw.bend is not None and draw.bend == again_draw.bend
    assert meshops.manifold_report(vertices, faces).ok
    straight, _, straight_draw = rigged.posed_animal(fox, 5, FAST_ANIMAL)
    assert straight_draw.bend is None
    assert straight.shape != vertices.shape or not np.allclose(straight, vertices)
    # the bend comes after every other draw: same clip, time and body scale
    assert (straight_draw.clip, straight_draw.time) == (draw.clip, draw.time)
    assert straight_draw.body_scale == draw.body_scale


def test_a_lean_build_thins_the_body_around_the_skeleton_and_keeps_the_head(fox):
    np.testing.assert_array_equal(fox.with_build(1.0), fox.mesh.vertices)
    lean, stocky = fox.with_build(0.6), fox.with_build(1.3)
    moved = np.linalg.norm(lean - fox.mesh.vertices, axis=1)
    head = np.isin(
        fox.mesh.joints[np.arange(len(moved)), fox.mesh.weights.argmax(axis=1)],
        [
            j
            for j, node in enumerate(fox.mesh.joint_nodes)
            if "head" in fox.tree.names[node].lower()
        ],
    )
    assert head.any() and np.median(moved[head]) < 0.2 * np.median(moved[~head])

    def volume(vertices: np.ndarray) -> float:
        return float(np.linalg.det(vertices[fox.mesh.faces]).sum() / 6.0)

    assert volume(lean) < 0.75 * volume(fox.mesh.vertices) < 0.75 * volume(stocky)
    # the build is drawn apart from the pose: same clip, time and body scale
    settings = rigged.PoseSettings(vertex_range=(1200, 1400), girth_std=0.3)
    vertices, faces, draw = rigged.posed_animal(fox, 5, settings)
    assert meshops.manifold_report(vertices, faces).ok and draw.girth != 1.0
    _, _, plain = rigged.posed_animal(fox, 5, FAST_ANIMAL)
    assert (plain.clip, plain.time, plain.body_scale, plain.girth) == (
        draw.clip,
        draw.time,
        draw.body_scale,
        1.0,
    )
    assert "girth0.3" in settings.describe() and "girth" not in FAST_ANIMAL.describe()


def test_the_rigged_factory_version_names_its_pose_settings():
    from litege_core.datasets.factories import RiggedFactory, factory_for, species_factory
    from litege_core.errors import InputError

    default = factory_for("rigged", TRAIN_DATA)
    bent = factory_for(
        "rigged", TRAIN_DATA, rigged.PoseSettings(bend=BendSettings(probability=0.7))
    )
    assert isinstance(bent, RiggedFactory) and default.version == rigged.RIGGED_VERSION
    assert bent.version.startswith(rigged.RIGGED_VERSION + ":") and "p=0.7" in bent.version
    bent_species = species_factory("Fox", TRAIN_DATA, bent.settings)
    assert bent_species.version != species_factory("Fox", TRAIN_DATA).version
    lean = factory_for("rigged", TRAIN_DATA, bent.settings, girth_std=0.3)
    assert lean.settings == dataclasses.replace(bent.settings, girth_std=0.3)
    assert lean.version != bent.version and "girth0.3" in lean.version
    with pytest.raises(InputError, match="rigged animals only"):
        factory_for("quadruped", None, bent.settings)
    with pytest.raises(InputError, match="rigged animals only"):
        species_factory("makehuman", TRAIN_DATA, bent.settings)


def _seed_in(mode: str) -> int:
    from litege_core.synth.poses import steep_pose

    return next(s for s in range(1000) if steep_pose("makehuman", s, 1.0) == mode)


def test_steep_humans_hold_their_poses_and_the_drawn_ones_keep_their_bodies(human):
    from litege_core.synth.poses import MAKEHUMAN_STEEP_MODES, steep_pose

    extents = {}
    for mode in MAKEHUMAN_STEEP_MODES:
        seed = _seed_in(mode)
        vertices, faces, draw = makehuman.posed_human(human, seed, FAST_HUMAN, steep_share=1.0)
        plain, _, plain_draw = makehuman.posed_human(human, seed, FAST_HUMAN)
        assert draw.mode == mode and plain_draw.mode is None
        assert meshops.manifold_report(vertices, faces).ok
        extents[mode] = (np.ptp(vertices, axis=0), np.ptp(plain, axis=0))
        angles = draw.angles
        if mode == "arms_overhead":
            assert min(angles["arm_raise.L"], angles["arm_raise.R"]) >= 120
        elif mode == "leg_lifted":
            assert max(angles["knee.L"], angles["knee.R"]) >= 90
        elif mode == "one_leg_balance":
            assert max(angles["leg_spread.L"], angles["leg_spread.R"]) >= 35
    # hands above the head make the body taller; the forward bend folds it at the hips
    overhead, drawn = extents["arms_overhead"]
    assert overhead[1] > 1.05 * drawn[1]  # a drawn arm (raised ≤ 75°) never tops the head
    bent, drawn = extents["bending_forward"]
    assert bent[1] < 0.7 * drawn[1] and bent[2] > drawn[2]
    # a seed not posed steep at this share is the body of the drawn pose, vertex for vertex
    seed = next(s for s in range(1000) if steep_pose("makehuman", s, 0.4) is None)
    shared, _, _ = makehuman.posed_human(human, seed, FAST_HUMAN, steep_share=0.4)
    np.testing.assert_array_equal(shared, makehuman.posed_human(human, seed, FAST_HUMAN)[0])


def test_steep_angles_refuse_an_unknown_mode():
    from litege_core.errors import InputError

    with pytest.raises(InputError, match="rearing"):
        makehuman.steep_angles("rearing", np.random.default_rng(0))


def test_the_makehuman_factory_names_its_steep_share():
    from litege_core.datasets.factories import MakeHumanFactory, factory_for

    steep = factory_for("makehuman", TRAIN_DATA, steep_share=0.4)
    assert isinstance(steep, MakeHumanFactory) and steep.steep_share == 0.4
    assert steep.version == f"{makehuman.MAKEHUMAN_VERSION}+steep0.4"
    assert factory_for("makehuman", TRAIN_DATA).version == makehuman.MAKEHUMAN_VERSION
