import numpy as np
import pytest
import trimesh

from litege_core.evaluation.diagnose import (
    BIPED_REGIONS,
    QUADRUPED_REGIONS,
    UNLABELLED,
    biped_tip_regions,
    density_stats,
    fill_unlabelled,
    pca_stats,
    per_vertex_error,
    spearman,
    synthetic_regions,
    transfer_labels,
    vertex_areas,
)


@pytest.fixture(scope="module")
def sphere():
    mesh = trimesh.creation.icosphere(subdivisions=2)
    return np.asarray(mesh.vertices), np.asarray(mesh.faces)


def test_vertex_areas_and_density(sphere):
    v, f = sphere
    assert vertex_areas(v, f).sum() == pytest.approx(trimesh.Trimesh(v, f).area)
    stats = density_stats(v, f)
    assert stats["area_cv"] < 0.2 and 40 < stats["min_angle"] < 60
    squashed = v * [1.0, 1.0, 0.2]
    assert density_stats(squashed, f)["min_angle"] < stats["min_angle"]


def test_pca_stats_of_an_ellipsoid(sphere):
    v, _ = sphere
    stats = pca_stats(v * [3.0, 2.0, 1.0])
    assert stats["lam1_lam0"] == pytest.approx(4 / 9, rel=0.05)
    assert stats["lam2_lam1"] == pytest.approx(1 / 4, rel=0.05)
    assert stats["median_margin0"] < 0.1  # symmetric: the sign rule has no margin


def test_labels_transfer_through_a_correspondence(sphere):
    v, f = sphere
    labels = (v[:, 0] > 0).astype(np.int64)
    perm = np.random.default_rng(0).permutation(len(v))  # target vertex perm[i] = ref vertex i
    rows = np.arange(len(v))[::2]  # only half the vertices have a correspondence
    out = transfer_labels(labels, rows, perm[rows], perm[f], len(v))
    assert (out != UNLABELLED).all()
    agree = (out[perm] == labels).mean()
    assert agree > 0.9


def test_fill_unlabelled_uses_the_nearest_labelled_vertex():
    faces = np.array([[k, k + 1, k + 2] for k in range(6)])  # a triangle strip 0…7
    labels = np.full(8, UNLABELLED)
    labels[0], labels[7] = 5, 7
    filled = fill_unlabelled(labels, faces)
    assert filled[[0, 1, 2]].tolist() == [5, 5, 5] and filled[[5, 6, 7]].tolist() == [7, 7, 7]
    assert (filled != UNLABELLED).all()


def test_per_vertex_error_and_spearman():
    truth = np.array([[0.0, 1.0, 2.0], [1.0, 0.0, 2.0]])
    pred = truth + np.array([[0.5, 0.1, 0.2], [0.1, 0.5, 0.4]])
    err = per_vertex_error(pred, truth, norm=1.0)
    np.testing.assert_allclose(err, [10.0, 10.0, 30.0])  # zero pairs excluded
    rho, p = spearman([1, 2, 3, 4, 5], [2, 4, 6, 8, 11])
    assert rho == pytest.approx(1.0) and p < 0.05
    assert np.isnan(spearman([1, 2, 3], [1, 2, 3])[0])  # too few points


def test_synthetic_regions_cover_the_vocabulary():
    for category, names in (("quadruped", QUADRUPED_REGIONS), ("biped", BIPED_REGIONS)):
        labels, got = synthetic_regions(category)
        assert got == names
        assert set(np.unique(labels)) == set(range(len(names)))


def test_biped_tip_regions_on_a_procedural_human():
    from litege_core import synth

    shape = synth.generate_shape("biped", "average", 2_000_000)
    faces = synth.template("biped").faces
    labels = biped_tip_regions(shape.vertices, faces)
    truth, _ = synthetic_regions("biped")
    # The automatic labels agree with the template's parts on most vertices.
    assert (labels == truth).mean() > 0.7
