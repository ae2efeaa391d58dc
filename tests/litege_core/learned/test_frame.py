import numpy as np
import pytest
import trimesh
from scipy.spatial import cKDTree

from litege_core.canonical import canonicalize_bbox
from litege_core.errors import InputError
from litege_core.learned import describe_shape, shape_samples
from litege_core.learned.frame import (
    FRAME_CANDIDATES,
    candidate_rotations,
    select_frame,
    select_frames,
    turned_frames,
)
from litege_core.sampling import sample_surface
from litege_core.shape import Shape
from litege_core.variants import random_rotation


def _egg(seed: int) -> Shape:
    """A bent, egg-like blob: no symmetry, so its canonical frame is unique."""
    rng = np.random.default_rng(seed)
    sphere = trimesh.creation.icosphere(subdivisions=3)
    v = np.asarray(sphere.vertices) * [1.6 + rng.uniform(-0.2, 0.2), 1.0, 0.6]
    v[:, 0] *= np.where(v[:, 0] > 0, 1.35, 1.0)  # one long end
    v[:, 1] += 0.35 * v[:, 0] ** 2 * rng.uniform(0.7, 1.3)  # bend
    v[:, 2] += 0.25 * np.clip(v[:, 0], 0, None) * rng.uniform(0.7, 1.3)  # tilt one end
    return Shape.from_arrays(v, sphere.faces)


@pytest.fixture(scope="module")
def basis(fit_toy_basis):
    return fit_toy_basis(_egg)


def _chamfer(a: np.ndarray, b: np.ndarray) -> float:
    """Symmetric mean nearest-neighbour distance after centring both sets (the biased
    samples below move the sample mean, which is the canonical centre)."""
    a, b = a - a.mean(axis=0), b - b.mean(axis=0)
    return float(cKDTree(b).query(a)[0].mean() + cKDTree(a).query(b)[0].mean())


@pytest.mark.parametrize("name, count", [("pca", 1), ("signs", 4), ("all", 24)])
def test_candidates_are_proper_rotations_identity_first(name, count):
    mats = candidate_rotations(name)
    assert len(mats) == count
    np.testing.assert_array_equal(mats[0], np.eye(3))
    for m in mats:
        np.testing.assert_allclose(m @ m.T, np.eye(3), atol=1e-12)
        assert np.linalg.det(m) == pytest.approx(1.0)
    assert len({m.tobytes() for m in mats}) == count


def test_swaps_only_where_eigenvalues_are_close():
    assert len(candidate_rotations("swaps", [1.0, 0.3, 0.1])) == 4
    assert len(candidate_rotations("swaps", [1.0, 0.9, 0.1])) == 8
    assert len(candidate_rotations("swaps", [1.0, 0.9, 0.8])) == 12
    with pytest.raises(InputError):
        candidate_rotations("swaps")
    with pytest.raises(InputError):
        candidate_rotations("mirror")
    assert "signs" in FRAME_CANDIDATES


def test_pca_candidate_reproduces_the_default_description(basis):
    shape = _egg(100)
    default = describe_shape(shape, basis, seed=3)
    choice = select_frame(shape_samples(shape, 2000, 3), basis, candidates="pca")
    assert choice.index == 0 and choice.scores.shape == (1,)
    assert choice.transform.allclose(default.transform)
    np.testing.assert_array_equal(choice.descriptor, default.descriptor)  # bit for bit
    assert choice.residual == pytest.approx(default.residual, rel=1e-6)
    transform, residual, descriptor, scores = choice  # unpacks like a tuple
    assert transform is choice.transform and descriptor is choice.descriptor
    assert residual == choice.residual and scores is choice.scores


def test_turned_frames_describe_each_turn_of_the_pca_frame(basis):
    shape = _egg(104)
    points = shape_samples(shape, 2000, 3)
    turns = np.stack([np.eye(3), random_rotation(1), random_rotation(2)])
    choices = turned_frames(points, basis, turns)
    default = select_frame(points, basis, candidates="pca")
    assert [c.index for c in choices] == [0, 1, 2]
    assert choices[0].transform.allclose(default.transform)
    # Three clouds go through one batched UDF-PCA call: equal to float32 rounding (the BLAS
    # kernel of a batch of 3 may round differently from a batch of 1, CPU by CPU).
    np.testing.assert_allclose(choices[0].descriptor, default.descriptor, rtol=1e-5, atol=1e-7)
    for turn, choice in zip(turns, choices, strict=True):
        np.testing.assert_allclose(
            choice.transform.rotation, turn @ default.transform.rotation, atol=1e-12
        )
        np.testing.assert_allclose(choice.samples, choice.transform.apply(points), atol=1e-9)
        assert choice.residual == choice.scores[choice.index]
    assert choices[1].residual != pytest.approx(choices[0].residual)  # described in its frame
    with pytest.raises(InputError, match="rotations"):
        turned_frames(points, basis, np.eye(3))


def test_a_deliberately_flipped_frame_is_restored(basis):
    shape = _egg(101)
    clean = shape_samples(shape, 2000, 0)
    reference = canonicalize_bbox(clean)
    # Many extra samples on the short (−x) end move the median: the sign rule flips axis 0.
    canonical = reference.apply(shape.vertices)
    faces = np.asarray(shape.faces)
    short_end = faces[(canonical[faces][:, :, 0] < -0.15).all(axis=1)]
    extra = sample_surface(shape.vertices, short_end, 2500, 1).points
    biased = np.concatenate([clean, extra])
    default = canonicalize_bbox(biased)
    # Which sign flip of the biased default frame matches the clean frame (up to the small
    # axis and centre changes the extra density causes)?
    distances = [
        _chamfer((default.apply(shape.vertices)) @ m.T, canonical)
        for m in candidate_rotations("signs")
    ]
    truth = int(np.argmin(distances))
    assert truth != 0 and distances[0] > 2 * distances[truth]  # the default is really flipped
    choice = select_frame(biased, basis, candidates="signs")
    assert choice.index == truth
    assert choice.residual < choice.scores[0]
    np.testing.assert_allclose(
        choice.transform.rotation, candidate_rotations("signs")[truth] @ default.rotation
    )
    # On clean samples the default frame is kept.
    assert select_frame(clean, basis, candidates="signs").index == 0


def test_selection_is_deterministic_batched_and_rotation_invariant(basis):
    shapes = [_egg(s) for s in (102, 103)]
    samples = [shape_samples(s, 1500, 0) for s in shapes]
    batched = select_frames(samples, basis, candidates="all")
    for points, choice in zip(samples, batched, strict=True):
        single = select_frame(points, basis, candidates="all")
        assert single.index == choice.index
        assert single.transform.allclose(choice.transform)
        np.testing.assert_allclose(single.scores, choice.scores, rtol=1e-5)
        assert choice.residual == pytest.approx(float(choice.scores.min()))
    rotation = random_rotation(5)
    moved = 2.0 * samples[0] @ rotation.T + [1.0, -3.0, 0.5]
    again = select_frame(moved, basis, candidates="all")
    assert again.index == batched[0].index
    np.testing.assert_allclose(again.samples, batched[0].samples, atol=1e-8)


def test_margin_keeps_the_default_frame(basis):
    points = shape_samples(_egg(104), 1500, 0)
    choice = select_frame(points, basis, candidates="all", margin=0.999)
    assert choice.index == 0
    assert choice.residual == choice.scores[0]
    with pytest.raises(InputError):
        select_frame(points, basis, margin=1.0)
