"""T-Net weights files: round trips, warm starts, refusals, one cloud's predicted rotation."""

import numpy as np
import pytest
import torch

import litege_core.train.tnet as tnet_module
from litege_core.errors import ArtifactError, InputError
from litege_core.nets import TNet, state_to_tensors
from litege_core.sampling import sample_surface
from litege_core.train.tnet import (
    PREDICT_MAX_POINTS,
    load_tnet,
    predict_rotation,
    read_tnet_metadata,
    save_tnet,
    train_tnet,
)
from tests.litege_core.train.tnet.conftest import tiny_config


def test_checkpoint_round_trip(tmp_path) -> None:
    torch.manual_seed(0)
    net = TNet((8, 16), (8,), prealign="pca").train()
    net(torch.randn(4, 30, 3))  # BatchNorm statistics move
    net.eval()
    path = tmp_path / "w" / "tnet.safetensors"
    save_tnet(net, path, {"note": "x"})
    loaded = load_tnet(path, "cpu")
    expected, got = state_to_tensors(net), state_to_tensors(loaded)
    assert set(expected) == set(got) and all(torch.equal(expected[k], got[k]) for k in expected)
    cloud = torch.randn(2, 40, 3)
    with torch.no_grad():
        torch.testing.assert_close(loaded(cloud), net(cloud), rtol=0, atol=0)
    assert read_tnet_metadata(path)["training"] == {"note": "x"}
    assert loaded.prealign == "pca"
    with torch.no_grad():
        torch.testing.assert_close(loaded.rotation(cloud), net.rotation(cloud), rtol=0, atol=0)


def test_init_starts_from_a_weights_file_or_a_matching_bundle(toy_shapes, tmp_path) -> None:
    train, val = toy_shapes
    torch.manual_seed(3)
    source = TNet((8, 16), (8,)).eval()
    save_tnet(source, tmp_path / "start.safetensors")
    expected = state_to_tensors(source)
    net = TNet((8, 16), (8,))
    tnet_module.start_from(net, tmp_path / "start.safetensors")
    assert all(torch.equal(state_to_tensors(net)[k], v) for k, v in expected.items())

    # a run with init validates the started network first: with a zero learning rate the
    # weights (BatchNorm statistics aside) stay the source's
    config = tiny_config(
        tmp_path, train={"init": str(tmp_path / "start.safetensors"), "lr": 1e-12, "eta_min": 1e-12}
    )
    result = train_tnet(config, train_shapes=train, val_shapes=val, make_report=False)
    trained = state_to_tensors(result.net)
    weights = [k for k in expected if k.endswith("weight") and expected[k].ndim > 1]
    assert weights and all(torch.allclose(trained[k], expected[k], atol=1e-6) for k in weights)
    cold = train_tnet(tiny_config(tmp_path), train_shapes=train, val_shapes=val, make_report=False)
    assert not all(torch.equal(state_to_tensors(cold.net)[k], expected[k]) for k in weights)

    bundle_tnet = TNet((64, 128, 256), (256, 128), prealign="pca")
    tnet_module.start_from(bundle_tnet, "quadrupeds")  # the shipped matching bundle's T-Net
    from litege_core.matching import MatchingModel

    shipped = state_to_tensors(MatchingModel.load("quadrupeds").bundle.tnet)
    got = state_to_tensors(bundle_tnet)
    assert all(torch.allclose(got[k], shipped[k].to(got[k].dtype)) for k in shipped)


def test_init_refuses_other_widths_and_unknown_names(tmp_path) -> None:
    save_tnet(TNet((8, 16), (8,)), tmp_path / "start.safetensors")
    with pytest.raises(InputError, match="set \\[network\\] to match"):
        tnet_module.start_from(TNet((8, 32), (8,)), tmp_path / "start.safetensors")
    with pytest.raises(InputError, match="set \\[network\\] to match"):
        tnet_module.start_from(TNet((8, 16), (8,), prealign="pca"), tmp_path / "start.safetensors")
    with pytest.raises(InputError, match="unknown matching model"):
        tnet_module.start_from(TNet((8, 16), (8,)), tmp_path / "missing.safetensors")


def test_load_tnet_refuses_foreign_files(tmp_path) -> None:
    from safetensors.torch import save_file

    foreign = tmp_path / "foreign.safetensors"
    save_file({"x": torch.zeros(2)}, str(foreign))
    with pytest.raises(ArtifactError):
        load_tnet(foreign)
    garbage = tmp_path / "garbage.safetensors"
    garbage.write_bytes(b"not a safetensors file")
    with pytest.raises(ArtifactError):
        load_tnet(garbage)


def test_predict_rotation(toy_shapes) -> None:
    torch.manual_seed(0)
    net = TNet((8, 16), (8,)).train()
    train, _ = toy_shapes
    rng = np.random.default_rng(0)
    cloud = sample_surface(train.vertices[0], train.faces[0], 3000, rng).points
    R = predict_rotation(net, cloud)
    assert R.shape == (3, 3) and R.dtype == np.float64
    np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-5)
    assert net.training  # mode restored
    np.testing.assert_array_equal(predict_rotation(net, cloud), R)  # deterministic subsample
    np.testing.assert_allclose(
        predict_rotation(net, cloud + np.array([0.3, -1.0, 2.0])), R, atol=1e-5
    )
    # Equal to the eval-mode network on the documented subset, centred.
    keep = np.sort(np.random.default_rng(0).choice(3000, PREDICT_MAX_POINTS, replace=False))
    subset = cloud[keep] - cloud[keep].mean(axis=0)
    net.eval()
    with torch.no_grad():
        direct = net.rotation(torch.as_tensor(subset, dtype=torch.float32)[None])[0]
    np.testing.assert_allclose(R, direct.double().numpy(), atol=1e-6)
    small = cloud[:500]
    assert predict_rotation(net, small).shape == (3, 3)
