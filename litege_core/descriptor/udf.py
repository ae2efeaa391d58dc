"""Unsigned distance fields at the informative voxel centres (reference spec §2.4).

The UDF of a shape at voxel centre ``c`` is the Euclidean distance from ``c`` to the nearest
point of a **point sample** of the shape (not to the triangle surface), in canonical-frame
units, with no clamping, truncation or scaling.

Backends (all agree to 1e-5; ``tests/litege_core/descriptor/test_descriptor_udf.py``):

* ``"kdtree"`` — :class:`scipy.spatial.cKDTree` built on the sample points, queried at the
  centres (``workers`` threads). Exact (float64).
* ``"pykdtree"`` — the same with ``pykdtree`` (OpenMP), an optional dependency. Exact.
* ``"triton"`` — the same brute force fused into one GPU kernel (a running minimum of exact
  squared differences per voxel centre; nothing but the output is written). Needs Triton.
* ``"torch"`` — brute force on one device, batched over ``B`` clouds: squared distances by
  ``baddbmm`` in float32 over chunks of centres, the ``candidates`` nearest by that estimate,
  then their exact distance by coordinate differences (plain ``|c|² + |p|² − 2c·p`` in float32
  is off by up to 1e-4 near the surface; this refinement brings it to ~1e-7).
* :func:`udf_reference` — float64 brute force in numpy, the slow reference.

Choice (``backend="auto"``), from ``scripts/bench_udf.py`` on the shared 2-core CPU of the
development machine, 2026-11-21 (M = 25,000 informative-like centres, area-weighted clouds;
milliseconds **per shape**, median of 20 runs after warm-up except ``*`` = one run; other
jobs shared the cores, so absolute values vary by up to 2× between runs, rankings did not)::

    P     B    kdtree  kdtree(workers=-1)  pykdtree  torch (CPU, brute force)
    300   1     10.1        12.0              8.0        63.5
    300   16     9.4         5.7              3.8        32.0
    300   64     9.7         7.8              3.9        18.4
    2000  1     23.7        24.6              8.1       302
    2000  16    23.8        17.3              7.9       120*
    2000  64    26.1        18.7             11.7       121*
    8000  1     70.2        67.5             16.2      1030
    8000  16    63.7        43.0             33.0       942*
    8000  64    70.0*       69.6*            35.5       782*

On a CPU the k-d trees win every regime, single shape or batched, by 5–65× over brute force
(a batch is a loop of independent trees: nothing is shared between clouds), and ``pykdtree``
beats ``cKDTree`` by 1.3–3×. ``auto`` therefore picks ``pykdtree`` when it is installed, else
``kdtree`` with all cores (``workers=-1``, 1.3–1.6× faster on batches), on a CPU device. On a
CUDA device it picks ``triton`` (:mod:`litege_core.descriptor.udf_triton`: one fused kernel,
exact differences, no distance block in memory) where Triton is installed, else ``torch``:
brute force on a GPU is what the authors (pytorch3d ``knn_points``) do. GPU timings: BENCHMARKS
"batch-table-cuda".
"""

from __future__ import annotations

import importlib.util
from collections.abc import Sequence
from typing import TYPE_CHECKING, cast

import numpy as np
from numpy.typing import ArrayLike, NDArray

from litege_core.descriptor._arrays import as_clouds, as_points, positive_int
from litege_core.device import resolve_device
from litege_core.enums import ParsableEnum
from litege_core.errors import ArrayShapeError, MissingDependencyError

if TYPE_CHECKING:  # torch is imported where a backend needs it (the numpy runtime never does)
    import torch

#: Elements of the (B, chunk, P) distance block materialised at once by the torch backend.
TORCH_BLOCK_ELEMENTS = 1 << 24


class UdfBackend(ParsableEnum, noun="UDF backend"):
    """How the nearest sample point of each voxel centre is found."""

    AUTO = "auto"
    KDTREE = "kdtree"
    PYKDTREE = "pykdtree"
    TORCH = "torch"
    TRITON = "triton"


def pykdtree_available() -> bool:
    """Whether the optional ``pykdtree`` package can be imported."""
    return importlib.util.find_spec("pykdtree") is not None


def resolve_backend(backend: str | UdfBackend, device: torch.device | str = "cpu") -> UdfBackend:
    """The concrete backend ``auto`` stands for on ``device`` (see the module docstring)."""
    chosen = UdfBackend.parse(backend)
    if chosen is not UdfBackend.AUTO:
        return chosen
    if device_type(device) != "cpu":
        from litege_core.descriptor.udf_triton import triton_available

        return UdfBackend.TRITON if triton_available(device_type(device)) else UdfBackend.TORCH
    return UdfBackend.PYKDTREE if pykdtree_available() else UdfBackend.KDTREE


def device_type(device: torch.device | str) -> str:
    """``"cpu"``, ``"cuda"``, ... of a torch device or its name (without importing torch)."""
    return str(getattr(device, "type", device)).split(":", 1)[0]


# --------------------------------------------------------------------------- single cloud
def udf_kdtree(points: ArrayLike, centers: ArrayLike, workers: int = 1) -> NDArray:
    """UDF of one cloud with a scipy ``cKDTree`` on the points.

    Args:
        points: ``(P, 3)`` sample points, canonical frame.
        centers: ``(M, 3)`` voxel centres.
        workers: query threads (``-1``: all cores).

    Returns:
        ``(M,)`` float64 distances.
    """
    from scipy.spatial import cKDTree  # imported on first use: ~0.3 s of CLI start-up

    pts, ctr = as_points(points, "points"), as_points(centers, "centers")
    return cKDTree(pts).query(ctr, k=1, workers=workers)[0]


def udf_pykdtree(points: ArrayLike, centers: ArrayLike) -> NDArray:
    """UDF of one cloud with ``pykdtree`` (optional dependency, OpenMP threads).

    Returns ``(M,)`` float64 distances. Raises MissingDependencyError when not installed.
    """
    try:
        from pykdtree.kdtree import KDTree
    except ImportError as exc:
        raise MissingDependencyError(
            "the 'pykdtree' UDF backend needs `pip install pykdtree`; use backend='kdtree'"
        ) from exc
    pts, ctr = as_points(points, "points"), as_points(centers, "centers")
    return KDTree(pts).query(ctr, k=1)[0].astype(np.float64, copy=False)


def udf_reference(points: ArrayLike, centers: ArrayLike, chunk: int = 2048) -> NDArray:
    """Slow reference: float64 brute force over all (centre, point) pairs by differences.

    Returns ``(M,)`` float64 distances.
    """
    pts, ctr = as_points(points, "points"), as_points(centers, "centers")
    out = np.empty(ctr.shape[0])
    for s in range(0, ctr.shape[0], chunk):
        diff = ctr[s : s + chunk, None, :] - pts[None, :, :]
        out[s : s + chunk] = np.sqrt(np.einsum("mpd,mpd->mp", diff, diff).min(axis=1))
    return out


# --------------------------------------------------------------------------- batched torch
def udf_torch(
    clouds: torch.Tensor,
    centers: torch.Tensor,
    *,
    candidates: int = 2,
    block_elements: int = TORCH_BLOCK_ELEMENTS,
) -> torch.Tensor:
    """Batched brute-force UDF on the device of the inputs.

    Args:
        clouds: ``(B, P, 3)`` float tensor.
        centers: ``(M, 3)`` float tensor on the same device and dtype.
        candidates: nearest points (by the fast matmul estimate) whose exact distance is
            recomputed from coordinate differences; 1 is exact up to near-ties, 2 (default)
            was exact to ~1e-7 in every test.
        block_elements: cap on ``B · chunk · P``, the distance block held at once.

    Returns:
        ``(B, M)`` distances in the dtype of the inputs.
    """
    import torch

    if clouds.ndim != 3 or clouds.shape[2] != 3 or centers.ndim != 2 or centers.shape[1] != 3:
        raise ArrayShapeError(
            f"expected clouds (B, P, 3) and centers (M, 3), got {tuple(clouds.shape)} and "
            f"{tuple(centers.shape)}"
        )
    n_batch, n_points, _ = clouds.shape
    k = min(positive_int(candidates, "candidates"), n_points)
    chunk = max(1, min(centers.shape[0], block_elements // max(1, n_batch * n_points)))
    squared_norms = (clouds * clouds).sum(dim=2).unsqueeze(1)  # (B, 1, P)
    transposed = clouds.transpose(1, 2)  # (B, 3, P)
    out = torch.empty((n_batch, centers.shape[0]), dtype=clouds.dtype, device=clouds.device)
    batch_index = torch.arange(n_batch, device=clouds.device)[:, None, None]
    for s in range(0, centers.shape[0], chunk):
        block = centers[s : s + chunk]
        # |p|² − 2 c·p  (|c|² is constant per row and does not change the ranking)
        estimate = torch.baddbmm(
            squared_norms, block.expand(n_batch, -1, -1), transposed, alpha=-2.0
        )
        if k == 1:
            nearest = estimate.argmin(dim=2, keepdim=True)
        else:
            nearest = estimate.topk(k, dim=2, largest=False, sorted=False).indices
        picked = clouds[batch_index, nearest]  # (B, chunk, k, 3)
        exact = (picked - block[None, :, None, :]).norm(dim=3)
        out[:, s : s + chunk] = exact.amin(dim=2)
    return out


# --------------------------------------------------------------------------- evaluator
class UdfEvaluator:
    """Precompute-then-query UDF at a fixed set of voxel centres.

    The centres are converted once (float64 numpy for the k-d tree backends, a float32 tensor
    on ``device`` for torch); :meth:`__call__` then evaluates batches of clouds.

    Args:
        centers: ``(M, 3)`` voxel centres, canonical frame.
        backend: ``"auto"`` (default; see the module docstring), ``"kdtree"``,
            ``"pykdtree"`` or ``"torch"``.
        device: torch device the result is returned on (and computed on for ``"torch"``).
        workers: query threads of the ``"kdtree"`` backend (default all cores).
    """

    def __init__(
        self,
        centers: ArrayLike,
        backend: str | UdfBackend = UdfBackend.AUTO,
        device: torch.device | str = "cpu",
        workers: int = -1,
    ) -> None:
        import torch

        self.device = resolve_device(device)
        self.backend = resolve_backend(backend, self.device)
        if self.backend is UdfBackend.PYKDTREE and not pykdtree_available():
            raise MissingDependencyError("the 'pykdtree' UDF backend needs `pip install pykdtree`")
        if self.backend is UdfBackend.TRITON:
            from litege_core.descriptor.udf_triton import triton_available

            if not triton_available(self.device.type):
                raise MissingDependencyError(
                    f"the 'triton' UDF backend needs Triton and a CUDA device (got "
                    f"{self.device.type}; TRITON_INTERPRET=1 runs it on the CPU, slowly)"
                )
        self.workers = workers
        self._centers64 = as_points(centers, "centers")
        self._centers64.setflags(write=False)
        self._centers_t = (
            torch.from_numpy(self._centers64.astype(np.float32)).to(self.device)
            if self.backend in (UdfBackend.TORCH, UdfBackend.TRITON)
            else None
        )

    @property
    def n_centers(self) -> int:
        return int(self._centers64.shape[0])

    def __call__(self, clouds: ArrayLike | torch.Tensor | Sequence[ArrayLike]) -> torch.Tensor:
        """UDF of a batch of clouds.

        Args:
            clouds: ``(B, P, 3)`` array or tensor, or a sequence of ``B`` arrays ``(P_b, 3)``
                of different sizes (padded by repeating each cloud's first point, which does
                not change a nearest-point distance).

        Returns:
            ``(B, M)`` float32 tensor on ``self.device``.
        """
        import torch

        if self._centers_t is not None:  # a tensor backend: a tensor stays on its device
            tensor = (
                clouds.to(self.device, torch.float32)
                if isinstance(clouds, torch.Tensor)
                else torch.from_numpy(stack_clouds(clouds)).to(self.device)
            )
            if self.backend is UdfBackend.TRITON:
                from litege_core.descriptor.udf_triton import udf_triton

                return udf_triton(tensor, self._centers_t)
            return udf_torch(tensor, self._centers_t)
        batch = stack_clouds(clouds)
        rows = np.empty((batch.shape[0], self.n_centers), dtype=np.float32)
        for b in range(batch.shape[0]):  # one tree per cloud: nothing to share between them
            points = batch[b].astype(np.float64)
            if self.backend is UdfBackend.PYKDTREE:
                rows[b] = udf_pykdtree(points, self._centers64)
            else:
                rows[b] = udf_kdtree(points, self._centers64, workers=self.workers)
        return torch.from_numpy(rows).to(self.device)


def stack_clouds(clouds: ArrayLike | torch.Tensor | Sequence[ArrayLike]) -> NDArray:
    """Validate clouds into one ``(B, P, 3)`` float32 array (ragged lists padded, see
    :meth:`UdfEvaluator.__call__`)."""
    if hasattr(clouds, "detach"):  # a torch tensor
        clouds = clouds.detach().cpu().numpy()
    if isinstance(clouds, (list, tuple)):
        if not clouds:
            raise ArrayShapeError("clouds is an empty sequence")
        items = [as_points(c, f"clouds[{b}]", dtype=np.float32) for b, c in enumerate(clouds)]
        width = max(c.shape[0] for c in items)
        out = np.empty((len(items), width, 3), dtype=np.float32)
        for b, c in enumerate(items):  # loop over clouds, not points
            out[b, : c.shape[0]] = c
            out[b, c.shape[0] :] = c[0]
        return out
    return as_clouds(cast(ArrayLike, clouds))  # lists and tensors were handled above


def compute_udf(
    points: ArrayLike,
    centers: ArrayLike,
    backend: str | UdfBackend = UdfBackend.AUTO,
    workers: int = 1,
) -> NDArray:
    """One-off UDF of one cloud on the CPU: ``(P, 3)`` points, ``(M, 3)`` centres → ``(M,)``
    float64 (float32 precision for the tensor backends)."""
    chosen = resolve_backend(backend)
    if chosen is UdfBackend.KDTREE:
        return udf_kdtree(points, centers, workers=workers)
    if chosen is UdfBackend.PYKDTREE:
        return udf_pykdtree(points, centers)
    cloud = as_points(points, "points", dtype=np.float32)[None]
    return UdfEvaluator(centers, backend=chosen)(cloud)[0].double().numpy()


__all__ = [
    "TORCH_BLOCK_ELEMENTS",
    "UdfBackend",
    "UdfEvaluator",
    "compute_udf",
    "device_type",
    "pykdtree_available",
    "resolve_backend",
    "stack_clouds",
    "udf_kdtree",
    "udf_pykdtree",
    "udf_reference",
    "udf_torch",
]
