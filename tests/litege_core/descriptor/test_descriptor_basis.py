"""UdfPcaBasis: descriptors, save/load round trip, and every way a saved file can be broken."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
import torch
from safetensors import safe_open
from safetensors.numpy import save_file

from litege_core.descriptor.basis import UdfPcaBasis
from litege_core.descriptor.grid import VoxelGrid
from litege_core.descriptor.pca import fit_pca_exact
from litege_core.descriptor.udf import udf_reference
from litege_core.errors import ArrayShapeError, ArtifactError, IndexOutOfRangeError, InputError

GRID = VoxelGrid(resolution=20, pitch=0.08)


def _cloud(rng: np.random.Generator, n: int = 300) -> np.ndarray:
    x = rng.normal(size=(n, 3))
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    return (x * rng.uniform(0.3, 0.7, 3) + rng.uniform(-0.1, 0.1, 3)).astype(np.float32)


@pytest.fixture(scope="module")
def basis() -> UdfPcaBasis:
    rng = np.random.default_rng(0)
    centers_all = GRID.centers()
    indices = np.flatnonzero(np.linalg.norm(centers_all, axis=1) < 0.75)[::3]
    centers = GRID.centers(indices)
    rows = np.stack([udf_reference(_cloud(rng), centers) for _ in range(24)])
    pca = fit_pca_exact(rows, 8)
    return UdfPcaBasis.from_pca(GRID, indices, pca, metadata={"note": "test basis"})


def test_construction_quantizes_components(basis: UdfPcaBasis) -> None:
    assert basis.components.dtype == np.float32 and basis.mean.dtype == np.float32
    np.testing.assert_array_equal(
        basis.components, basis.components.astype(np.float16).astype(np.float32)
    )
    np.testing.assert_array_equal(basis.centers, GRID.centers(basis.voxel_indices, np.float32))
    assert basis.n_fit_shapes == 24 and basis.n_components == 8
    assert basis.metadata["note"] == "test basis" and basis.metadata["total_variance"] > 0
    assert not basis.components.flags.writeable and not basis.voxel_indices.flags.writeable
    assert len(basis.content_hash) == 64


def test_describe_matches_numpy_formula_and_is_deterministic(basis: UdfPcaBasis) -> None:
    points = _cloud(np.random.default_rng(5), 500)
    z = basis.describe(points)
    assert z.shape == (8,) and z.dtype == np.float32
    udf = udf_reference(points, basis.centers.astype(np.float64))
    expected = (udf - basis.mean) @ basis.components.T.astype(np.float64)
    np.testing.assert_allclose(z, expected, atol=1e-5, rtol=1e-5)
    np.testing.assert_array_equal(basis.describe(points), z)
    np.testing.assert_allclose(basis.describe(points, udf_backend="torch"), z, atol=1e-5)


@pytest.mark.parametrize("udf_backend", ["auto", "kdtree", "torch"])
def test_batched_equals_single(basis: UdfPcaBasis, udf_backend: str) -> None:
    rng = np.random.default_rng(9)
    clouds = np.stack([_cloud(rng, 400) for _ in range(5)])
    batch = basis.describe_batch(clouds, udf_backend=udf_backend)
    assert isinstance(batch, torch.Tensor) and batch.shape == (5, 8)
    for b in range(5):
        np.testing.assert_allclose(
            batch[b].numpy(), basis.describe(clouds[b], udf_backend=udf_backend), atol=1e-5
        )
    ragged = basis.describe_batch([clouds[0][:100], clouds[1]], udf_backend=udf_backend)
    np.testing.assert_allclose(
        ragged[0].numpy(), basis.describe(clouds[0][:100], udf_backend=udf_backend), atol=1e-5
    )
    torch_in = basis.describe_batch(torch.from_numpy(clouds), udf_backend=udf_backend)
    torch.testing.assert_close(torch_in, batch)


def test_engine_is_cached_and_residual_matches_pca(basis: UdfPcaBasis) -> None:
    assert basis.engine("cpu") is basis.engine("cpu")
    clouds = np.stack([_cloud(np.random.default_rng(s)) for s in range(3)])
    result = basis.engine().describe_with_residual(clouds)
    np.testing.assert_allclose(
        result.residual.numpy(),
        basis.pca.reconstruction_residual(result.udf.numpy().astype(np.float64)),
        rtol=1e-4,
    )
    torch.testing.assert_close(result.descriptors, basis.describe_batch(clouds))


def test_truncate(basis: UdfPcaBasis) -> None:
    small = basis.truncate(3)
    assert small.n_components == 3 and small.content_hash != basis.content_hash
    points = _cloud(np.random.default_rng(2))
    np.testing.assert_allclose(small.describe(points), basis.describe(points)[:3], atol=1e-6)
    with pytest.raises(InputError):
        basis.truncate(9)


def test_save_load_round_trip(basis: UdfPcaBasis, tmp_path: Path) -> None:
    path = tmp_path / "basis.safetensors"
    basis.save(path)
    loaded = UdfPcaBasis.load(path)
    assert loaded == basis and loaded.content_hash == basis.content_hash
    for name in ("voxel_indices", "centers", "mean", "components", "explained_variance"):
        np.testing.assert_array_equal(getattr(loaded, name), getattr(basis, name))
    assert loaded.grid == basis.grid and loaded.metadata == basis.metadata
    points = _cloud(np.random.default_rng(3))
    np.testing.assert_array_equal(loaded.describe(points), basis.describe(points))
    with safe_open(str(path), framework="np") as handle:
        assert handle.get_tensor("components").dtype == np.float16
        header = json.loads(handle.metadata()["litege_udf_pca"])
    assert header["content_hash"] == basis.content_hash and header["grid"] == GRID.to_dict()
    assert path.stat().st_size < basis.nbytes_on_disk + 4096
    assert not list(tmp_path.glob("*.tmp-*"))


# --------------------------------------------------------------------------- int8 storage
def test_int8_storage_rounds_components_per_component(basis: UdfPcaBasis) -> None:
    small = basis.with_component_storage("int8")
    assert small.component_storage == "int8" and basis.component_storage == "float16"
    assert small.with_component_storage("int8") is small
    scales = small.component_scales
    assert scales is not None and scales.dtype == np.float32 and scales.shape == (8,)
    codes = small.components / scales[:, None]
    np.testing.assert_allclose(codes, np.rint(codes), atol=1e-4)
    assert np.abs(np.rint(codes)).max() == 127  # every component uses the full code range
    # the rounding error of a component is at most half a step
    assert (np.abs(small.components - basis.components).max(axis=1) <= scales / 2 + 1e-7).all()
    assert small.content_hash != basis.content_hash
    assert small.nbytes_on_disk < basis.nbytes_on_disk
    back = small.with_component_storage("float16")
    assert back.component_scales is None and back.component_storage == "float16"
    with pytest.raises(InputError):
        basis.with_component_storage("int4")


def test_int8_descriptor_stays_close_to_float16(basis: UdfPcaBasis) -> None:
    small = basis.with_component_storage("int8")
    points = _cloud(np.random.default_rng(4), 600)
    full, eight = basis.describe(points), small.describe(points)
    assert np.abs(full - eight).max() <= 0.01 * np.abs(full).max()
    assert not np.array_equal(full, eight)


def test_int8_save_load_round_trip(basis: UdfPcaBasis, tmp_path: Path) -> None:
    small = basis.with_component_storage("int8").truncate(5)
    assert small.component_storage == "int8" and small.n_components == 5
    path = tmp_path / "basis.safetensors"
    small.save(path)
    loaded = UdfPcaBasis.load(path)
    assert loaded == small and loaded.component_storage == "int8"
    np.testing.assert_array_equal(loaded.components, small.components)
    np.testing.assert_array_equal(loaded.component_scales, small.component_scales)
    with safe_open(str(path), framework="np") as handle:
        assert handle.get_tensor("components").dtype == np.int8
        header = json.loads(handle.metadata()["litege_udf_pca"])
    assert header["format_version"] == 2 and header["content_hash"] == small.content_hash


def test_int8_components_must_fit_their_scales(basis: UdfPcaBasis) -> None:
    scales = np.full(basis.n_components, 1e-6, np.float32)  # codes far beyond ±127
    with pytest.raises(ArrayShapeError):
        dataclasses.replace(basis, component_scales=scales)
    with pytest.raises(ArrayShapeError):
        dataclasses.replace(basis, component_scales=-np.ones(basis.n_components, np.float32))


# --------------------------------------------------------------------------- broken files
def _read(path: Path) -> tuple[dict[str, np.ndarray], dict[str, str]]:
    with safe_open(str(path), framework="np") as handle:
        return {k: handle.get_tensor(k) for k in handle.keys()}, dict(handle.metadata())  # noqa: SIM118


def _tamper(basis: UdfPcaBasis, tmp_path: Path, edit) -> Path:
    """Save ``basis``, apply ``edit(tensors, header, file_metadata)`` and write a new file.

    ``header`` is the parsed JSON document; it is serialised back unless the edit replaced
    the raw string in ``file_metadata`` (or removed it)."""
    good = tmp_path / "good.safetensors"
    basis.save(good)
    tensors, meta = _read(good)
    raw = meta["litege_udf_pca"]
    header = json.loads(raw)
    edit(tensors, header, meta)
    if meta.get("litege_udf_pca") == raw:
        meta["litege_udf_pca"] = json.dumps(header)
    bad = tmp_path / "bad.safetensors"
    save_file(tensors, str(bad), metadata=meta)
    return bad


def _set(name, value):
    def edit(tensors, header, meta):
        tensors[name] = value(tensors[name])

    return edit


BROKEN = {
    "tensor changed (hash)": _set("mean", lambda a: a + np.float32(1e-3)),
    "components width": _set("components", lambda a: a[:, :-1].copy()),
    "components dtype": _set("components", lambda a: a.astype(np.float32)),
    "indices dtype": _set("voxel_indices", lambda a: a.astype(np.int32)),
    "indices out of grid": _set("voxel_indices", lambda a: a + 8000),
    "indices unsorted": _set("voxel_indices", lambda a: a[::-1].copy()),
    "centres off grid": _set("centers", lambda a: a + np.float32(0.01)),
    "mean length": _set("mean", lambda a: a[:-1].copy()),
    "nan mean": _set("mean", lambda a: np.full_like(a, np.nan)),
    "variance length": _set("explained_variance", lambda a: a[:-1].copy()),
    "missing tensor": lambda t, h, m: t.pop("explained_variance_ratio"),
    "extra tensor": lambda t, h, m: t.__setitem__("weights", np.zeros(3, np.float32)),
    "format version": lambda t, h, m: h.__setitem__("format_version", 99),
    "grid changed": lambda t, h, m: h.__setitem__("grid", {"resolution": 21, "pitch": 0.08}),
    "grid invalid": lambda t, h, m: h.__setitem__("grid", {"resolution": -1, "pitch": 0.08}),
    "n_voxels header": lambda t, h, m: h.__setitem__("n_voxels", 3),
    "n_fit_shapes": lambda t, h, m: h.__setitem__("n_fit_shapes", 0),
    "hash header": lambda t, h, m: h.__setitem__("content_hash", "0" * 64),
    "header json": lambda t, h, m: m.__setitem__("litege_udf_pca", "{not json"),
    "header not object": lambda t, h, m: m.__setitem__("litege_udf_pca", "[1, 2]"),
    "no header": lambda t, h, m: m.pop("litege_udf_pca"),
    "wrong format": lambda t, h, m: m.__setitem__("format", "something-else"),
}


@pytest.mark.parametrize("case", sorted(BROKEN))
def test_inconsistent_files_raise_artifact_error(
    basis: UdfPcaBasis, tmp_path: Path, case: str
) -> None:
    path = _tamper(basis, tmp_path, BROKEN[case])
    with pytest.raises(ArtifactError) as info:
        UdfPcaBasis.load(path)
    assert str(path) in str(info.value)


@pytest.mark.parametrize("cut", [0, 7, 100, -10])
def test_truncated_or_garbage_files(basis: UdfPcaBasis, tmp_path: Path, cut: int) -> None:
    path = tmp_path / "basis.safetensors"
    basis.save(path)
    data = path.read_bytes()
    path.write_bytes(data[:cut])
    with pytest.raises(ArtifactError):
        UdfPcaBasis.load(path)


def test_unreadable_paths(tmp_path: Path) -> None:
    with pytest.raises(ArtifactError):
        UdfPcaBasis.load(tmp_path / "missing.safetensors")
    with pytest.raises(ArtifactError):
        UdfPcaBasis.load(tmp_path)
    garbage = tmp_path / "garbage.safetensors"
    garbage.write_bytes(b"\x08\x00\x00\x00\x00\x00\x00\x00not-json" + bytes(64))
    with pytest.raises(ArtifactError):
        UdfPcaBasis.load(garbage)


# --------------------------------------------------------------------------- direct construction
def _fields(basis: UdfPcaBasis) -> dict:
    return {
        "grid": basis.grid,
        "voxel_indices": basis.voxel_indices,
        "centers": basis.centers,
        "mean": basis.mean,
        "components": basis.components,
        "explained_variance": basis.explained_variance,
        "explained_variance_ratio": basis.explained_variance_ratio,
        "n_fit_shapes": basis.n_fit_shapes,
    }


@pytest.mark.parametrize(
    ("name", "value", "error"),
    [
        ("components", lambda a: a[:, :-1], ArrayShapeError),
        ("components", lambda a: a[0], ArrayShapeError),
        ("components", lambda a: a * 1e6, ArrayShapeError),  # overflows float16
        ("mean", lambda a: a[:, None], ArrayShapeError),
        ("centers", lambda a: a[:, :2], ArrayShapeError),
        ("voxel_indices", lambda a: a[:0], ArrayShapeError),
        ("voxel_indices", lambda a: a - 10**6, IndexOutOfRangeError),
        ("explained_variance", lambda a: -a, ArrayShapeError),
        ("n_fit_shapes", lambda a: 0, InputError),
        ("grid", lambda a: {"resolution": 20}, InputError),
    ],
)
def test_constructor_validation(basis: UdfPcaBasis, name: str, value, error: type) -> None:
    fields = _fields(basis)
    fields[name] = value(fields[name])
    with pytest.raises(error):
        UdfPcaBasis(**fields)


def test_constructor_rejects_bad_metadata_and_points(basis: UdfPcaBasis) -> None:
    with pytest.raises(InputError):
        UdfPcaBasis(**_fields(basis), metadata={"x": object()})
    with pytest.raises(ArrayShapeError):
        basis.describe(np.zeros((5, 2)))
    with pytest.raises(ArrayShapeError):
        basis.describe_batch(np.zeros((5, 3)))


INT8_BROKEN = {
    "int8 codes as float16": _set("components", lambda a: a.astype(np.float16)),
    "scales missing": lambda t, h, m: t.pop("component_scales"),
    "scales in a float16 file": lambda t, h, m: h.__setitem__("format_version", 1),
    "scales changed (hash)": _set("component_scales", lambda a: a * np.float32(1.01)),
}


@pytest.mark.parametrize("case", sorted(INT8_BROKEN))
def test_inconsistent_int8_files_raise_artifact_error(
    basis: UdfPcaBasis, tmp_path: Path, case: str
) -> None:
    path = _tamper(basis.with_component_storage("int8"), tmp_path, INT8_BROKEN[case])
    with pytest.raises(ArtifactError) as info:
        UdfPcaBasis.load(path)
    assert str(path) in str(info.value)
