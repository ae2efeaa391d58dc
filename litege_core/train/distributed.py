"""Data-parallel training over several processes: ``torchrun`` + DistributedDataParallel.

``torchrun --nproc-per-node=K -m litege_core.cli train geodesic --config FILE`` starts ``K``
processes (more with ``--nnodes``) that see ``WORLD_SIZE``, ``RANK``, ``LOCAL_RANK``,
``MASTER_ADDR`` and ``MASTER_PORT``; :func:`init_distributed` turns those into a process group
(``nccl`` on CUDA, one GPU per process: ``cuda:LOCAL_RANK``; ``gloo`` on the CPU) and a
:class:`DistributedContext`. Without ``WORLD_SIZE > 1`` nothing changes: one process trains as
before.

**What every rank does** (see :class:`~litege_core.train.trainer.Trainer`): all ranks build
the same tables and draw the same *global* batch of ``B`` views from the same seeded sampler;
rank ``r`` keeps views ``[r·B/W, (r+1)·B/W)`` (``B`` must be divisible by ``W``). Gradients are
averaged by DDP, so a step is the step of one process on the global batch. BatchNorm layers
are synchronized across ranks (:func:`convert_sync_batchnorm`: PyTorch's ``SyncBatchNorm`` on
CUDA, :class:`GlooSyncBatchNorm` on the CPU, where ``SyncBatchNorm`` refuses to run), so they
normalize with the statistics of the global batch, as one process does. Two ranks therefore
equal one process up to the order of floating-point reductions. Only rank 0 validates (the
report is broadcast, so every rank takes the same early-stopping decisions), writes checkpoints
and exports the bundle; every rank can resume from ``last.safetensors`` (it holds the sampler
state, which is the same on all ranks).
"""

from __future__ import annotations

import datetime
import gc
import logging
import os
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, TypeVar

import torch
import torch.distributed as dist
from torch import nn

from litege_core.errors import InputError

LOG = logging.getLogger("litege.train")
_T = TypeVar("_T")
DEFAULT_TIMEOUT_S = 1800.0  # collectives wait this long (rank 0 validating, checkpointing)


@dataclass(frozen=True)
class DistributedContext:
    """This process's place in a data-parallel run.

    Attributes:
        rank: global rank (0 validates, checkpoints, exports and logs).
        world_size: number of processes.
        local_rank: rank on this machine (the GPU index on CUDA).
        backend: ``"nccl"`` or ``"gloo"``.
        device: the device this rank trains on.
        owns_group: whether :func:`init_distributed` created the process group (and
            :meth:`close` destroys it).
    """

    rank: int
    world_size: int
    local_rank: int
    backend: str
    device: torch.device
    owns_group: bool = True

    @property
    def is_main(self) -> bool:
        return self.rank == 0

    def local_slice(self, batch: int) -> slice:
        """This rank's share ``[r·b, (r+1)·b)`` of a global batch of ``batch`` items."""
        if batch % self.world_size:
            raise InputError(
                f"train.batch_views={batch} must be divisible by the {self.world_size} "
                "data-parallel processes (each takes an equal share of every batch)"
            )
        size = batch // self.world_size
        return slice(self.rank * size, (self.rank + 1) * size)

    def barrier(self) -> None:
        if self.backend == "nccl":
            dist.barrier(device_ids=[self.device.index or 0])
        else:
            dist.barrier()

    def broadcast(self, value: _T) -> _T:
        """Rank 0's ``value`` on every rank (any picklable object; in memory only)."""
        holder = [value if self.is_main else None]
        dist.broadcast_object_list(holder, src=0, device=self._collective_device)
        return holder[0]  # type: ignore[return-value]

    def mean(self, value: torch.Tensor) -> torch.Tensor:
        """The mean of ``value`` over the ranks (a new tensor; float64 kept)."""
        total = value.detach().clone().to(self._collective_device)
        dist.all_reduce(total, op=dist.ReduceOp.SUM)
        return (total / self.world_size).to(value.device)

    def any(self, flag: bool) -> bool:
        """Whether ``flag`` is true on any rank (so that every rank takes the same branch)."""
        value = torch.tensor([int(flag)], dtype=torch.int32, device=self._collective_device)
        dist.all_reduce(value, op=dist.ReduceOp.MAX)
        return bool(value.item())

    @property
    def _collective_device(self) -> torch.device:
        return self.device if self.backend == "nccl" else torch.device("cpu")

    def close(self) -> None:
        """Destroy the process group if this context created it (after collecting the
        objects that still reference it, so Gloo's threads are joined now, not at exit)."""
        if self.owns_group and dist.is_initialized():
            gc.collect()
            dist.destroy_process_group()


def world_size_from_env(environ: Mapping[str, str] | None = None) -> int:
    """``WORLD_SIZE`` as set by ``torchrun`` (1 when absent)."""
    environ = os.environ if environ is None else environ
    try:
        return int(environ.get("WORLD_SIZE", "1"))
    except ValueError as exc:
        raise InputError(f"WORLD_SIZE={environ.get('WORLD_SIZE')!r} is not an integer") from exc


def init_distributed(
    device: torch.device,
    environ: Mapping[str, str] | None = None,
    timeout_s: float = DEFAULT_TIMEOUT_S,
) -> DistributedContext | None:
    """Join the data-parallel run described by the environment, or ``None`` for one process.

    Args:
        device: the configured device; ``cuda`` (any index) becomes ``cuda:LOCAL_RANK`` with
            the ``nccl`` backend, ``cpu`` uses ``gloo``.
        environ: the environment (default ``os.environ``): ``WORLD_SIZE``, ``RANK``,
            ``LOCAL_RANK``, and ``MASTER_ADDR`` / ``MASTER_PORT`` for the rendezvous.
        timeout_s: how long a collective may wait for the other ranks.

    Raises:
        InputError: inconsistent environment, or a CUDA run with fewer visible GPUs than
            local ranks.
    """
    environ = os.environ if environ is None else environ
    world_size = world_size_from_env(environ)
    if world_size <= 1:
        return None
    try:
        rank = int(environ["RANK"])
        local_rank = int(environ.get("LOCAL_RANK", "0"))
    except (KeyError, ValueError) as exc:
        raise InputError("WORLD_SIZE > 1 needs integer RANK and LOCAL_RANK (torchrun)") from exc
    if not 0 <= rank < world_size:
        raise InputError(f"RANK={rank} outside 0..{world_size - 1}")
    if device.type == "cuda":
        if local_rank >= torch.cuda.device_count():
            raise InputError(
                f"LOCAL_RANK={local_rank} but only {torch.cuda.device_count()} GPUs are visible"
            )
        device = torch.device("cuda", local_rank)
        torch.cuda.set_device(device)
        backend = "nccl"
    elif device.type == "cpu":
        backend = "gloo"
    else:
        raise InputError(f"data-parallel training supports cpu and cuda, not {device.type}")
    owns = not dist.is_initialized()
    if owns:
        dist.init_process_group(
            backend,
            init_method="env://",
            rank=rank,
            world_size=world_size,
            timeout=datetime.timedelta(seconds=timeout_s),
        )
    elif dist.get_world_size() != world_size or dist.get_rank() != rank:
        raise InputError("an existing process group disagrees with WORLD_SIZE / RANK")
    LOG.debug("rank %d of %d (%s on %s)", rank, world_size, backend, device)
    return DistributedContext(rank, world_size, local_rank, backend, device, owns)


# --------------------------------------------------------------------------- BatchNorm


class GlooSyncBatchNorm(nn.BatchNorm1d):
    """BatchNorm over the batches of all ranks, for CPU (gloo) runs.

    PyTorch's :class:`~torch.nn.SyncBatchNorm` only runs on accelerators. This layer computes
    the global mean (all-reduced sums and counts), then the global biased variance from the
    all-reduced squared deviations (two passes, as stable as BatchNorm's own), normalizes with
    them and updates the running statistics with the unbiased global variance, exactly as
    :class:`~torch.nn.BatchNorm1d` does on the concatenated batch. The all-reduces are
    differentiable (``torch.distributed.nn``), so gradients flow through the statistics of the
    other ranks' rows as they do through one process's batch. Outside training, or without a
    process group of more than one rank, it is a plain ``BatchNorm1d`` (same state dict).
    """

    def forward(self, input: torch.Tensor) -> torch.Tensor:
        if not (
            self.training
            and dist.is_available()
            and dist.is_initialized()
            and dist.get_world_size() > 1
        ):
            return super().forward(input)
        from torch.distributed.nn.functional import all_reduce

        self._check_input_dim(input)
        dims = [0, *range(2, input.ndim)]
        shape = [1, -1] + [1] * (input.ndim - 2)
        count = torch.tensor(
            [input.numel() // input.shape[1]], dtype=input.dtype, device=input.device
        )
        sums = all_reduce(torch.cat([input.sum(dims), count]))
        n = sums[-1]
        mean = sums[:-1] / n
        centered = input - mean.reshape(shape)
        var = all_reduce(centered.pow(2).sum(dims)) / n
        if self.track_running_stats and self.running_mean is not None:
            with torch.no_grad():
                assert self.num_batches_tracked is not None and self.running_var is not None
                self.num_batches_tracked.add_(1)
                momentum = (
                    1.0 / float(self.num_batches_tracked)
                    if self.momentum is None
                    else self.momentum
                )
                unbiased = var * (n / (n - 1).clamp(min=1))
                self.running_mean.mul_(1 - momentum).add_(mean.detach(), alpha=momentum)
                self.running_var.mul_(1 - momentum).add_(unbiased.detach(), alpha=momentum)
        out = centered * torch.rsqrt(var + self.eps).reshape(shape)
        if self.affine:
            out = out * self.weight.reshape(shape) + self.bias.reshape(shape)
        return out


def _swap_batchnorm(module: nn.Module, make: Any, kinds: tuple[type, ...]) -> nn.Module:
    """``module`` with every BatchNorm of ``kinds`` replaced by ``make(bn)``, which shares the
    original's parameters and buffers (optimizer state and state-dict keys are unchanged)."""
    if isinstance(module, kinds) and type(module) is not make:
        new = make(
            module.num_features,
            module.eps,
            module.momentum,
            module.affine,
            module.track_running_stats,
        )
        if module.affine:
            new.weight = module.weight
            new.bias = module.bias
        new.running_mean = module.running_mean
        new.running_var = module.running_var
        new.num_batches_tracked = module.num_batches_tracked
        new.train(module.training)
        return new
    for name, child in module.named_children():
        module.add_module(name, _swap_batchnorm(child, make, kinds))
    return module


_BATCHNORMS = (nn.BatchNorm1d, nn.SyncBatchNorm)


def convert_sync_batchnorm(module: nn.Module, device: torch.device) -> nn.Module:
    """Replace the BatchNorm layers of ``module`` (in place) by synchronized ones:
    ``nn.SyncBatchNorm`` on CUDA, :class:`GlooSyncBatchNorm` on the CPU. Parameters and
    buffers are shared, not copied; returns ``module``."""
    if device.type == "cuda":
        return nn.SyncBatchNorm.convert_sync_batchnorm(module)
    return _swap_batchnorm(module, GlooSyncBatchNorm, _BATCHNORMS)


def revert_sync_batchnorm(module: nn.Module) -> nn.Module:
    """Undo :func:`convert_sync_batchnorm`: plain ``nn.BatchNorm1d`` layers sharing the same
    parameters and buffers (for export and single-process use); returns ``module``."""
    return _swap_batchnorm(module, nn.BatchNorm1d, (nn.SyncBatchNorm, GlooSyncBatchNorm))


def wrap_ddp(module: nn.Module, context: DistributedContext) -> nn.Module:
    """``module`` in DistributedDataParallel on ``context.device``. Buffers are not
    broadcast at each forward: the synchronized BatchNorm keeps them equal on every rank."""
    from torch.nn.parallel import DistributedDataParallel

    device_ids = [context.device.index] if context.device.type == "cuda" else None
    return DistributedDataParallel(module, device_ids=device_ids, forward_sync_buffers=False)


__all__ = [
    "DEFAULT_TIMEOUT_S",
    "DistributedContext",
    "GlooSyncBatchNorm",
    "convert_sync_batchnorm",
    "init_distributed",
    "revert_sync_batchnorm",
    "world_size_from_env",
    "wrap_ddp",
]
