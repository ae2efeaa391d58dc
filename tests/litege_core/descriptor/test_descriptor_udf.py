"""UDF backends agree with the float64 brute-force reference to 1e-5."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from litege_core.descriptor import udf as udf_mod
from litege_core.descriptor.grid import VoxelGrid
from litege_core.descriptor.udf_triton import triton_available, udf_triton
from litege_core.errors import (
    ArrayShapeError,
    EmptyShapeError,
    InputError,
    MissingDependencyError,
    NonFiniteError,
)

TOL = 1e-5


def _centers(m: int = 3000, seed: int = 0) -> np.ndarray:
    grid = VoxelGrid()
    rng = np.random.default_rng(seed)
    centers = grid.centers(np.sort(rng.choice(grid.n_voxels, m, replace=False)))
    return centers * 0.6  # concentrate them near the clouds, where precision matters


def _cloud(p: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    x = rng.normal(size=(p, 3))
    return (x / np.linalg.norm(x, axis=1, keepdims=True) * [0.6, 0.4, 0.3]).astype(np.float32)


BACKENDS = ["kdtree", "torch"] + (["pykdtree"] if udf_mod.pykdtree_available() else [])


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("n_points", [1, 57, 4000])
def test_backends_match_reference(backend: str, n_points: int) -> None:
    centers = _centers()
    clouds = np.stack([_cloud(n_points, s) for s in range(3)])
    evaluator = udf_mod.UdfEvaluator(centers, backend=backend)
    got = evaluator(clouds)
    assert got.shape == (3, centers.shape[0]) and got.dtype == torch.float32
    for b in range(3):
        reference = udf_mod.udf_reference(clouds[b].astype(np.float64), centers)
        np.testing.assert_allclose(got[b].numpy(), reference, atol=TOL, rtol=0)
        single = udf_mod.compute_udf(clouds[b], centers, backend=backend)
        np.testing.assert_allclose(single, reference, atol=TOL, rtol=0)


def test_kdtree_workers_and_exactness() -> None:
    centers = _centers(500)
    cloud = _cloud(300, 1).astype(np.float64)
    reference = udf_mod.udf_reference(cloud, centers)
    parallel = udf_mod.udf_kdtree(cloud, centers, workers=-1)
    np.testing.assert_allclose(parallel, reference, atol=1e-12)
    # a point on a centre has distance 0
    assert udf_mod.udf_kdtree(centers[:1], centers)[0] == 0.0


def test_torch_chunking_and_candidates() -> None:
    centers = torch.from_numpy(_centers(700).astype(np.float32))
    clouds = torch.from_numpy(np.stack([_cloud(800, s) for s in range(2)]))
    full = udf_mod.udf_torch(clouds, centers)
    tiny_blocks = udf_mod.udf_torch(clouds, centers, block_elements=1000)
    torch.testing.assert_close(full, tiny_blocks, rtol=0, atol=0)
    one = udf_mod.udf_torch(clouds, centers, candidates=1)
    torch.testing.assert_close(full, one, rtol=0, atol=1e-4)
    # batched equals one cloud at a time
    for b in range(2):
        torch.testing.assert_close(udf_mod.udf_torch(clouds[b : b + 1], centers)[0], full[b])


def test_ragged_clouds_are_padded_without_changing_distances() -> None:
    centers = _centers(400)
    clouds = [_cloud(10, 0), _cloud(300, 1), _cloud(77, 2)]
    for backend in BACKENDS:
        evaluator = udf_mod.UdfEvaluator(centers, backend=backend)
        batch = evaluator(clouds)
        for b, cloud in enumerate(clouds):
            np.testing.assert_allclose(
                batch[b].numpy(), udf_mod.udf_reference(cloud, centers), atol=TOL, rtol=0
            )


def test_auto_backend_resolution() -> None:
    backend = udf_mod.UdfBackend
    expected = backend.PYKDTREE if udf_mod.pykdtree_available() else backend.KDTREE
    assert udf_mod.resolve_backend("auto", "cpu") is expected
    on_gpu = udf_mod.UdfBackend.TRITON if triton_available("cuda") else backend.TORCH
    assert udf_mod.resolve_backend("auto", "cuda") is on_gpu
    assert udf_mod.resolve_backend("torch", "cpu") is udf_mod.UdfBackend.TORCH
    with pytest.raises(InputError):
        udf_mod.resolve_backend("faiss")


def test_missing_pykdtree_is_reported(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(udf_mod, "pykdtree_available", lambda: False)
    assert udf_mod.resolve_backend("auto") is udf_mod.UdfBackend.KDTREE
    with pytest.raises(MissingDependencyError):
        udf_mod.UdfEvaluator(_centers(10), backend="pykdtree")


def test_invalid_inputs() -> None:
    centers = _centers(10)
    evaluator = udf_mod.UdfEvaluator(centers, backend="kdtree")
    with pytest.raises(ArrayShapeError):
        evaluator(np.zeros((4, 3)))
    with pytest.raises(ArrayShapeError):
        evaluator(np.zeros((1, 4, 2)))
    with pytest.raises(EmptyShapeError):
        evaluator(np.zeros((1, 0, 3)))
    with pytest.raises(NonFiniteError):
        evaluator(np.full((1, 4, 3), np.nan))
    with pytest.raises(ArrayShapeError):
        evaluator([])
    with pytest.raises(ArrayShapeError):
        udf_mod.udf_kdtree(np.zeros((4, 3)), np.zeros((4,)))
    with pytest.raises(ArrayShapeError):
        udf_mod.udf_torch(torch.zeros(4, 3), torch.zeros(5, 3))
    with pytest.raises(ArrayShapeError):
        udf_mod.UdfEvaluator(np.zeros((5, 2)))
    with pytest.raises(InputError):
        udf_mod.UdfEvaluator(centers, device="not-a-device")
    if not torch.cuda.is_available():
        with pytest.raises(InputError):
            udf_mod.UdfEvaluator(centers, device="cuda")


# Triton runs on a CUDA GPU, or on the CPU under its interpreter (TRITON_INTERPRET=1, slow:
# small sizes). Without Triton (the CPU install) these are skipped; the GPU run covers them.
TRITON_DEVICE = next((d for d in ("cuda", "cpu") if triton_available(d)), None)
needs_triton = pytest.mark.skipif(TRITON_DEVICE is None, reason="Triton cannot run here")


@needs_triton
@pytest.mark.parametrize("n_points", [1, 57, 130])
def test_triton_kernel_matches_reference(n_points: int) -> None:
    centers = _centers(300 if TRITON_DEVICE == "cpu" else 3000)
    clouds = [_cloud(n_points, s) for s in range(3)] + [_cloud(max(1, n_points // 3), 9)]
    evaluator = udf_mod.UdfEvaluator(centers, backend="triton", device=TRITON_DEVICE)
    got = evaluator(clouds).cpu()
    assert got.shape == (4, centers.shape[0]) and got.dtype == torch.float32
    for b, cloud in enumerate(clouds):
        reference = udf_mod.udf_reference(cloud.astype(np.float64), centers)
        np.testing.assert_allclose(got[b].numpy(), reference, atol=TOL, rtol=0)
    # the same numbers as the torch backend's refined candidates, from a device tensor
    tensor = torch.from_numpy(udf_mod.stack_clouds(clouds)).to(TRITON_DEVICE)
    ctr = torch.from_numpy(centers.astype(np.float32)).to(TRITON_DEVICE)
    torch.testing.assert_close(
        udf_triton(tensor, ctr).cpu(), udf_mod.udf_torch(tensor, ctr).cpu(), rtol=0, atol=1e-6
    )


def test_triton_backend_without_triton_is_reported(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("TRITON_INTERPRET", raising=False)
    with pytest.raises(MissingDependencyError, match="triton"):
        udf_mod.UdfEvaluator(_centers(10), backend="triton", device="cpu")
    with pytest.raises(ArrayShapeError):
        udf_triton(torch.zeros(2, 5), torch.zeros(4, 3))
