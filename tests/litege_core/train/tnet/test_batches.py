"""T-Net batches: rotated canonical clouds, frame turns, the fixed validation set, loaders."""

import math

import pytest
import torch

from litege_core.errors import InputError
from litege_core.nets.tnet import CUBE_ROTATIONS
from litege_core.train.tnet import (
    BatchLoader,
    sample_batch,
    train_tnet,
    validation_set,
)
from tests.litege_core.train.tnet.conftest import tiny_config


def test_batches_are_rotated_canonical_clouds_and_seeded(toy_shapes, tmp_path) -> None:
    train, _ = toy_shapes
    config = tiny_config(tmp_path)
    batch = sample_batch(train, config, step=3)
    B, N, _ = batch.canonical.shape
    assert B == 4 and 32 <= N <= 64 and batch.R_gt.shape == (4, 3, 3)
    torch.testing.assert_close(batch.rotated, batch.canonical @ batch.R_gt.transpose(1, 2))
    torch.testing.assert_close(
        batch.R_gt.transpose(1, 2) @ batch.R_gt, torch.eye(3).expand(4, 3, 3), atol=1e-5, rtol=0
    )
    assert batch.canonical.mean(dim=1).abs().max() < 1e-5  # each cloud centred
    assert batch.frame_turns is None
    again = sample_batch(train, config, step=3)
    assert all(torch.equal(a, b) for a, b in zip(batch[:3], again[:3], strict=True))
    other = sample_batch(train, config, step=4)
    assert not torch.equal(batch.R_gt, other.R_gt)
    stretched = sample_batch(train, config.replace(augment={"axis_scale": 0.5}), step=3)
    assert torch.equal(stretched.R_gt, batch.R_gt)  # same draws before the stretch
    assert not torch.equal(stretched.canonical, batch.canonical)
    torch.testing.assert_close(
        stretched.rotated, stretched.canonical @ stretched.R_gt.transpose(1, 2)
    )


def test_validation_set_is_fixed(toy_shapes, tmp_path) -> None:
    _, val = toy_shapes
    config = tiny_config(tmp_path)
    first, second = validation_set(val, config), validation_set(val, config)
    assert set(first.batches) == {"mesh", "cloud500", "broken"} and first.n_items == 6
    assert first.batches["cloud500"].canonical.shape[1] == 500
    for mode, batch in first.batches.items():
        assert all(
            torch.equal(a, b) for a, b in zip(batch[:3], second.batches[mode][:3], strict=True)
        )


def test_frame_turns_are_drawn_per_item_and_used_in_training(toy_shapes, tmp_path) -> None:
    train, val = toy_shapes
    config = tiny_config(
        tmp_path, augment={"frame_turns": True}, network={"prealign": "pca"}, train={"steps": 4}
    )
    batch = sample_batch(train, config, step=0)
    turns = batch.frame_turns
    assert turns is not None and turns.shape == (4, 3, 3)
    assert all(bool((CUBE_ROTATIONS.float() == t).all(dim=(1, 2)).any()) for t in turns)
    again = sample_batch(train, config, step=0)
    assert torch.equal(again.frame_turns, turns)
    result = train_tnet(config, train_shapes=train, val_shapes=val, make_report=False)
    assert result.net.prealign == "pca" and math.isfinite(result.best_val["mean"])


def test_batch_loader_processes_serve_the_sampled_batches_in_order(toy_shapes, tmp_path) -> None:
    train, _ = toy_shapes
    config = tiny_config(tmp_path, augment={"frame_turns": True}, network={"prealign": "pca"})
    with BatchLoader(train, config, workers=2) as loader:
        for step in range(6):  # more steps than the batches first put in flight (2 × workers)
            served, sampled = loader.batch(step), sample_batch(train, config, step)
            assert all(torch.equal(a, b) for a, b in zip(served, sampled, strict=True))
        with pytest.raises(InputError, match="in order"):
            loader.batch(9)
    with BatchLoader(train, config, workers=0) as inline:  # no processes: sampled on demand
        assert torch.equal(inline.batch(5).R_gt, sample_batch(train, config, 5).R_gt)
