"""A fused GPU kernel for the batched UDF (Triton): distances are never materialised.

:func:`~litege_core.descriptor.udf.udf_torch` builds ``(B, chunk, P)`` blocks of squared
distances in memory, ranks them with ``topk`` and refines the two best candidates: on a GPU the
blocks dominate both the time and the CUDA allocator peak (BENCHMARKS "batch-table-cuda").
Here one program owns ``BLOCK_M`` voxel centres of one cloud, walks the cloud's points in
tiles of ``BLOCK_P`` held in registers and keeps a running minimum of the exact squared
distance, computed from coordinate differences in float32 (what the torch backend's
refinement computes; no ``|c|² + |p|² − 2c·p`` estimate, so no candidates are needed). The
output is the only memory written: ``(B, M)`` float32.

Triton is optional (the GPU image has it; a CPU install does not). ``TRITON_INTERPRET=1``
runs the same kernel on CPU tensors, which is how the tests check it on a machine without a
GPU (``tests/litege_core/descriptor/test_descriptor_udf.py``; Triton 3.6's interpreter needs
numpy ≤ 2.2 for the kernel's loop bound — checked that way on 2026-11-27 — and the tests ran
compiled on an H200).
"""

from __future__ import annotations

import importlib.util
import os
from typing import TYPE_CHECKING, Any

from litege_core.errors import ArrayShapeError, MissingDependencyError

if TYPE_CHECKING:
    import torch

#: Voxel centres per program, points per tile (registers: BLOCK_M · BLOCK_P floats).
BLOCK_M = 64
BLOCK_P = 64


def triton_available(device_type: str = "cuda") -> bool:
    """Whether the kernel can run on ``device_type``: Triton is importable, and the device is
    a CUDA GPU (or the Triton interpreter is on, which runs it on CPU tensors)."""
    if importlib.util.find_spec("triton") is None:
        return False
    if device_type == "cuda":
        import torch

        return torch.cuda.is_available()
    return device_type == "cpu" and os.environ.get("TRITON_INTERPRET") == "1"


_KERNEL: Any = None


def _kernel() -> Any:
    """The compiled-on-first-use Triton kernel (defined lazily: Triton is optional)."""
    global _KERNEL
    if _KERNEL is not None:
        return _KERNEL
    try:
        import triton
        import triton.language as tl
    except ImportError as exc:  # pragma: no cover - guarded by triton_available
        raise MissingDependencyError("the 'triton' UDF backend needs Triton (GPU builds)") from exc

    @triton.jit
    def udf_kernel(  # pragma: no cover - traced by Triton, not run by Python
        clouds_ptr,
        centers_ptr,
        out_ptr,
        n_points,
        n_centers,
        BLOCK_M: tl.constexpr,
        BLOCK_P: tl.constexpr,
    ):
        cloud = tl.program_id(0)
        rows = tl.program_id(1) * BLOCK_M + tl.arange(0, BLOCK_M)
        valid = rows < n_centers
        cx = tl.load(centers_ptr + rows * 3, mask=valid, other=0.0)
        cy = tl.load(centers_ptr + rows * 3 + 1, mask=valid, other=0.0)
        cz = tl.load(centers_ptr + rows * 3 + 2, mask=valid, other=0.0)
        best = tl.full((BLOCK_M,), float("inf"), tl.float32)
        base = clouds_ptr + cloud * n_points * 3
        for start in range(0, n_points, BLOCK_P):
            cols = start + tl.arange(0, BLOCK_P)
            inside = cols < n_points
            px = tl.load(base + cols * 3, mask=inside, other=float("inf"))
            py = tl.load(base + cols * 3 + 1, mask=inside, other=float("inf"))
            pz = tl.load(base + cols * 3 + 2, mask=inside, other=float("inf"))
            dx = cx[:, None] - px[None, :]
            dy = cy[:, None] - py[None, :]
            dz = cz[:, None] - pz[None, :]
            best = tl.minimum(best, tl.min(dx * dx + dy * dy + dz * dz, axis=1))
        tl.store(out_ptr + cloud * n_centers + rows, tl.sqrt(best), mask=valid)

    _KERNEL = udf_kernel
    return _KERNEL


def udf_triton(clouds: torch.Tensor, centers: torch.Tensor) -> torch.Tensor:
    """Batched exact UDF in one fused kernel on the device of the inputs.

    Args:
        clouds: ``(B, P, 3)`` float tensor.
        centers: ``(M, 3)`` float tensor on the same device.

    Returns:
        ``(B, M)`` float32 distances from each centre to the nearest point of each cloud.
    """
    import torch

    if clouds.ndim != 3 or clouds.shape[2] != 3 or centers.ndim != 2 or centers.shape[1] != 3:
        raise ArrayShapeError(
            f"expected clouds (B, P, 3) and centers (M, 3), got {tuple(clouds.shape)} and "
            f"{tuple(centers.shape)}"
        )
    if clouds.shape[1] == 0:
        raise ArrayShapeError("clouds have no points")
    clouds = clouds.to(torch.float32).contiguous()
    centers = centers.to(clouds.device, torch.float32).contiguous()
    n_batch, n_points, n_centers = clouds.shape[0], clouds.shape[1], centers.shape[0]
    out = torch.empty((n_batch, n_centers), dtype=torch.float32, device=clouds.device)
    grid = (n_batch, -(-n_centers // BLOCK_M))
    _kernel()[grid](clouds, centers, out, n_points, n_centers, BLOCK_M=BLOCK_M, BLOCK_P=BLOCK_P)
    return out


__all__ = ["BLOCK_M", "BLOCK_P", "triton_available", "udf_triton"]
