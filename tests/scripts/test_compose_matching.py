"""scripts/compose_matching.py: a matching bundle from the networks of bundles that share their
frame and descriptor, with a chosen frame judge."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from litege_core.errors import InputError
from litege_core.matching import MatchingModel
from litege_core.shape import Shape
from litege_core.synth import families, generate_shape


def test_an_ensemble_of_a_bundle_with_itself_matches_as_the_bundle(compose_matching, tmp_path):
    summary = compose_matching.main(["quadrupeds", "quadrupeds", "--out", str(tmp_path / "e")])
    single, pair = MatchingModel.load("quadrupeds"), MatchingModel.load(summary["out"])
    assert len(pair.bundle.networks) == 2 and pair.content_hash == summary["content_hash"]
    assert [m["model"] for m in pair.bundle.manifest["training"]["ensemble"]] == ["quadrupeds"] * 2
    assert len(pair.bundle.frame_judge_networks) == len(single.bundle.frame_judge_networks)
    shapes = [generate_shape("quadruped", families("quadruped")[k], 2_000_000 + k) for k in (0, 1)]
    meshes = [Shape.from_arrays(s.vertices, s.faces) for s in shapes]
    queries = np.arange(0, len(meshes[0].vertices), 97)
    for model in (single, pair):
        x, y = model.prepare_many(meshes, seed=0)
        found = model.match(x, y, queries).indices
        if model is single:
            expected = found
    np.testing.assert_array_equal(found, expected)  # the mean of two equal networks is one


def test_bundles_with_another_frame_or_descriptor_are_refused(compose_matching, tmp_path):
    with pytest.raises(InputError, match="basis"):
        compose_matching.main(["quadrupeds", "humans", "--out", str(tmp_path / "x")])
    with pytest.raises(InputError, match="two"):
        compose_matching.main(["quadrupeds", "--out", str(tmp_path / "y")])


def test_own_judge_drops_the_judge_networks(compose_matching, tmp_path):
    shipped = MatchingModel.load("quadrupeds").bundle
    assert shipped.judge_networks  # the shipped continuation keeps its start as judge
    summary = compose_matching.main(["quadrupeds", "--judge", "own", "--out", str(tmp_path / "o")])
    own = MatchingModel.load(summary["out"]).bundle
    assert own.judge_networks == () and own.frame_judge_networks == own.networks
    assert own.manifest["training"]["judge"] == "its matching networks"


def test_an_orientation_network_is_added_kept_and_dropped(compose_matching, tmp_path):
    from litege_core.nets import state_to_tensors
    from litege_core.nets.orientation import OrientationNet
    from litege_core.train.orientation import save_orientation

    torch.manual_seed(0)
    net = OrientationNet(grid=8, conv_widths=(4, 8), fc_width=16)
    save_orientation(net, tmp_path / "o.safetensors")
    added = compose_matching.main(
        [
            "quadrupeds",
            "--orientation",
            str(tmp_path / "o.safetensors"),
            "--out",
            str(tmp_path / "a"),
        ]
    )
    bundle = MatchingModel.load(added["out"]).bundle
    assert bundle.orientation is not None and bundle.orientation.config() == net.config()
    for key, value in state_to_tensors(net).items():  # stored in float16
        torch.testing.assert_close(
            state_to_tensors(bundle.orientation)[key], value, atol=2e-3, rtol=0
        )
    assert bundle.judge_networks  # the judge stays, for bundles read without the network
    kept = compose_matching.main([added["out"], added["out"], "--out", str(tmp_path / "k")])
    assert MatchingModel.load(kept["out"]).bundle.orientation is not None
    dropped = compose_matching.main(
        [added["out"], "--orientation", "none", "--out", str(tmp_path / "d")]
    )
    assert MatchingModel.load(dropped["out"]).bundle.orientation is None
