"""Weights as flat tensor dicts: round trip (also through safetensors) and strict loading."""

from pathlib import Path

import pytest
import torch
from safetensors.torch import load_file, save_file

from litege_core.errors import ArtifactError
from litege_core.nets import GeodesicNet, TNet, load_state, state_to_tensors


def trained_like(seed: int = 0) -> GeodesicNet:
    torch.manual_seed(seed)
    net = GeodesicNet(16, 11)
    net.set_coord_normalization([0.1, -0.2, 0.0], [0.3, 0.2, 0.08])
    net.train()
    net(torch.randn(8, 3), torch.randn(8, 3), torch.randn(8, 11))  # moves the BN statistics
    return net.eval()


def test_round_trip_through_safetensors(tmp_path: Path) -> None:
    net = trained_like()
    tensors = state_to_tensors(net)
    assert set(tensors) == set(net.state_dict())
    assert {"coord_mean", "coord_std", "mlp_coord.1.running_mean"} <= set(tensors)
    assert all(t.device.type == "cpu" and t.is_contiguous() for t in tensors.values())
    save_file(tensors, tmp_path / "net.safetensors")

    fresh = GeodesicNet(16, 11).eval()
    load_state(fresh, load_file(tmp_path / "net.safetensors"))
    src, dst, desc = torch.randn(5, 3), torch.randn(5, 3), torch.randn(5, 11)
    with torch.no_grad():
        torch.testing.assert_close(fresh(src, dst, desc), net(src, dst, desc), rtol=0, atol=0)
    torch.testing.assert_close(fresh.coord_std, net.coord_std)


def test_state_is_a_copy() -> None:
    net = trained_like()
    tensors = state_to_tensors(net)
    tensors["final_linear.bias"].add_(1.0)
    assert not torch.equal(tensors["final_linear.bias"], net.final_linear.bias.detach())


def test_float16_storage_is_cast_to_the_module_dtype() -> None:
    net = trained_like()
    half = {k: (v.half() if v.is_floating_point() else v) for k, v in state_to_tensors(net).items()}
    fresh = GeodesicNet(16, 11)
    load_state(fresh, half)
    assert fresh.final_linear.weight.dtype == torch.float32
    torch.testing.assert_close(fresh.final_linear.weight, net.final_linear.weight.half().float())


def test_tnet_round_trip() -> None:
    torch.manual_seed(0)
    net = TNet().eval()
    fresh = TNet().eval()
    load_state(fresh, state_to_tensors(net))
    cloud = torch.randn(1, 40, 3)
    with torch.no_grad():
        torch.testing.assert_close(fresh(cloud), net(cloud), rtol=0, atol=0)


def test_mismatches_name_the_keys() -> None:
    tensors = state_to_tensors(trained_like())
    target = GeodesicNet(16, 11)

    missing = dict(tensors)
    del missing["coord_std"]
    with pytest.raises(ArtifactError, match="missing: coord_std") as info:
        load_state(target, missing)
    assert info.value.details["missing"] == ["coord_std"]

    extra = {**tensors, "surprise.weight": torch.zeros(2)}
    with pytest.raises(ArtifactError, match=r"unexpected: surprise\.weight") as info:
        load_state(target, extra)
    assert info.value.details["unexpected"] == ["surprise.weight"]

    with pytest.raises(ArtifactError, match=r"mis-shaped: mlp_pca\.0\.weight") as info:
        load_state(GeodesicNet(16, 12), tensors)
    assert info.value.details["mis_shaped"] == ["mlp_pca.0.weight (16, 11) (expected (16, 12))"]

    with pytest.raises(ArtifactError):
        load_state(GeodesicNet(32, 11), tensors)  # a different width: many keys mis-shaped


def test_corrupt_values_are_artifact_errors() -> None:
    tensors = state_to_tensors(trained_like())
    target = GeodesicNet(16, 11)
    before = state_to_tensors(target)
    with pytest.raises(ArtifactError, match="NaN"):
        load_state(target, {**tensors, "coord_std": torch.tensor([1.0, float("nan"), 1.0])})
    with pytest.raises(ArtifactError, match="not tensors"):
        load_state(target, {**tensors, "coord_std": [1.0, 1.0, 1.0]})  # type: ignore[dict-item]
    with pytest.raises(ArtifactError, match="dtype"):
        load_state(target, {**tensors, "mlp_coord.1.num_batches_tracked": torch.tensor(1.5)})
    for key, value in state_to_tensors(target).items():  # a failed load changes nothing
        assert torch.equal(value, before[key]), key
