"""Data-parallel training (torchrun, DistributedDataParallel over gloo on the CPU): two
processes sharing every global batch equal one process on the same batch, resume included.

The two-process run is a real ``python -m torch.distributed.run --nproc-per-node=2`` launch of
:func:`~litege_core.train.pipeline.train_geodesic` (rendezvous on localhost, gloo, synchronized
BatchNorm). Only the order of the floating-point reductions differs (BatchNorm statistics and
gradients summed over two ranks), so the final weights agree with the one-process run up to
:data:`MOVEMENT_RTOL` of what training changed, and the losses and predictions agree closely.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from safetensors.torch import load_file

from litege_core.errors import InputError
from litege_core.nets import GeodesicNet, load_state
from litege_core.train.distributed import (
    DistributedContext,
    GlooSyncBatchNorm,
    convert_sync_batchnorm,
    init_distributed,
    revert_sync_batchnorm,
)
from litege_core.train.pipeline import prepare_run, train_geodesic
from litege_core.train.trainer import LAST, evaluate, read_checkpoint

REPO = Path(__file__).resolve().parents[3]
NULL_GRADIENT = {"project_embed.bias", "project_down_pcacoord.bias", "mlp_pcacoord.1.running_mean"}
"""Parameters whose exact gradient is zero: ``project_embed.bias`` cancels in ``e_src − e_dst``,
``project_down_pcacoord.bias`` is removed by the BatchNorm after the next linear layer (whose
running mean follows it). Their computed gradients are rounding noise, which Adam (update ≈
``lr · g / |g|``) turns into ``lr``-sized steps that differ with the reduction order, so they
are compared through the network's predictions, not entry by entry."""

MOVEMENT_RTOL = 1e-2
"""How far (Frobenius norm) a parameter of the two-process run may be from the one-process run's,
relative to how far training moved it. Ten Adam steps at ``lr=1e-2`` amplify rounding: Adam
divides each gradient entry by its own running magnitude, so a change in the order of a sum
changes the steps of small-gradient entries, and BatchNorm carries that on. Measured on the CI
machine: two processes vs one, gaps up to 1.5e-3 of the movement; one process with 2 threads vs
1 thread (only the order of the sums differs), gaps of ~1e-2 of the weights' norm. A wrong
reduction (unsynchronized BatchNorm, a rank training on the other's share) moves them far more."""

WORKER = r"""
import json, os, sys
from pathlib import Path
from safetensors.torch import save_file
import torch.distributed as dist
from litege_core.nets import state_to_tensors
from litege_core.train.config import TrainConfig
from litege_core.train.pipeline import prepare_run, train_geodesic
from litege_core.train.trainer import LAST

config = TrainConfig.from_dict(json.loads(Path(sys.argv[1]).read_text()))
out, mode, rank = Path(sys.argv[2]), sys.argv[3], os.environ["RANK"]
if mode == "first":
    result = train_geodesic(config, max_epochs=1)
else:
    result = train_geodesic(config, resume=config.run_dir / "checkpoints" / LAST)
assert not dist.is_initialized()  # the run destroyed the process group it created
save_file(state_to_tensors(result.prepared.network), str(out / f"{mode}{rank}.safetensors"))
(out / f"{mode}{rank}.json").write_text(json.dumps({
    "history": result.state.history,
    "manifest_hash": result.manifest and result.manifest["content_hash"],
    "bn": sorted({type(m).__name__ for m in result.prepared.network.modules()
                  if "BatchNorm" in type(m).__name__}),
}))
"""


def _torchrun(config, tmp_path: Path, mode: str) -> None:
    """``torchrun --standalone --nproc-per-node=2`` of :data:`WORKER` (``mode``: ``first``
    trains one epoch, ``resume`` continues from its checkpoint to the end)."""
    config_file = tmp_path / "config.json"
    config_file.write_text(json.dumps(config.to_dict()))
    script = tmp_path / "worker.py"
    script.write_text(WORKER)
    env = {k: v for k, v in os.environ.items() if k not in ("WORLD_SIZE", "RANK", "LOCAL_RANK")}
    env.update(OMP_NUM_THREADS="1", PYTHONPATH=str(REPO))
    result = subprocess.run(
        [
            sys.executable,
            "-m",
            "torch.distributed.run",
            "--standalone",
            "--nproc-per-node=2",
            str(script),
            str(config_file),
            str(tmp_path),
            mode,
        ],
        cwd=REPO,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-5000:]


def _timeless(history):
    return [{k: v for k, v in h.items() if "seconds" not in k} for h in history]


def test_two_processes_equal_one_process_on_the_same_global_batch(make_config, tmp_path):
    one = train_geodesic(make_config("one"))  # 2 epochs x 5 steps, batch of 4 views
    config = make_config("two")
    _torchrun(config, tmp_path, "first")  # one epoch, as if the job were stopped there
    first = json.loads((tmp_path / "first0.json").read_text())
    assert len(first["history"]) == 1 and first["manifest_hash"] is None
    _torchrun(config, tmp_path, "resume")  # a new launch resumes from last.safetensors
    ranks = [load_file(str(tmp_path / f"resume{r}.safetensors")) for r in (0, 1)]
    reports = [json.loads((tmp_path / f"resume{r}.json").read_text()) for r in (0, 1)]
    reference = {k: v.detach().cpu() for k, v in one.prepared.network.state_dict().items()}
    assert ranks[0].keys() == reference.keys()
    initial = prepare_run(make_config("initial")).network.state_dict()  # same seed: same start
    for key in reference:
        torch.testing.assert_close(ranks[0][key], ranks[1][key], rtol=0, atol=0, msg=key)
        if key not in NULL_GRADIENT:
            moved = float((reference[key] - initial[key]).double().norm())
            gap = float((ranks[0][key] - reference[key]).double().norm())
            assert gap <= MOVEMENT_RTOL * moved, f"{key}: |two − one| {gap:.3g}, moved {moved:.3g}"

    # The network as a whole (null-gradient parameters included) predicts the same.
    two = GeodesicNet.from_config(one.prepared.network.config())
    load_state(two, ranks[0])
    ours = evaluate(two, one.prepared.validation)
    theirs = evaluate(one.prepared.network, one.prepared.validation)
    assert ours.l1 == pytest.approx(theirs.l1, rel=1e-3)
    assert ours.mean == pytest.approx(theirs.mean, rel=1e-3)
    # The checkpoint (rank 0 only) holds the same weights; BatchNorm is plain again after fit.
    tensors, header = read_checkpoint(config.run_dir / "checkpoints" / LAST)
    torch.testing.assert_close(
        tensors["model/final_linear.weight"], ranks[0]["final_linear.weight"]
    )
    assert header["step"] == one.state.step == 10
    assert reports[0]["bn"] == reports[1]["bn"] == ["BatchNorm1d"]
    # Every rank saw the same (global) losses and validation; rank 0 exported the bundle.
    assert _timeless(reports[0]["history"]) == _timeless(reports[1]["history"])
    assert _timeless(first["history"]) == _timeless(reports[0]["history"][:1])
    for mine, theirs in zip(reports[0]["history"], one.state.history, strict=True):
        assert mine["step"] == theirs["step"]
        assert mine["loss"] == pytest.approx(theirs["loss"], rel=1e-3)
        assert mine["val_mean"] == pytest.approx(theirs["val_mean"], rel=1e-3)
    assert reports[0]["manifest_hash"] == reports[1]["manifest_hash"]
    assert (config.run_dir / "bundle" / "manifest.json").exists()
    assert not list((config.run_dir / "checkpoints").glob("*.tmp*"))


def test_no_torchrun_environment_means_one_process():
    assert init_distributed(torch.device("cpu"), environ={}) is None
    assert init_distributed(torch.device("cpu"), environ={"WORLD_SIZE": "1"}) is None
    with pytest.raises(InputError, match="RANK"):
        init_distributed(torch.device("cpu"), environ={"WORLD_SIZE": "2"})
    context = DistributedContext(1, 4, 1, "gloo", torch.device("cpu"), owns_group=False)
    assert context.local_slice(8) == slice(2, 4) and not context.is_main
    with pytest.raises(InputError, match="divisible"):
        context.local_slice(6)


def test_sync_batchnorm_conversion_shares_parameters_and_round_trips():
    net = torch.nn.Sequential(torch.nn.Linear(3, 4), torch.nn.BatchNorm1d(4), torch.nn.ReLU())
    bn = net[1]
    x = torch.randn(8, 3)
    before = {k: v.clone() for k, v in net.state_dict().items()}
    expected = net(x)
    net.load_state_dict(before)
    convert_sync_batchnorm(net, torch.device("cpu"))
    assert isinstance(net[1], GlooSyncBatchNorm) and net[1].weight is bn.weight
    assert net[1].running_mean is bn.running_mean
    for key, value in before.items():
        torch.testing.assert_close(net.state_dict()[key], value)
    # Without a process group it is a plain BatchNorm1d (same output, same running stats).
    net.load_state_dict(before)
    torch.testing.assert_close(net(x), expected)
    revert_sync_batchnorm(net)
    assert type(net[1]) is torch.nn.BatchNorm1d and net[1].weight is bn.weight
