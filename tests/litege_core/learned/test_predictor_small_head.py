"""``Predictor(bundle, head="small")`` (issue 17): the distilled head read from its sidecar,
checked against the trainable module pair by pair, across the dense and flat code paths, on a
state shared with a full-head predictor, and refused when it belongs to another bundle."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
import torch

from litege_core.errors import ArtifactError, InputError
from litege_core.learned import Predictor, load_bundle, load_shipped, shipped_bundles
from litege_core.learned.bundle import SHIPPED_DIR
from litege_core.learned.small_head import (
    SMALL_HEAD_CONFIG,
    SMALL_HEAD_WEIGHTS,
    load_small_head,
    save_small_head,
)
from litege_core.nets.small_head import SmallHead
from litege_core.synth import families, generate_shape

M, H = 12, 8


def _student(width: int, seed: int = 5) -> SmallHead:
    torch.manual_seed(seed)
    head = SmallHead(width, M, H)
    with torch.no_grad():
        head.bias.normal_(0.0, 0.3)
        head.final.bias.fill_(0.05)
    return head.eval()


@pytest.fixture(scope="module")
def bundle_dir(tmp_path_factory, toy_predictor):
    """A copy of the toy bundle with a small head beside it."""
    directory = tmp_path_factory.mktemp("small-head") / "toy"
    shutil.copytree(toy_predictor.bundle.path, directory)
    bundle = load_bundle(directory)
    save_small_head(
        directory,
        _student(bundle.network.width),
        bundle.content_hash,
        distillation={"steps": 0},
        agreement={"mesh": {"mean": 0.0}},
    )
    return directory


@pytest.fixture(scope="module")
def predictors(bundle_dir):
    bundle = load_bundle(bundle_dir)
    return Predictor(bundle, head="full"), Predictor(bundle, head="small")


@pytest.fixture(scope="module")
def shape(blob):
    return blob(7)


def test_the_sidecar_leaves_the_bundle_hash_alone(bundle_dir, toy_predictor) -> None:
    assert load_bundle(bundle_dir).content_hash == toy_predictor.bundle.content_hash
    config = json.loads((bundle_dir / SMALL_HEAD_CONFIG).read_text())
    assert config["teacher_content_hash"] == toy_predictor.bundle.content_hash
    assert config["head"] == {"width": 32, "features": M, "hidden": H, "output": "abs"}
    assert (bundle_dir / SMALL_HEAD_WEIGHTS).stat().st_size < 10_000


def test_small_head_distances_equal_the_module_pair_by_pair(predictors, shape) -> None:
    full, small = predictors
    assert small.head == "small" and full.head == "full" and "head='small'" in repr(small)
    state = small.register(shape)
    sources, targets = np.array([0, 11, 300]), np.arange(0, shape.n_points, 5)
    distances = small.distances(state, sources, targets)
    head, _ = load_small_head(small.bundle)
    x = torch.tensor(state.canonical_points, dtype=torch.float32)
    with torch.no_grad():
        e = small.folded.embed(x, state.shape_bias)
        out = head(e[sources].repeat_interleave(targets.size, 0), e[targets].repeat(3, 1))
    reference = out.numpy().reshape(3, -1) / small.target_scale
    reference += np.linalg.norm(x[sources][:, None] - x[targets][None], axis=-1)
    reference[sources[:, None] == targets[None, :]] = 0.0
    reference = reference / state.transform.scale
    assert np.isfinite(distances).all()
    np.testing.assert_allclose(distances, reference, rtol=1e-4, atol=1e-6)


def test_dense_and_flat_paths_agree_with_a_zero_diagonal(predictors, shape) -> None:
    _, small = predictors
    state = small.register(shape)
    sources = np.array([0, 5, 99])
    dense = small.distances(state, sources)  # 3 × N ≥ DENSE_MIN_PAIRS: broadcast, tiled
    picked = np.array([0, 4, 5, 99, 200])
    flat = small.distances(state, sources, picked)  # 15 pairs: the flat group
    np.testing.assert_allclose(flat, dense[:, picked], rtol=1e-5, atol=1e-6)
    many = small.distances_many([state, state], [sources, [4]], [picked, None])
    np.testing.assert_allclose(many[0], flat, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(many[1][0], small.distance_field(state, 4), rtol=1e-5, atol=1e-6)
    matrix = small.distances(state, picked, picked)
    assert np.all(np.diag(matrix) == 0) and np.all(matrix[~np.eye(5, dtype=bool)] > 0)


def test_one_state_serves_both_heads_with_separate_tables(predictors, shape) -> None:
    full, small = predictors
    state = full.register(shape)
    before = full.distances(state, [3])
    assert state.feature_table is not None and state.feature_table.shape[1] == 64
    size = state.nbytes
    small_field = small.distances(state, [3])  # builds the small table beside the full one
    assert small.point_table(state).shape == (shape.n_points, M)
    assert state.feature_table.shape[1] == 64 and state.nbytes == size + shape.n_points * M * 4
    np.testing.assert_allclose(full.distances(state, [3]), before, rtol=1e-6, atol=1e-7)
    fresh = small.register(shape)
    np.testing.assert_allclose(small.distances(fresh, [3]), small_field, rtol=1e-6, atol=1e-7)
    assert not np.allclose(small_field, before)  # a different head, not the cached table


def test_paths_follow_the_small_head(predictors, shape) -> None:
    _, small = predictors
    state = small.register(shape)
    path = small.path(state, 0, 300)
    assert path.converged and np.isfinite(path.points).all()
    assert path.predicted_distance == pytest.approx(
        float(small.distances(state, [0], [300])[0, 0]), rel=1e-5
    )


def test_a_head_of_another_bundle_is_refused(tmp_path, bundle_dir) -> None:
    directory = tmp_path / "other"
    shutil.copytree(bundle_dir, directory)
    bundle = load_bundle(directory)
    save_small_head(directory, _student(32), "f" * 64)
    with pytest.raises(InputError, match="distilled from bundle ffffffffffff"):
        Predictor(bundle, head="small")
    with pytest.raises(InputError, match="distilled from bundle ffffffffffff"):
        Predictor(bundle)  # the default takes the sidecar it finds, so it is refused too
    Predictor(bundle, head="full")  # the full head is unaffected


def test_the_default_head_is_the_small_one_where_the_bundle_ships_it(
    bundle_dir, toy_predictor
) -> None:
    from litege_core.cli.common import HEAD_CHOICES
    from litege_core.learned.manifest import HEAD_CHOICES as LIBRARY_HEADS

    assert HEAD_CHOICES == LIBRARY_HEADS
    assert Predictor(load_bundle(bundle_dir)).head == "small"
    assert Predictor(load_bundle(bundle_dir), head="auto").head == "small"
    assert Predictor(toy_predictor.bundle).head == "full"  # no sidecar: the trained head
    for name in shipped_bundles():
        assert Predictor(load_shipped(name)).head == "small"


def test_missing_or_damaged_sidecars(tmp_path, bundle_dir, toy_predictor) -> None:
    with pytest.raises(InputError, match="has no small head"):
        Predictor(toy_predictor.bundle, head="small")
    with pytest.raises(InputError, match="head must be one of"):
        Predictor(toy_predictor.bundle, head="tiny")
    directory = tmp_path / "damaged"
    shutil.copytree(bundle_dir, directory)
    weights = directory / SMALL_HEAD_WEIGHTS
    weights.write_bytes(weights.read_bytes()[:-4] + b"\0\0\0\0")
    with pytest.raises(ArtifactError, match="does not match its hash"):
        Predictor(load_bundle(directory), head="small")
    (directory / SMALL_HEAD_CONFIG).write_text("{not json")
    with pytest.raises(ArtifactError, match="not valid JSON"):
        Predictor(load_bundle(directory), head="small")


def test_an_unsaved_student_module_is_taken_as_is(predictors, shape) -> None:
    full, small = predictors
    head, _ = load_small_head(small.bundle)
    direct = Predictor(full.bundle, head=head)
    state = full.register(shape)
    np.testing.assert_allclose(
        direct.distances(state, [1, 2]), small.distances(state, [1, 2]), rtol=1e-6, atol=1e-7
    )
    with pytest.raises(InputError, match="does not fit"):
        Predictor(full.bundle, head=SmallHead(16, M, H))


SHIPPED_WITH_HEAD = [
    name for name in shipped_bundles() if (SHIPPED_DIR / name / SMALL_HEAD_CONFIG).is_file()
]
CATEGORY = {"quadrupeds": "quadruped", "humans": "biped"}


@pytest.mark.parametrize("name", SHIPPED_WITH_HEAD)
def test_shipped_small_heads_load_and_agree_with_their_teacher(name) -> None:
    for filename in (SMALL_HEAD_CONFIG, SMALL_HEAD_WEIGHTS):
        assert (SHIPPED_DIR / name / filename).stat().st_size < 1_000_000
    bundle = load_shipped(name)
    full, small = Predictor(bundle), Predictor(bundle, head="small")
    assert small.small_head_config is not None
    assert small.small_head_config["teacher_content_hash"] == bundle.content_hash
    generated = generate_shape(CATEGORY[name], families(CATEGORY[name])[2], 2_000_321)
    shape = generated.to_shape()
    state = full.register(shape)
    sources = np.arange(0, shape.n_points, shape.n_points // 6)[:6]
    reference = full.distances(state, sources)
    gap = np.abs(small.distances(state, sources) - reference).mean() / reference.mean() * 100
    assert gap < 3.0  # quadrupeds: measured 1.55 on this horse (×100 units; pooled 0.87)
