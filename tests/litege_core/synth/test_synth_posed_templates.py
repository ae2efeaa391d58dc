"""Rigged animals and MakeHuman bodies on one fixed triangulation per source model (matching
training data). They need
the train-data directory (``$LITEGE_TRAIN_DATA`` or ../shared/train-data): skipped without it."""

import os
from pathlib import Path

import numpy as np
import pytest

from litege_core.errors import ComputationError
from litege_core.synth import meshops, rigged
from litege_core.synth.posed_templates import (
    MAKEHUMAN,
    MakeHumanTemplateFactory,
    RiggedTemplateFactory,
)

TRAIN_DATA = Path(
    os.environ.get("LITEGE_TRAIN_DATA")
    or Path(__file__).resolve().parents[4] / "shared" / "train-data"
)
pytestmark = pytest.mark.skipif(not TRAIN_DATA.is_dir(), reason="train-data not available")


@pytest.fixture(scope="module")
def fox_factory():
    return RiggedTemplateFactory(str(TRAIN_DATA), rigged.KHRONOS_FOX, target_vertices=1500)


def _edge_lengths(vertices, faces):
    return np.linalg.norm(vertices[faces[:, 0]] - vertices[faces[:, 1]], axis=1)


def test_template_is_a_clean_remeshed_rest_pose(fox_factory):
    vertices, faces = fox_factory.template()
    assert meshops.manifold_report(vertices, faces).ok
    assert abs(len(vertices) / 1500 - 1.0) < 0.15
    # Loop subdivision shrinks the unit-area low-poly body a little
    assert 0.8 < meshops.triangle_area_total(vertices, faces) < 1.05


def test_poses_share_the_template_and_move_every_vertex_with_its_body_part(fox_factory):
    template, faces = fox_factory.template()
    a = fox_factory.generate(rigged.KHRONOS_FOX, 3)
    again = fox_factory.generate(rigged.KHRONOS_FOX, 3)
    b = fox_factory.generate(rigged.KHRONOS_FOX, 4)
    np.testing.assert_array_equal(a, again)  # a pure function of the seed
    assert a.shape == b.shape == template.shape and not np.allclose(a, b)
    rest_edges = _edge_lengths(template, faces)
    for posed in (a, b):
        # skinning stretches joints a little; a vertex read off the wrong body part would
        # stretch its edges many times over
        ratio = _edge_lengths(posed, faces) / rest_edges
        assert np.median(ratio) == pytest.approx(1.0, abs=0.15)
        assert ratio.max() < 6.0
        assert 0.6 < meshops.triangle_area_total(posed, faces) < 1.6


def test_the_rest_pose_read_back_is_the_template(fox_factory):
    model, template = fox_factory._loaded()
    rest = model.rest_vertices()
    again = template.transfer(rest - rest.mean(axis=0), model.mesh.faces)
    np.testing.assert_allclose(again, template.vertices, atol=1e-12)
    with pytest.raises(ComputationError, match="connectivity"):
        template.transfer(rest, model.mesh.faces[:-1])


def test_makehuman_bodies_share_the_template():
    factory = MakeHumanTemplateFactory(str(TRAIN_DATA), target_vertices=2000)
    template, faces = factory.template()
    assert meshops.manifold_report(template, faces).ok
    assert 0.85 < meshops.triangle_area_total(template, faces) < 1.05  # chords of a 2K remesh
    a, b = factory.generate(MAKEHUMAN, 1), factory.generate(MAKEHUMAN, 2)
    np.testing.assert_array_equal(a, factory.generate(MAKEHUMAN, 1))
    assert a.shape == b.shape == template.shape and not np.allclose(a, b)
    for body in (a, b):
        ratio = _edge_lengths(body, faces) / _edge_lengths(template, faces)
        assert np.median(ratio) == pytest.approx(1.0, abs=0.15) and ratio.max() < 6.0
    with pytest.raises(ComputationError, match="family"):
        factory.generate("Wolf", 0)


def test_the_factory_serves_only_its_species(fox_factory):
    with pytest.raises(ComputationError, match="Wolf"):
        fox_factory.generate("Wolf", 0)


def test_cli_builds_one_matching_dataset_per_species(tmp_path, capsys):
    import json

    from litege_core.cli import main as cli_main
    from litege_core.datasets import GeodesicDataset
    from litege_core.train.matching import species_datasets

    out = tmp_path / "species"
    argv = ["data", "build", "--category", "rigged", "--preset", "matching", "--out", str(out)]
    argv += ["--shapes", "train=1,val=1", "--solver", "heat", "--workers", "1"]
    assert cli_main([*argv, "--train-data", str(TRAIN_DATA)]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert list(summary["species"]) == list(rigged.ANIMALS)
    assert [p.name for p in species_datasets(out)] == sorted(rigged.ANIMALS)
    wolf = GeodesicDataset(out / "Wolf")
    train = wolf.load_split("train")
    assert train["vertices"].shape[1] == int(np.asarray(wolf.faces).max()) + 1
    assert train["distances"].shape[1] == wolf.shared_sources.size  # shared sources only
    assert GeodesicDataset(out / "Fox").load_split("val")["vertices"].shape[0] == 1
    missing = ["--train-data", str(tmp_path / "nowhere"), "--out", str(tmp_path / "x")]
    assert cli_main([*argv[:6], *missing]) != 0
    assert "nowhere" in capsys.readouterr().err
    humans = ["data", "build", "--category", "makehuman", "--preset", "matching", *argv[6:]]
    humans[7] = str(tmp_path / "mh")
    assert cli_main([*humans, "--train-data", str(TRAIN_DATA)]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert list(summary["species"]) == [MAKEHUMAN]
    assert [p.name for p in species_datasets(tmp_path / "mh")] == [MAKEHUMAN]
