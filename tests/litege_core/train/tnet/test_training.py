"""T-Net training loop: schedule, loss, determinism, outputs, loaders, time budgets, CLI."""

import argparse
import json
import math

import numpy as np
import pytest
import torch

import litege_core.train.tnet as tnet_module
import litege_core.train.tnet.training as tnet_training
from litege_core.cli.train import add_train_parser
from litege_core.nets import TNet, state_to_tensors
from litege_core.train.tnet import (
    TNetTrainConfig,
    cosine_lr,
    load_tnet,
    read_tnet_metadata,
    run_tnet_training,
    sample_batch,
    train_step,
    train_tnet,
)
from tests.litege_core.train.tnet.conftest import REPO, tiny_config


def test_cosine_schedule_endpoints() -> None:
    opt = TNetTrainConfig().train
    assert cosine_lr(0, opt) == pytest.approx(opt.lr)
    assert cosine_lr(opt.steps, opt) == pytest.approx(opt.eta_min)
    assert cosine_lr(opt.steps // 2, opt) == pytest.approx((opt.lr + opt.eta_min) / 2)


def test_loss_decreases_on_a_fixed_batch(toy_shapes, tmp_path) -> None:
    train, _ = toy_shapes
    config = tiny_config(tmp_path, train={"batch_size": 8})
    torch.manual_seed(0)
    net = TNet((16, 32), (16,)).train()
    optimizer = torch.optim.Adam(net.parameters(), lr=1e-2)
    batch = sample_batch(train, config, step=0)
    losses = [train_step(net, optimizer, batch, 2.0)["loss"] for _ in range(60)]
    assert all(math.isfinite(x) for x in losses)
    assert np.mean(losses[-5:]) < 0.5 * losses[0]


def test_training_is_deterministic(toy_shapes, tmp_path) -> None:
    train, val = toy_shapes
    config = tiny_config(tmp_path)
    first = train_tnet(config, train_shapes=train, val_shapes=val, make_report=False)
    second = train_tnet(config, train_shapes=train, val_shapes=val, make_report=False)
    a, b = state_to_tensors(first.net), state_to_tensors(second.net)
    assert all(torch.equal(a[k], b[k]) for k in a)
    assert first.best_val == second.best_val and first.best_step == second.best_step
    other = train_tnet(
        config.replace(train={"seed": 1}), train_shapes=train, val_shapes=val, make_report=False
    )
    c = state_to_tensors(other.net)
    assert not all(torch.equal(a[k], c[k]) for k in a)
    assert [h["step"] for h in first.history] == [3, 6]
    assert not first.net.training


def test_run_writes_weights_report_and_log(toy_shapes, tmp_path) -> None:
    train, val = toy_shapes
    config = tiny_config(tmp_path)
    report = run_tnet_training(config, train_shapes=train, val_shapes=val)
    run = tmp_path / "run"
    assert {p.name for p in run.iterdir()} == {"tnet.safetensors", "report.json", "train.log"}
    on_disk = json.loads((run / "report.json").read_text())
    assert on_disk == json.loads(json.dumps(report))
    assert on_disk["network"] == {"conv_widths": [8, 16], "fc_widths": [8], "prealign": "none"}
    assert on_disk["training"]["best_step"] in (3, 6)
    alignment = on_disk["alignment"]
    assert alignment["failed_train_indices"] == alignment["train"]["failures"]
    for name, n in (("train", 4), ("val", 2), ("val_cloud500", 2), ("val_broken", 2)):
        stats = alignment[name]
        keys = {"n", "mean", "std", "median", "max", "n_failures", "failures", "threshold"}
        assert keys <= set(stats) and stats["n"] == n
        assert 0.0 <= stats["median"] <= stats["max"] <= math.pi
        assert stats["n_failures"] == len(stats["failures"])
    assert len(alignment["train"]["failed_keys"]) == alignment["train"]["n_failures"]
    log = (run / "train.log").read_text()
    assert "val step 6" in log and "val_broken: mean" in log

    net = load_tnet(run / "tnet.safetensors")
    assert not net.training and net.config() == on_disk["network"]
    meta = read_tnet_metadata(run / "tnet.safetensors")
    assert meta["training"]["config"]["train"]["steps"] == 6
    assert meta["training"]["best_val"] == on_disk["training"]["best_val"]


def test_parser_registers_train_tnet_and_keeps_geodesic() -> None:
    parser = argparse.ArgumentParser(prog="litege")
    add_train_parser(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(["train", "tnet", "--config", "c.toml", "--out", "o"])
    assert (args.config, args.out, args.train_command) == ("c.toml", "o", "tnet")
    assert callable(args.handler)
    args = parser.parse_args(["train", "geodesic", "--config", "g.toml"])
    assert args.train_command == "geodesic" and callable(args.handler)
    with pytest.raises(SystemExit):
        parser.parse_args(["train", "tnet"])


def test_training_with_loader_processes_is_the_same_run(toy_shapes, tmp_path) -> None:
    train, val = toy_shapes
    config = tiny_config(tmp_path)
    inline = train_tnet(config, train_shapes=train, val_shapes=val, make_report=False)
    forked = train_tnet(
        config.replace(train={"loader_workers": 2}),
        train_shapes=train,
        val_shapes=val,
        make_report=False,
    )
    a, b = state_to_tensors(inline.net), state_to_tensors(forked.net)
    assert all(torch.equal(a[k], b[k]) for k in a)
    assert forked.best_val == inline.best_val and forked.steps == inline.steps == 6


def test_time_budget_plans_the_steps_that_fit() -> None:
    opt = TNetTrainConfig.from_dict({"train": {"steps": 10_000, "time_budget_minutes": 1.0}}).train
    # 100 steps in 6 s: 54 s left at ~16.7 steps/s → 900 more
    assert tnet_training._planned_steps(opt, 100, 6.0) == 1000
    assert tnet_training._planned_steps(opt, 100, 0.01) == 10_000  # capped at train.steps
    assert tnet_training._planned_steps(opt, 100, 90.0) == 100  # already over: stop now


def test_time_budget_run_records_the_steps_it_ran(toy_shapes, tmp_path, monkeypatch) -> None:
    train, val = toy_shapes
    monkeypatch.setattr(tnet_training, "PLAN_AFTER_STEPS", 2)
    monkeypatch.setattr(tnet_training, "_planned_steps", lambda opt, done, elapsed: 4)
    config = tiny_config(tmp_path, train={"steps": 50, "time_budget_minutes": 5.0})
    result = train_tnet(config, train_shapes=train, val_shapes=val, make_report=False)
    assert result.steps == 4
    assert [h["step"] for h in result.history] == [3, 4]  # val_every 3, then the last step
    assert cosine_lr(4, config.train, result.steps) == pytest.approx(config.train.eta_min)


def test_cli_overrides_workers_and_time_budget(monkeypatch, tmp_path) -> None:
    captured = {}

    def fake_run(config, out=None):
        captured["config"] = config
        return {
            "weights": "w",
            "training": {"best_step": 1, "best_val": {}, "steps_per_second": 1.0, "steps_run": 1},
            "alignment": {},
        }

    monkeypatch.setattr(tnet_module, "run_tnet_training", fake_run)
    parser = argparse.ArgumentParser(prog="litege")
    add_train_parser(parser.add_subparsers(dest="command", required=True))
    config_path = REPO / "configs" / "tnet-quadrupeds.toml"
    command = ["train", "tnet", "--config", str(config_path), "--workers", "3"]
    args = parser.parse_args([*command, "--time-budget", "2.5", "--init", "quadrupeds"])
    assert args.handler(args) == 0
    config = captured["config"]
    assert (config.data.workers, config.train.loader_workers) == (3, 3)
    assert config.train.time_budget_minutes == 2.5
    assert config.train.init == "quadrupeds"
