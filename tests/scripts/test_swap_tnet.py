"""scripts/swap_tnet.py: a matching bundle with another T-Net, everything else kept."""

from __future__ import annotations

import torch

from litege_core.matching import MatchingModel
from litege_core.train.tnet import save_tnet


def test_the_swap_keeps_the_networks_and_the_frame_judge(swap_tnet, tmp_path):
    tnet = MatchingModel.load("quadrupeds").bundle.tnet
    with torch.no_grad():
        for parameter in tnet.parameters():
            parameter.mul_(0.5)  # another T-Net
    weights = tmp_path / "tnet.safetensors"
    save_tnet(tnet, weights, training={"note": "halved"})
    shipped = MatchingModel.load("quadrupeds").bundle  # loads are not cached: the shipped T-Net
    assert shipped.judge_networks  # the shipped continuation judges frames with its start
    summary = swap_tnet.main(["quadrupeds", str(weights), "--out", str(tmp_path / "swapped")])
    swapped = MatchingModel.load(summary["out"]).bundle
    assert swapped.manifest["training"]["tnet_swap"]["tnet_training"] == {"note": "halved"}
    assert (
        swapped.manifest["content_hash"]
        == summary["content_hash"]
        != shipped.manifest["content_hash"]
    )
    assert len(swapped.judge_networks) == len(shipped.judge_networks)
    for old, new in zip(
        (*shipped.networks, *shipped.judge_networks),
        (*swapped.networks, *swapped.judge_networks),
        strict=True,
    ):
        for a, b in zip(old.state_dict().values(), new.state_dict().values(), strict=True):
            torch.testing.assert_close(a.float(), b.float())
    first = next(iter(shipped.tnet.state_dict().values())).float()
    assert not torch.allclose(first, next(iter(swapped.tnet.state_dict().values())).float())
